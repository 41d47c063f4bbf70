"""Run a scenario and write its artifacts into a folder, atomically.

The folder holds:
  scenario.json     the canonical scenario that ran
  summary.json      status, backend, timings, final observables, convergence times
  observables.csv   the observables' time series (a header row, then one row per time)
  trajectory.h5     recorded frames and observables in H5MD (see service/h5md.py), and
                    what drawing the run needs: the model card's facts resolved for this
                    scenario and the overlay geometry (kernels/overlays.py), so
                    that the renderer reads files and never imports the engine
  trajectory.gsd    the frames in HOOMD's GSD schema, when recording.format names gsd
                    (service/gsd_trajectory.py); trajectory.h5 then holds frames only
                    when the format also names h5md
Everything is written into a hidden sibling folder first and renamed into place at the
end, so the target is either complete or absent; a run that blows up still lands, with
status "diverged" and the frames recorded before the blow-up, and so does a run stopped
through `should_stop` (status "cancelled", or the caller's `stopped_status`: the CLI's
Ctrl-C gives "interrupted"), with the frames and observables up to the stop.
While the run goes on, the observation rows computed so far are published in the hidden
folder's `observables.partial.csv` (service/live_observables.py; deleted once the final
observables.csv is written), which the service reads for a running job.
A run with checkpoints (`recording.checkpoint_every`, `checkpoint_seconds`) keeps its
latest checkpoint and its frames in the hidden folder (service/checkpoints.py), which
then survives a kill or an exception; `resume_dir` goes on from it. A stopped run lands
with them, and can be resumed too; a finished one drops them.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from flocklab.schemas import Scenario
from flocklab.schemas.version import version

from .checkpoints import (
    CHECKPOINT,
    FRAMES,
    LOCK,
    CheckpointRefused,
    FrameStore,
    hold_lock,
    read_checkpoint,
    write_checkpoint,
)

if TYPE_CHECKING:
    from flocklab.kernels import RunResult

ARTIFACTS = ("scenario.json", "summary.json", "observables.csv", "trajectory.h5")


class Frames:
    """The frame sink of a run: each trajectory writer of `recording.format` gets every
    frame."""

    def __init__(self, writers: list[Any]):
        self.writers = writers

    def frame(self, step: int, time: float, arrays: dict[str, np.ndarray]) -> None:
        for w in self.writers:
            w.frame(step, time, arrays)


def write_observables_csv(path: Path, observables: dict[str, np.ndarray]) -> None:
    names = list(observables)
    table = np.column_stack([observables[k] for k in names]) if names else np.zeros((0, 0))
    np.savetxt(path, table, delimiter=",", header=",".join(names), comments="", fmt="%.17g")


def run_summary(scenario: Scenario, result: RunResult, *, frames: int,
                files: list[str]) -> dict[str, Any]:
    """The JSON-ready summary.json of one run (a job's, or a sweep run's)."""
    return {
        "flocklab_version": version(),
        "scenario_name": scenario.name,
        "model": scenario.model.kind,
        **result.summary(),
        "frames": frames,
        "files": files,
    }


def execute_to_dir(
    scenario: Scenario,
    out_dir: Path,
    *,
    on_progress: Callable[[int, int], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    overwrite: bool = False,
    on_result: Callable[[RunResult], None] | None = None,
    stopped_status: str = "cancelled",
    path: str = "auto",
) -> dict[str, Any]:
    """Run `scenario` on the engine's schedule `path` and write its artifacts to
    `out_dir`. Returns the summary dict; `on_result` gets the engine's result before the
    folder is moved into place. A run that `should_stop` ended is written with status
    `stopped_status`."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not overwrite and any(out_dir.iterdir()):
        raise FileExistsError(f"{out_dir} exists and is not empty")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = _partial(out_dir)
    tmp.mkdir()
    try:
        (tmp / "scenario.json").write_text(scenario.model_dump_json(indent=2))
        lock = hold_lock(tmp) if scenario.recording.checkpoints else None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return _run_in(tmp, out_dir, scenario, lock, None, path=path, on_progress=on_progress,
                   should_stop=should_stop, on_result=on_result,
                   stopped_status=stopped_status)


