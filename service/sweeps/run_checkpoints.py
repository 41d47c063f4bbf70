"""A sweep's runs with checkpoints: each run alone, its checkpoint in its own run folder.

A sweep run whose scenario asks for checkpoints (`recording.checkpoint_every` or
`checkpoint_seconds`, from the sweep's base or an axis) goes to the engine alone, not in
a fused batch: the engine checkpoints one replica at a time, and a run alone has the
bits it has in any batch (kernels.run_batch). Its checkpoint (service/checkpoints.py)
lies in its own folder while it goes on:
  keep = summaries  runs/<i>/checkpoint.npz (the state and its fingerprint, no frames)
  or table          and runs/<i>/.run.lock; both removed once the run's journal line is
                    written (`drop_checkpoint`), beside its summary.json (keep = table:
                    with the folder)
  keep = all        the run's hidden folder runs/.<i>.partial-* (with its frames), as
                    `flocklab run --out runs/<i>` keeps it (service/execute.py)
Running the sweep again into its folder (the CLI's rerun, a service attempt after a
killed worker or a restarted API, a Ray task retried) goes on with each partially run
run from its latest checkpoint, to the bits of the uninterrupted sweep; `on_resumed(run,
step, None)` says so before its first step, and the run's summary.json and result carry
`resumed_from_step`. A checkpoint that cannot be resumed exactly (corrupted, another
flocklab or engine bits version, another backend, arrays that do not fit) is dropped
with a warning and `on_resumed(run, None, why)`: that run starts over, to the same bits.
A folder still locked by another process (the orphaned worker of a killed API, which
stops at its next step) is waited for; past LOCK_WAIT_SECONDS the run goes on without
checkpoints rather than write beside that process. Importing this module does not
import the engine.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, TYPE_CHECKING

from flocklab.schemas.sweep import SweepRun

from ..checkpoints import (
    CHECKPOINT,
    LOCK,
    CheckpointRefused,
    hold_lock,
    read_checkpoint,
    write_checkpoint,
)
from ..execute import execute_to_dir, resume_dir

if TYPE_CHECKING:
    from flocklab.kernels import RunResult

log = logging.getLogger("flocklab.sweep")

# (run, the checkpoint's step it goes on from, or None with why it starts over)
ResumedFn = Callable[[SweepRun, "int | None", "str | None"], None]
StopFn = Callable[[], bool]
LOCK_WAIT_SECONDS = 30.0


def wants_checkpoints(run: SweepRun) -> bool:
    return run.scenario.recording.checkpoints


def run_folder(out_dir: Path, index: int) -> Path:
    return Path(out_dir) / "runs" / str(index)


def run_alone(run: SweepRun, keep: str, out_dir: Path, should_stop: StopFn | None,
              on_resumed: ResumedFn | None = None) -> RunResult | None:
    """One checkpointed run, from its checkpoint when it has one; None when should_stop
    ended it (its checkpoint kept: a rerun goes on from it)."""
    told = on_resumed or (lambda run, step, why: None)
    if keep == "all":
        return _with_artifacts(run, out_dir, should_stop, told)
    return _without_frames(run, out_dir, should_stop, told)


def drop_checkpoint(out_dir: Path, index: int) -> None:
    """A keep = summaries (or table) run's checkpoint, once its journal line is
    written; with keep = table its emptied folder too."""
    folder = run_folder(out_dir, index)
    for name in (CHECKPOINT, LOCK):
        (folder / name).unlink(missing_ok=True)
    for empty in (folder, folder.parent):
        with contextlib.suppress(OSError):  # not empty (summary.json), or absent
            empty.rmdir()


def _without_frames(run: SweepRun, out_dir: Path, should_stop: StopFn | None,
                    told: ResumedFn) -> RunResult | None:
    from flocklab import kernels
    from flocklab.kernels.checkpoint import BACKEND, PATH, STEP, CheckpointMismatch

    folder = run_folder(out_dir, run.index)
    folder.mkdir(parents=True, exist_ok=True)
    lock = _wait_for_lock(folder, run)
    if lock is None:
        result = kernels.run(run.scenario, should_stop=should_stop)
        return None if result.status == "cancelled" else result
    try:
        resume = _checkpoint_state(folder, run, told)

        def on_checkpoint(step: int, state: dict) -> None:
            write_checkpoint(folder, run.scenario, step, state,
                             {"frames": 0, "frames_chain": "", "path": str(state[PATH]),
                              "backend": str(state[BACKEND])})

        step = None if resume is None else int(resume[STEP])
        try:
            result = kernels.run(run.scenario, should_stop=should_stop,
                                 on_checkpoint=on_checkpoint, resume=resume)
        except CheckpointMismatch as exc:
            _refused(run, folder, f"{folder / CHECKPOINT} does not fit this run: {exc}", told)
            step = None
            result = kernels.run(run.scenario, should_stop=should_stop,
                                 on_checkpoint=on_checkpoint)
    finally:
        lock.close()
    if result.status == "cancelled":
        return None
    if step is not None:
        result.extra["resumed_from_step"] = step
    return result


def _checkpoint_state(folder: Path, run: SweepRun, told: ResumedFn) -> dict | None:
    """The state of `folder`'s checkpoint when this run can go on from it exactly (told
    so), else None (a refused checkpoint is dropped, and told why)."""
    if not (folder / CHECKPOINT).exists():
        return None
    from flocklab.kernels.checkpoint import STEP
    from flocklab.kernels.runtime import resolve_backend

    try:
        meta, state = read_checkpoint(folder, run.scenario)
        if resolve_backend(run.scenario.backend) != meta["backend"]:
            raise CheckpointRefused(f"{folder / CHECKPOINT} ran on backend "
                                    f"{meta['backend']!r}, which this machine does not start "
                                    f"for {run.scenario.backend!r}: its bits would differ")
    except CheckpointRefused as exc:
        _refused(run, folder, str(exc), told)
        return None
    _resumed(run, int(state[STEP]), told)
    return state


def _resumed(run: SweepRun, step: int, told: ResumedFn) -> None:
    log.info("sweep run %d: resumed from its checkpoint at step %d", run.index, step)
    told(run, step, None)


def _refused(run: SweepRun, folder: Path, why: str, told: ResumedFn) -> None:
    log.warning("sweep run %d: checkpoint refused, running from step 0: %s", run.index, why)
    (folder / CHECKPOINT).unlink(missing_ok=True)
    told(run, None, why)


def _wait_for_lock(folder: Path, run: SweepRun) -> IO[bytes] | None:
    """The run folder's lock, once no other process holds it (None after
    LOCK_WAIT_SECONDS: then the run goes on without checkpoints)."""
    deadline = time.monotonic() + LOCK_WAIT_SECONDS
    while True:
        try:
            return hold_lock(folder)
        except CheckpointRefused:
            if time.monotonic() >= deadline:
                log.warning("sweep run %d: another process still runs in %s; running "
                            "it without checkpoints", run.index, folder)
                return None
            time.sleep(0.2)


def _with_artifacts(run: SweepRun, out_dir: Path, should_stop: StopFn | None,
                    told: ResumedFn) -> RunResult | None:
    """keep = all: the run into runs/<i> (execute_to_dir), or on from the checkpoint of
    its hidden folder or of its folder landed stopped (resume_dir)."""
    folder = run_folder(out_dir, run.index)
    partials = sorted(folder.parent.glob(f".{folder.name}.partial-*"))
    got: list[RunResult] = []
    step = None
    if (folder / CHECKPOINT).exists() or any((p / CHECKPOINT).exists() for p in partials):
        for p in partials:  # an orphaned process still in one stops at its next step
            lock = _wait_for_lock(p, run) if p.exists() else None
            if lock is not None:
                lock.close()

        def resumed(at: int) -> None:
            nonlocal step
            step = at
            _resumed(run, at, told)

        try:
            resume_dir(folder, should_stop=should_stop, on_result=got.append,
                       on_resumed=resumed)
        except CheckpointRefused as exc:
            log.warning("sweep run %d: checkpoint refused, running from step 0: %s",
                        run.index, exc)
            told(run, None, str(exc))
            got, step = [], None
    if not got:
        for p in folder.parent.glob(f".{folder.name}.partial-*"):
            shutil.rmtree(p, ignore_errors=True)  # killed or refused: redone from step 0
        execute_to_dir(run.scenario, folder, should_stop=should_stop, overwrite=True,
                       on_result=got.append)
    result = got[0]
    if result.status == "cancelled":
        return None  # landed stopped with its checkpoint: a rerun resumes it
    if step is not None:
        result.extra["resumed_from_step"] = step
    return result
