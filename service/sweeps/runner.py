"""Run a sweep into a folder, resumably: `run_sweep(sweep, out_dir) -> SweepOutcome`.

The folder:
  sweep.json          the canonical sweep, its resolved base scenario and every run
                      (index, grid point, replica, seed, axis values)
  runs.jsonl          the journal: one line per finished run (see journal.py)
  runs.csv, table.csv, series.csv   the tables (see tables.py), rewritten atomically
                      every TABLE_INTERVAL s or more and at the end (also on cancel)
  sensitivity.csv     with an `analysis`, once every run has finished (sensitivity.py)
  runs/<index>/summary.json         keep = summaries (the default) or all; for
                      summaries it holds the run's measures (its runs.csv columns)
  runs/<index>/{scenario.json, observables.csv, trajectory.h5}   keep = all
Running the same sweep into the same folder again resumes it: runs found in the journal
are not redone, and a run with checkpoints (`recording.checkpoint_every`) goes on from
its latest one in its run folder (run_checkpoints.py), to the bits of the sweep never
interrupted; `on_resumed(run, step)` says so. A folder holding a different sweep is
refused (SweepFolderConflict).

The runs execute through an executor (executors.py): by default in this process, through
`kernels.run_batch` (BATCH_RUNS consecutive runs at a time, so memory stays bounded however
many runs a sweep has), or, for keep = all, through `service.execute.execute_to_dir` one
run at a time (frames need a sink); or as tasks on a Ray cluster (ray_executor.py). Every
way gives the same bits as `kernels.run` of the run's scenario alone, and whatever runs
where, only this process records results (journal, summaries, tables). Importing this
module does not import the engine.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pydantic import ValidationError

from flocklab.schemas import FieldError, Scenario
from flocklab.schemas.sweep import Sweep, SweepError, SweepRun
from flocklab.schemas.version import version

from ..execute import run_summary
from .executors import Executor, LocalExecutor
from .journal import Finished, Journal
from .measures import reduce_run
from .run_checkpoints import drop_checkpoint, wants_checkpoints
from .run_index import PendingRuns, RunIndex
from .sensitivity import write_sensitivity
from .tables import SWEEP_FILE, atomic_file, atomic_write, axis_columns, write_tables

if TYPE_CHECKING:
    from flocklab.kernels import RunResult

TABLE_INTERVAL = 10.0  # least seconds between table rewrites while a sweep runs


@dataclass(frozen=True)
class SweepProgress:
    """Runs finished so far: `runs_done` completed, `runs_failed` diverged (a numerical
    blow-up: a finished run without measures), out of `runs_total`."""

    runs_done: int
    runs_failed: int
    runs_total: int


@dataclass(frozen=True)
class SweepOutcome:
    """How `run_sweep` ended: "completed" (every run finished) or "cancelled" (stopped;
    the finished runs are kept and a rerun resumes). `runs_resumed`: finished runs found in
    the folder at the start."""

    status: Literal["completed", "cancelled"]
    runs_done: int
    runs_failed: int
    runs_total: int
    out_dir: Path
    runs_resumed: int = 0
    # runs that went on from their checkpoint: run index -> the checkpoint's step
    checkpoints_resumed: dict[int, int] = field(default_factory=dict)


class SweepFolderConflict(FileExistsError):
    """The output folder holds something other than this sweep."""


def run_sweep(
    sweep: Sweep,
    out_dir: Path,
    *,
    on_progress: Callable[[SweepProgress], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    executor: Executor | None = None,
    on_resumed: Callable[[int, int | None], None] | None = None,
) -> SweepOutcome:
    """Run every run of `sweep` not yet finished in `out_dir`, writing the tables; the
    runs execute through `executor` (default: in this process). `on_resumed(run, step)`:
    run `run` goes on from its checkpoint at `step` (None: its checkpoint was refused
    after all, it runs from step 0).

    Raises SweepError (before any run) for an invalid sweep or an observable the model
    does not have, SweepFolderConflict for a folder holding something else; engine errors
    (e.g. kernels.BackendUnavailable) propagate, with the finished runs kept.
    """
    index = RunIndex.build(sweep)  # every run checked (SweepError), none kept
    out_dir = Path(out_dir)
    resuming = _check_folder(out_dir, sweep)
    finished = Finished.from_journal(out_dir, index.n_runs) if resuming \
        else Finished(index.n_runs)
    resumed = finished.count
    pending = PendingRuns(sweep, lambda i: i not in finished, index.n_runs - resumed)
    executor = executor or LocalExecutor()
    first = next(iter(pending), None)
    if first is not None:  # before the folder is made: a fixed sweep file is then no
        _check_observables(sweep, first, executor)  # "other sweep"
    if not resuming:
        _create_folder(out_dir, sweep, index)
    state = _State(sweep, index, out_dir, finished, on_progress, on_resumed)
    state.progress()
    for i in range(index.n_runs):  # a kill between a run's journal line and the end of
        if i in finished and index.wants_checkpoints(i):  # its checkpoint
            drop_checkpoint(out_dir, i)

    def stop() -> bool:
        return should_stop is not None and should_stop()

    journal = Journal(out_dir)
    try:
        executor.run_sweep_runs(pending, sweep.keep, out_dir,
                                lambda run, result: state.finish(run, result, journal), stop,
                                on_resumed=state.resumed_run)
    finally:
        journal.close()
        state.write_tables()
    status = "completed" if finished.count == index.n_runs else "cancelled"
    if status == "completed" and sweep.analysis is not None:
        write_sensitivity(out_dir, sweep)
    done, failed = state.counts()
    return SweepOutcome(status, done, failed, index.n_runs, out_dir, resumed,
                        dict(state.resumed))


class _State:
    """What the runner holds while a sweep runs: which runs finished (`Finished`: O(1)
    per run, the records stay in the journal) and the progress reporting."""

    def __init__(self, sweep: Sweep, index: RunIndex, out_dir: Path, finished: Finished,
                 on_progress: Callable[[SweepProgress], None] | None,
                 on_resumed: Callable[[int, int | None], None] | None = None):
        self.sweep, self.index, self.out_dir = sweep, index, out_dir
        self.finished = finished
        self.on_progress = on_progress
        self.on_resumed = on_resumed
        self.resumed: dict[int, int] = {}  # run -> the checkpoint's step it went on from
        self.last_tables = time.monotonic()
        self.table_interval = TABLE_INTERVAL

    def counts(self) -> tuple[int, int]:
        return self.finished.count - self.finished.failed, self.finished.failed

    def progress(self) -> None:
        if self.on_progress is not None:
            done, failed = self.counts()
            self.on_progress(SweepProgress(done, failed, self.index.n_runs))

    def resumed_run(self, run: SweepRun, step: int | None, why: str | None = None) -> None:
        """Run `run` goes on from its checkpoint at `step` (None: refused, from step 0)."""
        if step is None:
            self.resumed.pop(run.index, None)
        else:
            self.resumed[run.index] = step
        if self.on_resumed is not None:
            self.on_resumed(run.index, step)

    def finish(self, run: SweepRun, result: RunResult, journal: Journal) -> None:
        """Record one finished run. The journal line goes last: it is the resume state,
        so a run whose line is missing is redone (and its summary rewritten); then a
        checkpointed run's checkpoint is dropped."""
        step = result.extra.get("resumed_from_step")
        if step is not None and self.resumed.get(run.index) != step:
            self.resumed_run(run, step)  # told only now (a Ray task's run)
        record = _record(self.sweep, run, result)
        if self.sweep.keep == "summaries":
            summary = run_summary(run.scenario, result, frames=0, files=["summary.json"])
            summary["sweep_run"] = {"run": run.index, "point": run.point,
                                    "replica": run.replica, "seed": run.seed,
                                    "values": run.values}
            summary["measures"] = record["measures"]  # this run's columns of runs.csv
            folder = self.out_dir / "runs" / str(run.index)
            folder.mkdir(parents=True, exist_ok=True)
            atomic_write(folder / "summary.json",
                         json.dumps(summary, indent=2, allow_nan=False), durable=False)
        offset = journal.append(record)
        if wants_checkpoints(run) and self.sweep.keep != "all":
            drop_checkpoint(self.out_dir, run.index)
        self.finished.add(run.index, offset, record["status"] == "completed")
        self.progress()
        if time.monotonic() - self.last_tables >= self.table_interval:
            self.write_tables()

    def write_tables(self) -> None:
        """Rewrite the tables; the next periodic rewrite waits at least 10 times as long
        as this one took, so a sweep with long series does not spend its time in CSV."""
        t0 = time.monotonic()
        write_tables(self.out_dir, self.sweep, self.index, self.finished)
        self.last_tables = time.monotonic()
        self.table_interval = max(TABLE_INTERVAL, 10 * (self.last_tables - t0))


