"""The bodies of flocklab's Ray tasks: what runs inside a Ray worker process.

Each function is wrapped with `ray.remote` by ray_executor.py (which sets the task's CPUs,
GPUs, retries and `max_calls`); Ray imports this module on the worker by name, so the
worker needs flocklab installed (`pip install 'flocklab[ray]'` on every node). Taichi is
initialised here, on the first task a worker process runs (`kernels.runtime.ensure`, called
by the engine), and reused by its later tasks with the same backend and thread count;
the worker process is recycled after `max_calls` tasks, so memory stays flat.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from flocklab.schemas import Scenario
from flocklab.schemas.sweep import SweepRun

if TYPE_CHECKING:
    from flocklab.kernels import RunResult


def _use_threads(threads: int) -> None:
    """CPU threads for runs that name none = the CPUs this task reserved (num_cpus)."""
    os.environ["FLOCKLAB_THREADS"] = str(threads)


def run_chunk(runs: list[SweepRun], keep: str, out_dir: str, threads: int
              ) -> list[tuple[int, RunResult]]:
    """Run consecutive sweep runs through `kernels.run_batch` (one fused launch where the
    engine can), or, for keep = all, one by one into out_dir/runs/<i> (a path every node
    can write); runs with checkpoints one by one, each on from its checkpoint under
    out_dir/runs (run_checkpoints.py: out_dir must then be a path every node can write,
    whatever `keep`), so a task Ray retries after a lost worker goes on from there.
    Returns (position in `runs`, result) for each finished run."""
    _use_threads(threads)
    from .run_checkpoints import run_alone, wants_checkpoints

    done = []
    rest = []
    for i, run in enumerate(runs):
        if not wants_checkpoints(run):
            rest.append(i)
            continue
        result = run_alone(run, keep, Path(out_dir), None)
        if result is not None:
            done.append((i, result))
    if keep == "all":
        from .executors import run_with_artifacts

        for i in rest:
            result = run_with_artifacts(runs[i], Path(out_dir), None)
            if result is not None:
                done.append((i, result))
        return done
    from flocklab import kernels

    results = kernels.run_batch([runs[i].scenario for i in rest]) if rest else []
    return done + [(i, r) for i, r in zip(rest, results, strict=True)
                   if r.status != "cancelled"]


def probe(scenario: Scenario, threads: int) -> RunResult:
    """One (tiny) run: the sweep runner learns which observables the model has."""
    _use_threads(threads)
    from flocklab import kernels

    return kernels.run(scenario)


def run_job(scenario: Scenario, out_dir: str, threads: int) -> dict[str, Any]:
    """A service job: the scenario's artifacts into out_dir (the attempt's folder under
    the service's results root, which every node must be able to write)."""
    _use_threads(threads)
    from flocklab.service.execute import execute_to_dir

    return execute_to_dir(scenario, Path(out_dir))
