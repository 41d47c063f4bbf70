"""The job runtime: the data directory with its lock, the store, the results and the
supervisor, opened and closed together by the API's lifespan."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Callable
from pathlib import Path

from .results import ResultStore
from .store import JobStore
from .supervisor import Supervisor, SupervisorConfig


class DataDirLocked(RuntimeError):
    """Another service already runs on this data directory."""


class JobRuntime:
    """Everything that must exist once per data directory.

    The directory is locked for the runtime's life: the supervisor re-queues, at
    start-up, every job a previous process left running, which is only safe when no
    other live service could be running them.
    """

    def __init__(self, data_dir: Path, config: SupervisorConfig,
                 on_change: Callable[[str], None] | None = None):
        self.data_dir = data_dir.resolve()
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self._lock_fd = _lock(self.data_dir / "service.lock")
        try:
            self.store = JobStore(self.data_dir / "jobs.sqlite3")
            self.results = ResultStore(self.data_dir / "results")
            scratch = self.data_dir / "tmp"
            scratch.mkdir(exist_ok=True)
            self.supervisor = Supervisor(self.store, self.results, config, scratch,
                                         on_change or (lambda job_id: None))
        except BaseException:
            os.close(self._lock_fd)
            raise

    def start(self) -> None:
        self.supervisor.start()

    def close(self) -> None:
        self.supervisor.stop()
        self.store.close()
        os.close(self._lock_fd)


def data_dir_locked(data_dir: Path) -> bool:
    """Whether a live service holds `data_dir`'s lock (probed without keeping it)."""
    path = data_dir / "service.lock"
    if not path.exists():
        return False
    try:
        fd = _lock(path)
    except DataDirLocked:
        return True
    os.close(fd)
    return False


def _lock(path: Path) -> int:
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise DataDirLocked(f"another flocklab service is using {path.parent}") from None
    return fd
