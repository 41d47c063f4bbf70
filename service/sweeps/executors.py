"""Where a sweep's runs (and the service's jobs) execute: this process, or a Ray cluster.

An executor takes the pending runs of a sweep and calls `on_result(run, result)` for
each run that finished (completed or diverged), in any order; the runner records it (the
journal, the tables), so recording never depends on where a run ran. Runs stopped by
`should_stop` are not reported: they are redone on resume. Both executors give the same
bits for a run: each run's result is `kernels.run` of its scenario alone, wherever it ran.

- `LocalExecutor`: `kernels.run_batch` in this process (the CLI's and a service worker's
  behaviour before Ray existed). A run's `threads` is capped at the threads this process
  is allotted (`FLOCKLAB_THREADS`, else its CPUs), as a job's is: Taichi starts a pool of
  that many threads and keeps it until it is re-initialised, so a sweep asking for 1024
  left 1,030 threads in the service's worker.
- `RayExecutor` (ray_executor.py): batches of runs as Ray tasks on a cluster; this
  process is only the driver and never initialises Taichi.

`factory.make_executor(config)` picks one; importing this module imports neither Taichi nor
Ray.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol

from flocklab.schemas import Scenario
from flocklab.schemas.sweep import SweepRun

from ..execute import execute_to_dir
from .run_checkpoints import ResumedFn, run_alone, wants_checkpoints

if TYPE_CHECKING:
    from flocklab.kernels import RunResult

# Runs handed to the engine at once (the batch it may fuse into one launch); smaller
# batches report and resume at a finer grain. FLOCKLAB_SWEEP_BATCH_RUNS sets it.
BATCH_RUNS = max(1, int(os.environ.get("FLOCKLAB_SWEEP_BATCH_RUNS", "64")))

ResultFn = Callable[[SweepRun, "RunResult"], None]
StopFn = Callable[[], bool]


@dataclass(frozen=True)
class ExecutorConfig:
    """How to execute: `kind` "local" or "ray"; for Ray the cluster `ray_address`
    ("auto", "host:port" or "ray://host:port"), the CPU threads of each task (a run's own
    `threads` wins), the tasks a Ray worker process runs before it is recycled, and the
    seconds a cancelled task gets to stop before it is killed."""

    kind: Literal["local", "ray"] = "local"
    ray_address: str | None = None
    threads: int = 1
    max_calls: int = 20
    cancel_grace_seconds: float = 5.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class Executor(Protocol):
    """What the sweep runner (and the service's job worker) needs from an executor."""

    def run_sweep_runs(self, runs: Iterable[SweepRun], keep: str, out_dir: Path,
                       on_result: ResultFn, should_stop: StopFn,
                       on_resumed: ResumedFn | None = None) -> None:
        """Run `runs`, taken from the iterable as they go, never all at once (the runner's
        are made lazily; its `len` is the count when it has one); `keep` = "all" writes
        each run's artifacts into out_dir/runs/<i>. Runs with checkpoints go on from
        theirs (run_checkpoints.py), said through `on_resumed` where the executor can
        (else in the result's extra)."""

    def probe(self, scenario: Scenario) -> RunResult:
        """Run a (tiny) scenario and return its result: which observables a model has."""

    def run_job(self, scenario: Scenario, out_dir: Path, *,
                on_progress: Callable[[int, int], None] | None,
                should_stop: StopFn) -> dict[str, Any]:
        """Run one job's scenario into out_dir (execute_to_dir); return its summary."""


def allotted_threads() -> int:
    """The CPU threads this process may give a run (the engine's default)."""
    from flocklab.kernels.runtime import default_threads

    return default_threads()


def fit_threads(run: SweepRun, allowed: int) -> SweepRun:
    """`run` with its scenario's `threads` at most `allowed` (more threads than the
    process's CPUs only contend for them; same seed, same bits whatever the count)."""
    threads = run.scenario.threads
    if threads is None or threads <= allowed:
        return run
    return replace(run, scenario=run.scenario.model_copy(update={"threads": allowed}))


class LocalExecutor:
    """Runs everything in this process, through the engine."""

    def run_sweep_runs(self, runs: Iterable[SweepRun], keep: str, out_dir: Path,
                       on_result: ResultFn, should_stop: StopFn,
                       on_resumed: ResumedFn | None = None) -> None:
        """The runs are taken from `runs` as they go (at most BATCH_RUNS held): a run
        with checkpoints alone (run_checkpoints.py), keep = all runs one by one, the
        others in batches of BATCH_RUNS consecutive runs."""
        allowed = allotted_threads()
        batch: list[SweepRun] = []
        for run in runs:
            if should_stop():
                return
            run = fit_threads(run, allowed)
            if wants_checkpoints(run):
                if not self._batch(batch, on_result, should_stop):
                    return
                result = run_alone(run, keep, out_dir, should_stop, on_resumed)
            elif keep == "all":
                result = run_with_artifacts(run, out_dir, should_stop)
                if result is None:
                    return
            else:
                batch.append(run)
                if len(batch) == BATCH_RUNS and not self._batch(batch, on_result,
                                                                should_stop):
                    return
                continue
            if result is not None:
                on_result(run, result)
        self._batch(batch, on_result, should_stop)

    @staticmethod
    def _batch(batch: list[SweepRun], on_result: ResultFn, should_stop: StopFn) -> bool:
        """Run the runs gathered in `batch` through `kernels.run_batch` (emptying it);
        False when should_stop ended it."""
        if not batch:
            return True
        if should_stop():
            return False
        from flocklab import kernels

        chunk = list(batch)
        batch.clear()

        def done(i: int, result: RunResult) -> None:
            if result.status != "cancelled":  # a cancelled run is redone on resume
                on_result(chunk[i], result)

        kernels.run_batch([r.scenario for r in chunk], on_result=done,
                          should_stop=should_stop)
        return not should_stop()

    def probe(self, scenario: Scenario) -> RunResult:
        from flocklab import kernels

        allowed = allotted_threads()
        if scenario.threads is not None and scenario.threads > allowed:
            scenario = scenario.model_copy(update={"threads": allowed})
        return kernels.run(scenario)

    def run_job(self, scenario: Scenario, out_dir: Path, *,
                on_progress: Callable[[int, int], None] | None,
                should_stop: StopFn) -> dict[str, Any]:
        return execute_to_dir(scenario, out_dir, on_progress=on_progress,
                              should_stop=should_stop)


def run_with_artifacts(run: SweepRun, out_dir: Path, should_stop: StopFn | None
                       ) -> RunResult | None:
    """One keep = all run into out_dir/runs/<index>; None (and no folder) if cancelled."""
    folder = Path(out_dir) / "runs" / str(run.index)
    got: list[RunResult] = []
    execute_to_dir(run.scenario, folder, should_stop=should_stop, overwrite=True,
                   on_result=got.append)
    if got[0].status == "cancelled":
        shutil.rmtree(folder, ignore_errors=True)
        return None
    return got[0]
