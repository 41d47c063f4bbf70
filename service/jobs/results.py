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
A job's run with checkpoints (docs/CHECKPOINTS.md) outlives a lost attempt the same way:
its hidden folder holding `checkpoint.npz` (a killed worker's), or its attempt folder
landed stopped with one (a worker that stopped because the API died), is kept, and the
next attempt takes it over to resume from the checkpoint.
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

from ..checkpoints import CHECKPOINT

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

    def adopt_checkpoint(self, job_id: str, token: str) -> bool:
        """Hand a new attempt of a job the checkpointed run of an earlier attempt, if one
        is left; delete every other leftover of the job's earlier attempts.

        The newest checkpoint wins. A hidden `.partial-*` folder is renamed the new
        attempt's hidden folder, a landed (stopped) one its attempt folder: where
        `execute.resume_dir(attempt_dir)` looks. Only the supervisor thread calls it,
        before the worker is told to run. True when a checkpoint was handed over.
        """
        dst = self.attempt_dir(job_id, token)
        u = _as_uuid(job_id)
        earlier = [p for p in (*self.attempts.glob(f"{u}.*"), *self.attempts.glob(f".{u}.*"))
                   if p.is_dir() and not _of_attempt(p, dst.name)]
        held = [p for p in earlier if (p / CHECKPOINT).is_file()]
        newest = max(held, key=lambda p: (p / CHECKPOINT).stat().st_mtime) if held else None
        if newest is not None:
            hidden = newest.name.startswith(".")
            suffix = newest.name.rsplit(".partial-", 1)[-1]
            os.replace(newest, dst.with_name(f".{dst.name}.partial-{suffix}") if hidden
                       else dst)
        for p in earlier:
            if p != newest:
                shutil.rmtree(p, ignore_errors=True)
        return newest is not None

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

    def discard_attempt(self, job_id: str, token: str, *, keep_checkpoint: bool = False
                        ) -> None:
        """Delete an attempt's output, finished or not: a killed run leaves its hidden
        `.partial-*` (or `.old-*`) sibling, which would otherwise fill the disk.
        `keep_checkpoint`: but a folder holding a checkpoint, which the job's next attempt
        resumes from (`adopt_checkpoint`)."""
        final = self.attempt_dir(job_id, token)
        for p in (final, *self.attempts.glob(f".{final.name}.*")):
            if not (keep_checkpoint and (p / CHECKPOINT).is_file()):
                shutil.rmtree(p, ignore_errors=True)

    def delete(self, job_id: str) -> None:
        shutil.rmtree(self.job_dir(job_id), ignore_errors=True)

    def sweep_attempts(self, keep: Collection[str] = (),
                       keep_checkpoints: Collection[str] = ()) -> None:
        """Delete every attempt folder but those of the jobs in `keep` (unfinished sweeps,
        which resume from them) and those holding a checkpoint of a job in
        `keep_checkpoints` (unfinished jobs); called at start-up, when no attempt runs."""
        for p in self.attempts.iterdir():
            if p.name.split(".")[0] in keep:
                continue
            if p.name.lstrip(".").split(".")[0] in keep_checkpoints and (
                    p / CHECKPOINT).is_file():
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


def _of_attempt(path: Path, name: str) -> bool:
    """Whether `path` is the attempt folder `name` or one of its hidden siblings."""
    return path.name == name or path.name.startswith(f".{name}.")


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