def resume_dir(
    out_dir: Path,
    *,
    on_progress: Callable[[int, int], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    on_result: Callable[[RunResult], None] | None = None,
    stopped_status: str = "cancelled",
    on_resumed: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Continue the checkpointed run of `out_dir` from its latest checkpoint: the one in
    its hidden folder (a run killed while it went on) or in the folder itself (a run
    stopped through `should_stop`). Its artifacts are those the run would have written
    uninterrupted, bit for bit, plus `resumed_from_step` in the summary. `on_resumed`
    gets the checkpoint's step once every check passed, before the first step. Raises
    CheckpointRefused (service/checkpoints.py) when there is nothing to resume exactly."""
    out_dir = Path(out_dir)
    tmp, scenario, lock, meta, state, frames = _resumable(out_dir)
    if on_resumed is not None:
        on_resumed(int(meta["step"]))
    return _run_in(tmp, out_dir, scenario, lock, (meta, state, frames), path=meta["path"],
                   on_progress=on_progress, should_stop=should_stop, on_result=on_result,
                   stopped_status=stopped_status)


def _partial(out_dir: Path) -> Path:
    return out_dir.parent / f".{out_dir.name}.partial-{uuid.uuid4().hex[:8]}"


def _resumable(out_dir: Path) -> tuple[Path, Scenario, IO[bytes], dict[str, Any],
                                         dict[str, np.ndarray], FrameStore]:
    """(folder to go on in, its scenario, the folder's lock, the checkpoint's fingerprint,
    state and frames): the newest hidden folder with a checkpoint, else `out_dir` itself
    when it landed stopped with one (then moved back to a hidden folder, once every
    check passed)."""
    partials = sorted((p for p in out_dir.parent.glob(f".{out_dir.name}.partial-*")
                       if (p / CHECKPOINT).exists()),
                      key=lambda p: (p / CHECKPOINT).stat().st_mtime)
    if partials:
        src = partials[-1]
    elif (out_dir / CHECKPOINT).exists():
        src = out_dir
    elif (out_dir / "summary.json").exists():
        status = json.loads((out_dir / "summary.json").read_text()).get("status")
        raise CheckpointRefused(f"{out_dir}: the run ended ({status}) with no checkpoint "
                                "left; nothing to resume")
    else:
        raise CheckpointRefused(f"{out_dir}: no checkpoint to resume from (neither the "
                                f"folder nor a hidden .{out_dir.name}.partial-* folder "
                                f"beside it holds {CHECKPOINT})")
    try:
        scenario = Scenario.model_validate_json((src / "scenario.json").read_text())
    except (OSError, ValueError) as exc:
        raise CheckpointRefused(f"{src / 'scenario.json'} is unreadable: {exc}") from None
    lock = hold_lock(src)
    try:
        meta, state = read_checkpoint(src, scenario)
        from flocklab.kernels.runtime import resolve_backend

        if resolve_backend(scenario.backend) != meta["backend"]:
            raise CheckpointRefused(f"{src / CHECKPOINT} ran on backend {meta['backend']!r}, "
                                    f"which this machine does not start for "
                                    f"{scenario.backend!r}: its bits would differ")
        frames = FrameStore(src, meta["frames"], meta["frames_chain"])
        if src == out_dir:  # landed stopped: back to a hidden folder, its results redone
            lock.close()
            tmp = _partial(out_dir)
            os.rename(out_dir, tmp)
            lock = hold_lock(tmp)
            for name in ("summary.json", "observables.csv", "trajectory.h5"):
                (tmp / name).unlink(missing_ok=True)
            src = tmp
            frames.dir = tmp / FRAMES
    except BaseException:
        lock.close()
        raise
    return src, scenario, lock, meta, state, frames


def _run_in(tmp: Path, out_dir: Path, scenario: Scenario, lock: IO[bytes] | None,
            resume: tuple[dict[str, Any], dict[str, np.ndarray], FrameStore] | None, *,
            path: str,
            on_progress: Callable[[int, int], None] | None,
            should_stop: Callable[[], bool] | None,
            on_result: Callable[[RunResult], None] | None,
            stopped_status: str) -> dict[str, Any]:
    """Run `scenario` in the hidden folder `tmp` (from `resume`'s checkpoint, if given)
    and move it into place as `out_dir`. A checkpointed run keeps its frames in a
    `FrameStore` and writes trajectory.h5 from them at the end; a hidden folder that
    holds a checkpoint survives an exception, to be resumed."""
    from flocklab import kernels  # the engine: only where a simulation runs
    from flocklab.kernels.checkpoint import CheckpointMismatch
    from flocklab.kernels.overlays import overlays

    from .h5md import H5MDWriter
    from .live_observables import LIVE_FILE, LiveObservables

    try:
        formats = scenario.recording.formats
        frames = None
        if scenario.recording.checkpoints:
            frames = resume[2] if resume else FrameStore(tmp)

        def on_checkpoint(step: int, state: dict[str, np.ndarray]) -> None:
            assert frames is not None
            from flocklab.kernels.checkpoint import BACKEND, PATH

            write_checkpoint(tmp, scenario, step, state,
                             {**frames.seal(), "path": str(state[PATH]),
                              "backend": str(state[BACKEND])})

        files = list(ARTIFACTS)
        if "gsd" in formats:
            from .gsd_trajectory import GSD_FILE, GSDWriter

            files.append(GSD_FILE)

        def open_writers() -> tuple[H5MDWriter, list[Any]]:
            """trajectory.h5 (always: observables, scenario, drawing) and the frame sinks
            of `recording.format`."""
            h5 = H5MDWriter(tmp / "trajectory.h5", scenario)
            gsd = GSDWriter.for_scenario(tmp / GSD_FILE, scenario) if "gsd" in formats else None
            return h5, [w for w in (h5 if "h5md" in formats else None, gsd) if w]

        # A checkpointed run keeps its frames in the FrameStore and writes them at the end.
        writer, sinks = open_writers() if frames is None else (None, [])
        live = LiveObservables(tmp / LIVE_FILE)
        try:
            try:
                result = kernels.run(
                    scenario, sink=Frames(sinks) if frames is None else frames,
                    on_progress=on_progress, should_stop=should_stop,
                    on_observations=live.append, path=path,
                    on_checkpoint=on_checkpoint, resume=resume[1] if resume else None,
                )
            except CheckpointMismatch as exc:
                raise CheckpointRefused(f"{tmp / CHECKPOINT} does not fit this run: {exc}"
                                        ) from None
            if frames is not None:
                writer, sinks = open_writers()
                frames.replay(Frames(sinks))
            assert writer is not None
            writer.write_observables(result.observables)
            writer.write_overlays(overlays(scenario, np.array(writer.frame_times)))
        finally:
            for w in {id(w): w for w in [writer, *sinks] if w is not None}.values():
                w.close()
        write_observables_csv(tmp / "observables.csv", result.observables)
        live.remove()
        summary = run_summary(scenario, result, frames=sinks[0].frames, files=files)
        if resume is not None:
            summary["resumed_from_step"] = resume[0]["step"]
        if summary["status"] == "cancelled":
            summary["status"] = stopped_status
        if frames is not None and result.status != "cancelled":
            # Done: nothing to resume. A stopped run keeps its checkpoint and frames.
            (tmp / CHECKPOINT).unlink(missing_ok=True)
            shutil.rmtree(frames.dir, ignore_errors=True)
        if on_result is not None:
            on_result(result)
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False))
        (tmp / LOCK).unlink(missing_ok=True)
        _fsync_dir(tmp)
        if out_dir.exists():
            old = out_dir.parent / f".{out_dir.name}.old-{uuid.uuid4().hex[:8]}"
            os.rename(out_dir, old)
            os.rename(tmp, out_dir)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(tmp, out_dir)
        return summary
    except BaseException:
        if not (tmp / CHECKPOINT).exists():
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        if lock is not None:
            lock.close()


def _fsync_dir(path: Path) -> None:
    for p in path.iterdir():
        if p.is_dir():  # frames/: synced as they were sealed
            continue
        with open(p, "rb") as fh:
            os.fsync(fh.fileno())
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