def _record(sweep: Sweep, run: SweepRun, result: RunResult) -> dict[str, Any]:
    """The journal record of a finished run (measures None for a diverged run)."""
    obs = result.observables
    completed = result.status == "completed"
    if completed:
        _require_observables(sweep, run, obs)
    tol = run.scenario.convergence.tolerance
    measures: dict[str, float | None] = {}
    for name, m in sweep.measure.items():
        cols = reduce_run(name, m, obs, tol, run.scenario.n_agents) if completed \
            else dict.fromkeys(m.run_columns(name))
        measures.update({k: _finite(v) for k, v in cols.items()})
    series: dict[str, list[Any]] = {}
    if completed and sweep.series:
        series = {"step": [int(s) for s in obs["step"]], "time": [float(t) for t in obs["time"]]}
        series.update({o: [_finite(float(v)) for v in obs[o]] for o in sweep.series})
    return {"run": run.index, "status": result.status, "seed": run.seed,
            "measures": measures, "series": series,
            "error": result.error["message"] if result.error else None}


def _finite(v: float | None) -> float | None:
    return v if v is not None and math.isfinite(v) else None


def _require_observables(sweep: Sweep, run: SweepRun, obs: dict[str, Any]) -> None:
    """SweepError naming each measure or series whose observable this run does not have."""
    have = sorted(k for k in obs if k not in ("step", "time"))
    errors = [FieldError(loc=loc, type="unknown_observable",
                         msg=f"{name!r} is not an observable of runs[{run.index}] "
                         f"({run.scenario.model.kind}); it has: {', '.join(have)}")
              for loc, name in [*((f"measure.{k}.observable", m.observable)
                                  for k, m in sweep.measure.items()),
                                *((f"series.{i}", o) for i, o in enumerate(sweep.series))]
              if name not in obs or name in ("step", "time")]
    if errors:
        raise SweepError(errors)


