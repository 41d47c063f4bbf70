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
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from flocklab.schemas import Scenario

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
        "flocklab_version": "0.1.0",
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
    from flocklab import kernels  # the engine: only where a simulation runs
    from flocklab.kernels.overlays import overlays

    from .h5md import H5MDWriter
    from .live_observables import LIVE_FILE, LiveObservables

    out_dir = Path(out_dir)
    if out_dir.exists() and not overwrite and any(out_dir.iterdir()):
        raise FileExistsError(f"{out_dir} exists and is not empty")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_dir.parent / f".{out_dir.name}.partial-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    try:
        (tmp / "scenario.json").write_text(scenario.model_dump_json(indent=2))
        formats = scenario.recording.formats
        writer = H5MDWriter(tmp / "trajectory.h5", scenario)
        gsd_writer, files = None, list(ARTIFACTS)
        if "gsd" in formats:
            from .gsd_trajectory import GSD_FILE, GSDWriter

            gsd_writer = GSDWriter.for_scenario(tmp / GSD_FILE, scenario)
            files.append(GSD_FILE)
        sinks = [w for w in (writer if "h5md" in formats else None, gsd_writer) if w]
        live = LiveObservables(tmp / LIVE_FILE)
        try:
            result = kernels.run(
                scenario, sink=Frames(sinks), on_progress=on_progress,
                should_stop=should_stop, on_observations=live.append, path=path,
            )
            writer.write_observables(result.observables)
            writer.write_overlays(overlays(scenario, np.array(writer.frame_times)))
        finally:
            writer.close()
            if gsd_writer is not None:
                gsd_writer.close()
        write_observables_csv(tmp / "observables.csv", result.observables)
        live.remove()
        summary = run_summary(scenario, result, frames=sinks[0].frames, files=files)
        if summary["status"] == "cancelled":
            summary["status"] = stopped_status
        if on_result is not None:
            on_result(result)
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False))
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
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _fsync_dir(path: Path) -> None:
    for p in path.iterdir():
        with open(p, "rb") as fh:
            os.fsync(fh.fileno())
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
