"""Where results live on disk, and the only way to turn a job id into a path (R22).

Layout under the results root:
    <job-uuid>/                 committed results of a job (scenario.json, summary.json,
                                observables.csv, trajectory.h5[, trajectory.gsd])
    .attempts/<job-uuid>.<token>/   one attempt's output, written by a worker
    .attempts/.<job-uuid>.<token>.partial-*/   the same while the run writes it (renamed
                                the attempt folder when complete; left behind by a kill)
A sweep's committed folder holds the sweep runner's output instead (sweep.json, runs.csv,
table.csv, series.csv, runs/<i>/). A sweep's attempt folder outlives a lost attempt: the
next attempt adopts it and the runner skips the runs already finished there.
A path is only ever built from a UUID the server generated and parsed back as a UUID,
then resolved and checked to lie under the root; client-supplied names never reach here.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import uuid
from collections.abc import Collection
from pathlib import Path

# trajectory.gsd: only a run with recording.format gsd has it (service/gsd_trajectory.py).
RESULT_FILES = ("scenario.json", "summary.json", "observables.csv", "trajectory.h5",
                "trajectory.gsd")
SWEEP_FILES = ("sweep.json", "runs.csv", "table.csv", "series.csv", "sensitivity.csv")


class ResultStore:
    def __init__(self, root: Path):
        self.root = root.resolve()
        self.attempts = self.root / ".attempts"
        self.attempts.mkdir(parents=True, exist_ok=True)

    def job_dir(self, job_id: str | uuid.UUID) -> Path:
        """The committed results folder of a job (which may not exist)."""
        return self._inside(self.root / str(_as_uuid(job_id)))

    def file(self, job_id: str | uuid.UUID, name: str) -> Path:
        if name not in RESULT_FILES + SWEEP_FILES:
            raise ValueError(f"not a result file: {name!r}")
        return self._inside(self.job_dir(job_id) / name)

    def attempt_dir(self, job_id: str | uuid.UUID, token: str) -> Path:
        if not token.isalnum():
            raise ValueError("attempt tokens are hex strings")
        return self._inside(self.attempts / f"{_as_uuid(job_id)}.{token}")

    def adopt_attempt(self, job_id: str, token: str) -> Path:
        """Give a new attempt the folder of the job's latest earlier attempt, if any.

        Used for sweeps: the finished runs of a lost attempt are not redone. The rename is
        atomic, and only the supervisor thread calls it (before the worker is told to run).
        """
        dst = self.attempt_dir(job_id, token)
        earlier = [p for p in self.attempts.glob(f"{_as_uuid(job_id)}.*")
                   if p.is_dir() and p != dst]
        if earlier and not dst.exists():
            newest = max(earlier, key=lambda p: p.stat().st_mtime)
            os.replace(newest, dst)
            for p in earlier:
                if p != newest:
                    shutil.rmtree(p, ignore_errors=True)
        return dst

    def commit(self, job_id: str, token: str) -> bool:
        """Move an attempt's output into place; False when the attempt wrote nothing.

        A folder already at the destination can only be a leftover of an attempt that
        was renamed but never recorded as finished (the service died in between): the
        store still says the job is running, so nothing refers to it.
        """
        src, dst = self.attempt_dir(job_id, token), self.job_dir(job_id)
        if not src.is_dir():
            return False
        if dst.exists():
            shutil.rmtree(dst)
        os.replace(src, dst)
        _fsync_dir(self.root)
        return True

    def discard_attempt(self, job_id: str, token: str) -> None:
        """Delete an attempt's output, finished or not: a killed run leaves its hidden
        `.partial-*` (or `.old-*`) sibling, which would otherwise fill the disk."""
        final = self.attempt_dir(job_id, token)
        shutil.rmtree(final, ignore_errors=True)
        for leftover in self.attempts.glob(f".{final.name}.*"):
            shutil.rmtree(leftover, ignore_errors=True)

    def delete(self, job_id: str) -> None:
        shutil.rmtree(self.job_dir(job_id), ignore_errors=True)

    def sweep_attempts(self, keep: Collection[str] = ()) -> None:
        """Delete every attempt folder but those of the jobs in `keep` (unfinished sweeps,
        which resume from them); called at start-up, when no attempt is running."""
        for p in self.attempts.iterdir():
            if p.name.split(".")[0] in keep:
                continue
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)

    def _inside(self, path: Path) -> Path:
        resolved = path.resolve()
        if not resolved.is_relative_to(self.root):
            raise ValueError("result path escapes the results root")
        return resolved


def _as_uuid(job_id: str | uuid.UUID) -> uuid.UUID:
    return job_id if isinstance(job_id, uuid.UUID) else uuid.UUID(str(job_id))


def _fsync_dir(path: Path) -> None:
    """Make a rename in `path` durable before the store records the job as finished."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def checksums(folder: Path, names: tuple[str, ...] = RESULT_FILES) -> dict[str, str]:
    """sha256 of every result file present in `folder` (hex), for download integrity."""
    out = {}
    for name in names:
        p = folder / name
        if p.is_file():
            h = hashlib.sha256()
            with p.open("rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
            out[name] = h.hexdigest()
    return out
