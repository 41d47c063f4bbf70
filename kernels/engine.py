"""The one engine entry: `run(scenario, path=...) -> RunResult`, and `run_batch`.

Called by the CLI, the service's worker processes and any batch driver alike. It knows
nothing of jobs, HTTP or files: frames go to a `FrameSink`, progress to a callback, and
cancellation comes from polling `should_stop` between windows. It picks the schedule (the
per-step, fused or batched `Replicas` of the scenario's model) and hands it to the one
driver, kernels/driver.py.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from flocklab.schemas import Scenario

from . import runtime
from .checkpoint import CheckpointFn, State
from .driver import Hooks, ProgressFn, StopFn, run_replicas
from .live import OBSERVATIONS_INTERVAL, ObservationsFn
from .model import kernel_for
from .per_step import PerStep
from .replicas import Replicas
from .result import FrameSink, RunResult

PATHS = ("auto", "per_step", "fused", "batched")
# The fused schedule runs one replica per CPU task, serially inside: it beats the per-step
# one (parallel over agents, one launch per pass) up to about this N on this CPU.
FUSED_MAX_N = 10_000
# Replicas per fused or batched launch: enough to fill the cores, few enough to poll for a
# stop.
BATCH_AGENTS = 400_000
# The fused schedule writes each observation's step number into a row of the kernels' float
# type: exact below 2^24 in float32, so longer float32 runs take the per-step schedule.
FUSED_MAX_STEPS_FLOAT32 = 2**24


class PathUnavailable(ValueError):
    """The schedule asked for (`path=`) does not cover this scenario; the message says why."""


def run(
    scenario: Scenario,
    *,
    path: str = "auto",
    sink: FrameSink | None = None,
    on_progress: ProgressFn | None = None,
    should_stop: StopFn | None = None,
    on_observations: ObservationsFn | None = None,
    observations_interval: float = OBSERVATIONS_INTERVAL,
    on_checkpoint: CheckpointFn | None = None,
    resume: State | None = None,
) -> RunResult:
    """Run `scenario` to the end, to cancellation, or to numerical blow-up.

    `path` is the schedule: "per_step", "fused", "batched", or "auto" (decided from the
    scenario and the backend alone, `choose_path`); the result's `extra["engine_path"]`
    names the one that ran. Observables are evaluated every `recording.observables_every`
    steps and at the end; frames every `recording.every` steps and at the end. A blow-up
    returns status "diverged" with the step and likely cause; what was recorded before it
    is kept. `on_observations` gets the observation rows computed so far while the run goes
    on, in batches at most every `observations_interval` seconds (see kernels/live.py); the
    result's `observables` hold them all. With `recording.checkpoint_every` (or
    `checkpoint_seconds`), `on_checkpoint(step, state)` gets the whole state at those
    steps (kernels/checkpoint.py); `resume=state` continues a run from one, on the same
    schedule, to the bits the run would have had uninterrupted.
    """
    rt = runtime.ensure(scenario.backend, scenario.threads, scenario.precision)
    name, make = schedule(scenario, rt.backend, path)
    hooks = Hooks(on_progress, should_stop, on_observations, observations_interval,
                  on_checkpoint if scenario.recording.checkpoints else None)
    return run_replicas(make, [scenario], path=name, backend=rt.backend, sinks=[sink],
                        hooks=hooks, resume=resume)[0]


def _uncovered(scenario: Scenario, backend: str, path: str) -> str | None:
    """Why the schedule `path` ("fused" or "batched") cannot run `scenario` on `backend`
    (None: it can)."""
    cls = getattr(kernel_for(scenario.model.kind), path)
    if cls is None:
        return f"model {scenario.model.kind!r} has none"
    if path == "fused" and backend != "cpu":
        return "it runs on the CPU backend only (a GPU wants parallel agents)"
    if path == "fused" and scenario.precision == "float32" and (
            scenario.time.steps >= FUSED_MAX_STEPS_FLOAT32):
        return (f"float32 runs of {FUSED_MAX_STEPS_FLOAT32} steps or more take the per-step "
                "schedule (the step numbers of its observations would round)")
    if scenario.neighbours is not None and scenario.neighbours.topological:
        return "topological neighbours run on the per-step schedule only"
    if scenario.dimension not in cls.dimensions:
        return f"it runs space.dimension {' or '.join(map(str, cls.dimensions))} only"
    if scenario.recording.enabled and scenario.recording.derived:
        return "it records no derived arrays (recording.derived: take the per-step schedule)"
    if cls.batch_key(scenario) is None:
        return "it does not cover this scenario's options (e.g. the integrator)"
    return None


def choose_path(scenario: Scenario, backend: str) -> str:
    """The schedule "auto" takes: decided from the scenario and the backend alone, so a
    run's bits never depend on the company it keeps. The fused one on the CPU up to
    FUSED_MAX_N agents where it covers the scenario, else the per-step one."""
    if scenario.n_agents <= FUSED_MAX_N and _uncovered(scenario, backend, "fused") is None:
        return "fused"
    return "per_step"


def schedule(scenario: Scenario, backend: str, path: str = "auto"
             ) -> tuple[str, Callable[[list[Scenario]], Replicas]]:
    """(the schedule's name, its `Replicas` class) for `scenario` on `backend`. Raises
    PathUnavailable when an explicitly asked-for schedule does not cover it."""
    if path not in PATHS:
        raise PathUnavailable(f"path {path!r}: one of {', '.join(PATHS)}")
    if path == "auto":
        path = choose_path(scenario, backend)
    if path == "per_step":
        return path, PerStep
    why = _uncovered(scenario, backend, path)
    if why is not None:
        raise PathUnavailable(f"the {path} schedule is not available here: {why}")
    return path, getattr(kernel_for(scenario.model.kind), path)


ResultFn = Callable[[int, RunResult], None]


def run_batch(
    scenarios: Sequence[Scenario],
    *,
    path: str = "auto",
    on_result: ResultFn | None = None,
    should_stop: StopFn | None = None,
) -> list[RunResult]:
    """Run many scenarios (a sweep's runs); results in input order.

    Each result is bit-identical to `run(scenario, path=path)` alone: the schedule is chosen
    from each scenario by itself, never from its companions. `on_result(index, result)` is
    called as each run finishes. Once `should_stop()` is true, the runs in progress end
    "cancelled" and the runs not yet started are left out of the returned list.
    """
    results: dict[int, RunResult] = {}
    for group in _batches(scenarios, path):
        if should_stop is not None and should_stop():
            break
        first = scenarios[group[0]]
        rt = runtime.ensure(first.backend, first.threads, first.precision)
        name, make = schedule(first, rt.backend, path)
        done = run_replicas(make, [scenarios[i] for i in group], path=name,
                            backend=rt.backend, hooks=Hooks(should_stop=should_stop))
        for i, res in zip(group, done, strict=True):
            results[i] = res
            if on_result is not None:
                on_result(i, res)
    return [results[i] for i in sorted(results)]


def _group_key(scenario: Scenario, path: str) -> tuple | None:
    """The launch group of `scenario` (None: a group of its own, the per-step schedule)."""
    name, make = schedule(scenario, runtime.resolve_backend(scenario.backend), path)
    if name == "per_step":
        return None
    return (scenario.backend, scenario.threads, scenario.precision, name,
            make.batch_key(scenario))


def _batches(scenarios: Sequence[Scenario], path: str = "auto") -> list[list[int]]:
    """Indices grouped into launches: same backend, threads, precision, schedule and batch
    key, at most BATCH_AGENTS agents each; a per-step scenario is a group of its own."""
    groups: dict[tuple, list[list[int]]] = {}
    out: list[list[int]] = []
    for i, sc in enumerate(scenarios):
        key = _group_key(sc, path)
        if key is None:
            out.append([i])
            continue
        lanes = groups.setdefault(key, [[]])
        if lanes[-1] and sum(scenarios[j].n_agents for j in lanes[-1]) + sc.n_agents > (
                BATCH_AGENTS):
            lanes.append([])
        lanes[-1].append(i)
    out.extend(g for lanes in groups.values() for g in lanes if g)
    return sorted(out)
