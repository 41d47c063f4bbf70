"""A run folder's checkpoint on disk, its fingerprint, and the frames it vouches for.

A run with `recording.checkpoint_every` (or `checkpoint_seconds`) keeps in its folder:
  checkpoint.npz    the latest complete checkpoint: the engine's saved state (named
                    arrays, kernels/checkpoint.py) and `__meta__`, a JSON fingerprint:
                    the step, the frames recorded up to it, the schedule and backend
                    that ran, the SHA-256 of the canonical scenario JSON, the flocklab
                    version and the engine's bits version, and the SHA-256 of the arrays
  frames/           the recorded frames, one `<index>.npz` each, in order; the run's
                    trajectory.h5 is written from them when it ends (an HDF5 file being
                    appended to when the process is killed can be left unreadable, a
                    frame file only incomplete, and the checkpoint counts the complete ones)
A checkpoint is written to a temporary file, flushed to disk (fsync) and renamed over
the previous one, after the frames it counts are on disk: a kill at any moment leaves
the previous checkpoint or the new one, whole. Reading refuses (`CheckpointRefused`,
its message for the user) a file that does not read back to its own hash, a checkpoint
of another scenario, and one from another flocklab version or engine bits version.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from flocklab.schemas import Scenario

    from .h5md import H5MDWriter

CHECKPOINT = "checkpoint.npz"
FRAMES = "frames"
LOCK = ".run.lock"
FORMAT = "flocklab-checkpoint/1"
_META = "__meta__"


class CheckpointRefused(ValueError):
    """A checkpoint that cannot be resumed from exactly; the message says why."""


def scenario_hash(scenario: Scenario) -> str:
    """SHA-256 of the scenario's canonical JSON (sorted keys, no spaces)."""
    text = json.dumps(scenario.model_dump(mode="json"), sort_keys=True,
                      separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def payload_hash(state: Mapping[str, np.ndarray]) -> str:
    """SHA-256 over the arrays' names, dtypes, shapes and bytes, in name order."""
    h = hashlib.sha256()
    for k in sorted(state):
        a = np.ascontiguousarray(state[k])
        h.update(f"{k}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def versions() -> dict[str, str]:
    """What the bits of a run depend on besides its scenario: the flocklab version and
    the engine's bits version (kernels/checkpoint.py)."""
    import flocklab
    from flocklab.kernels.checkpoint import ENGINE_BITS

    return {"flocklab_version": flocklab.__version__, "engine_bits": ENGINE_BITS}


def write_checkpoint(folder: Path, scenario: Scenario, step: int,
                     state: Mapping[str, np.ndarray], extra: Mapping[str, Any]) -> None:
    """Write `state` (the engine's, at `step`) as `folder`/checkpoint.npz atomically."""
    meta = {"format": FORMAT, "step": step, "scenario_sha256": scenario_hash(scenario),
            **versions(), "payload_sha256": payload_hash(state), **extra}
    tmp = folder / f".{CHECKPOINT}.tmp"
    with open(tmp, "wb") as fh:
        np.savez(fh, **state, **{_META: np.array(json.dumps(meta))})
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, folder / CHECKPOINT)
    fsync_dir(folder)


def read_checkpoint(folder: Path, scenario: Scenario
                    ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(fingerprint, state) of `folder`'s checkpoint, for `scenario` (the folder's);
    raises CheckpointRefused when it cannot continue this run exactly."""
    path = folder / CHECKPOINT
    try:
        with np.load(path, allow_pickle=False) as z:
            state = {k: z[k] for k in z.files}  # reads every member: checks its CRC
        meta = json.loads(str(state.pop(_META)))
    except FileNotFoundError:
        raise CheckpointRefused(f"{folder} holds no checkpoint ({CHECKPOINT})") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise CheckpointRefused(f"{path} is corrupted ({type(exc).__name__}: {exc}); "
                                "it cannot be resumed from") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CheckpointRefused(f"{path} is not a {FORMAT} checkpoint")
    if meta.get("payload_sha256") != payload_hash(state):
        raise CheckpointRefused(f"{path} is corrupted (its arrays do not match their "
                                "hash); it cannot be resumed from")
    if meta.get("scenario_sha256") != scenario_hash(scenario):
        raise CheckpointRefused(f"{path} is a checkpoint of another scenario than "
                                f"{folder / 'scenario.json'}; refusing to resume from it")
    for key, now in versions().items():
        if meta.get(key) != now:
            raise CheckpointRefused(
                f"{path} was written by {key.replace('_', ' ')} {meta.get(key)!r}, this is "
                f"{now!r}: its continuation would not have the bits of the run it began")
    return meta, state


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def hold_lock(folder: Path) -> IO[bytes]:
    """An exclusive lock on the run folder, held while a process runs in it (released by
    the kernel when the process dies, kill -9 included); CheckpointRefused when another
    process holds it."""
    fh = open(folder / LOCK, "ab")  # noqa: SIM115 (held open for the whole run)
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.close()
        raise CheckpointRefused(
            f"{folder}: another process is still running this run") from None
    return fh


class FrameStore:
    """A `FrameSink` keeping each frame as `frames/<index>.npz` (step, time, arrays);
    `seal()` makes the frames so far durable and returns their count and `chain`, a hash
    chained over every frame's `payload_hash` (the checkpoint keeps both, so a frame
    file lost, damaged or from another run is refused on resume); `replay` hands them
    to the trajectory writer."""

    def __init__(self, folder: Path, count: int = 0, chain: str = ""):
        self.dir = folder / FRAMES
        self.dir.mkdir(exist_ok=True)
        for extra in self.dir.glob("*.npz"):  # frames after the checkpoint's: redone
            if not extra.stem.isdigit() or int(extra.stem) >= count:
                extra.unlink()
        self.count, self.chain = 0, ""
        for i in range(count):
            try:
                self._link(self._read(i))
            except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
                break
        if (self.count, self.chain) != (count, chain):
            raise CheckpointRefused(f"{self.dir} does not hold the {count} frames its "
                                    "checkpoint counts (lost, damaged or another run's)")
        self._unsynced: list[Path] = []

    def _read(self, i: int) -> dict[str, np.ndarray]:
        with np.load(self._path(i), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    def _link(self, frame: dict[str, np.ndarray]) -> None:
        self.chain = hashlib.sha256((self.chain + payload_hash(frame)).encode()).hexdigest()
        self.count += 1

    def _path(self, i: int) -> Path:
        return self.dir / f"{i:08d}.npz"

    def frame(self, step: int, time: float, arrays: dict[str, np.ndarray]) -> None:
        path = self._path(self.count)
        frame = {"__step__": np.int64(step), "__time__": np.float64(time), **arrays}
        np.savez(path, **frame)
        self._unsynced.append(path)
        self._link({k: np.asarray(v) for k, v in frame.items()})

    def seal(self) -> dict[str, Any]:
        """fsync the frames written since the last seal; their count and chain."""
        for path in self._unsynced:
            with open(path, "rb") as fh:
                os.fsync(fh.fileno())
        if self._unsynced:
            fsync_dir(self.dir)
        self._unsynced.clear()
        return {"frames": self.count, "frames_chain": self.chain}

    def replay(self, writer: H5MDWriter) -> None:
        for i in range(self.count):
            frame = self._read(i)
            step, time = int(frame.pop("__step__")), float(frame.pop("__time__"))
            writer.frame(step, time, frame)