def _check_observables(sweep: Sweep, first: SweepRun, executor: Executor) -> None:
    """Before any run: a one-step run of the first scenario shows which observables the
    model has, so a misspelt observable fails now, not after the first full run."""
    if not sweep.measure and not sweep.series:
        return

    doc = first.scenario.model_dump(mode="json")
    doc["time"]["steps"] = 1
    doc["recording"]["every"] = 0
    try:
        probe = Scenario.model_validate(doc)
    except ValidationError:
        return  # a model that needs more steps: checked on the first result instead
    _require_observables(sweep, first, executor.probe(probe).observables)


def _check_folder(out_dir: Path, sweep: Sweep) -> bool:
    """Whether `out_dir` holds this very sweep (to resume); False when it is absent or
    empty; SweepFolderConflict when it holds anything else."""
    path = out_dir / SWEEP_FILE
    if path.exists():
        try:
            old = json.loads(path.read_text())["sweep"]
        except (ValueError, KeyError, TypeError):
            raise SweepFolderConflict(f"{path} is not a flocklab sweep file") from None
        new = sweep.model_dump(mode="json")
        # A field added since the folder was made (design, analysis, labels) matches when
        # this sweep leaves it at its default.
        new = {k: v for k, v in new.items()
               if k in old or v != type(sweep).model_fields[k].get_default()}
        if old != new:
            raise SweepFolderConflict(
                f"{out_dir} holds a different sweep ({old.get('name')!r}; its sweep.json "
                "differs from this one): choose another folder")
        return True
    if out_dir.exists() and not out_dir.is_dir():
        raise SweepFolderConflict(f"{out_dir} exists and is not a folder")
    if out_dir.exists() and any(out_dir.iterdir()):
        raise SweepFolderConflict(f"{out_dir} exists, is not empty and holds no sweep")
    return False


def _create_folder(out_dir: Path, sweep: Sweep, index: RunIndex) -> None:
    """The folder and its sweep.json: the canonical sweep and every run (written run by
    run, as `json.dumps(doc, indent=2)` of the whole would print it)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {
        "flocklab_version": version(),
        "sweep": sweep.model_dump(mode="json"),
        "base": sweep.base_scenario.model_dump(mode="json"),
        "n_points": sweep.n_points,
        "n_runs": index.n_runs,
        "total_agent_steps": index.total_agent_steps,
        "axes": axis_columns(sweep),
        "measures": list(sweep.measure),
        "series": list(sweep.series),
        "runs": [],
    }
    head = json.dumps(doc, indent=2, allow_nan=False)
    assert head.endswith('"runs": []\n}')
    with atomic_file(out_dir / SWEEP_FILE) as fh:
        fh.write(head[:-len("[]\n}")] + "[")
        sep = "\n    "
        for point in index.points():
            for i, replica, seed in point.runs:
                entry = {"run": i, "point": point.point, "replica": replica, "seed": seed,
                         "values": point.values}
                fh.write(sep + json.dumps(entry, indent=2, allow_nan=False)
                         .replace("\n", "\n    "))
                sep = ",\n    "
        fh.write("\n  ]\n}")
