"""The one engine entry: `run(scenario) -> RunResult`.

Called by the CLI, the service's worker processes and any batch driver alike. It knows
nothing of jobs, HTTP or files: frames go to a `FrameSink`, progress to a callback, and
cancellation comes from polling `should_stop` between steps.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from flocklab.schemas import Scenario

from . import batch, runtime
from .checks import run_checks
from .live import OBSERVATIONS_INTERVAL, ObservationFeed, ObservationsFn
from .model import ModelKernel, kernel_for
from .result import FrameSink, RunResult, SimulationDiverged

ProgressFn = Callable[[int, int], None]
StopFn = Callable[[], bool]
PROGRESS_INTERVAL = 0.2  # seconds between progress callbacks
STOP_INTERVAL = 0.05  # seconds between cancellation polls


def run(
    scenario: Scenario,
    *,
    sink: FrameSink | None = None,
    on_progress: ProgressFn | None = None,
    should_stop: StopFn | None = None,
    on_observations: ObservationsFn | None = None,
    observations_interval: float = OBSERVATIONS_INTERVAL,
) -> RunResult:
    """Run `scenario` to the end, to cancellation, or to numerical blow-up.

    Observables are evaluated every `recording.observables_every` steps and at the end;
    frames every `recording.every` steps and at the end. A blow-up returns status
    "diverged" with the step and likely cause; what was recorded before it is kept.
    `on_observations` gets the observation rows computed so far while the run goes on, in
    batches at most every `observations_interval` seconds (see kernels/live.py); the
    result's `observables` hold them all.
    """
    rt = runtime.ensure(scenario.backend, scenario.threads, scenario.precision)
    make = fused_batch(scenario, rt.backend)
    if make is not None:
        return batch.run_batch(make, [scenario], backend=rt.backend, sinks=[sink],
                               on_progress=on_progress, should_stop=should_stop,
                               on_observations=on_observations,
                               observations_interval=observations_interval)[0]
    t0 = time.perf_counter()
    model: ModelKernel = kernel_for(scenario.model.kind)(scenario, rt.policy)
    setup_seconds = time.perf_counter() - t0
    rec = scenario.recording
    steps = scenario.time.steps
    dt = scenario.time.dt
    arrays = [a for a in rec.arrays if a in type(scenario.model).state_arrays]
    derived = rec.derived  # degree, radius: computed from the state at the frame's step
    series: dict[str, list[float]] = {"step": [], "time": []}
    status, error, done = "completed", None, 0
    last_progress = last_poll = time.perf_counter()
    feed = (None if on_observations is None
            else ObservationFeed(on_observations, rec.observables, observations_interval))

    def observe(step: int) -> None:
        values = model.observe(step)
        series["step"].append(step)
        series["time"].append(step * dt)
        for k, v in values.items():
            series.setdefault(k, []).append(v)

    def record(step: int) -> None:
        if sink is not None and rec.enabled and (arrays or derived):
            values = model.frame(arrays)
            if derived:
                values.update(model.derived_arrays(step, derived))
            sink.frame(step, step * dt, values)

    try:
        for step in range(steps):
            if step % rec.observables_every == 0:
                observe(step)
            if rec.enabled and step % rec.every == 0:
                record(step)
            model.step(step)
            done = step + 1
            now = time.perf_counter()
            if should_stop is not None and now - last_poll >= STOP_INTERVAL:
                last_poll = now
                if should_stop():
                    status = "cancelled"
                    break
            if on_progress is not None and now - last_progress >= PROGRESS_INTERVAL:
                last_progress = now
                on_progress(done, steps)
            if feed is not None and feed.due(now):
                feed.send(series, now)
        # The final state, observed (its grid build may still find a runaway) and recorded.
        if not series["step"] or series["step"][-1] != done:
            observe(done)
        record(done)
    except SimulationDiverged as exc:
        status = "diverged"
        error = {
            "step": exc.step,
            "time": exc.step * dt,
            "quantity": exc.quantity,
            "cause": exc.cause,
            "message": str(exc),
        }
    if status != "diverged" and on_progress is not None:
        on_progress(done, steps)
    wall = time.perf_counter() - t0
    obs = {k: np.asarray(v, dtype=np.float64) for k, v in series.items()
           if k in ("step", "time") or rec.wants(k)}
    final = {k: float(v[-1]) for k, v in obs.items() if len(v)}
    tol = scenario.convergence.tolerance
    convergence = {k: time_to_converge(obs["time"], obs[k], tol)
                   for k in model.convergence_keys() if k in obs}
    return RunResult(
        status=status,
        backend=rt.backend,
        steps=done,
        wall_seconds=wall,
        n_agents=scenario.n_agents,
        observables=obs,
        final=final,
        convergence=convergence,
        extra={"setup_seconds": setup_seconds, "engine_path": "per_step", **model.extra(),
               **run_checks(scenario, obs)},
        error=error,
    )


ResultFn = Callable[[int, RunResult], None]
# The small-N path runs one replica per CPU task, serially inside: it beats the per-step
# path (parallel over agents, one launch per pass) up to about this N on this CPU.
FUSED_MAX_N = 10_000
# Replicas per fused launch: enough to fill the cores, few enough to poll for a stop.
BATCH_AGENTS = 400_000
# The fused path writes each observation's step number into a row of the kernels' float
# type: exact below 2^24 in float32, so longer float32 runs take the per-step path.
FUSED_MAX_STEPS_FLOAT32 = 2**24


def _fused_key(scenario: Scenario):
    """The fused batch key of `scenario` (None: the per-step path), backend aside."""
    cls = kernel_for(scenario.model.kind).batch
    if cls is None or scenario.n_agents > FUSED_MAX_N or (
            scenario.precision == "float32"
            and scenario.time.steps >= FUSED_MAX_STEPS_FLOAT32):
        return None
    if scenario.dimension not in cls.dimensions:  # e.g. a 2D-only fused kernel in 3D
        return None
    if scenario.recording.enabled and scenario.recording.derived:
        return None  # the fused kernels keep no per-agent degree or radius at frame steps
    return cls.batch_key(scenario)


def fused_batch(scenario: Scenario, backend: str) -> Callable | None:
    """The fused small-N batch class for `scenario`, or None for the per-step path. Decided
    from the scenario (and the backend that runs it) alone, so a run's bits never depend
    on the company it keeps."""
    if backend != "cpu" or _fused_key(scenario) is None:
        return None
    return kernel_for(scenario.model.kind).batch


def run_batch(
    scenarios: Sequence[Scenario],
    *,
    on_result: ResultFn | None = None,
    should_stop: StopFn | None = None,
) -> list[RunResult]:
    """Run many scenarios (a sweep's runs); results in input order.

    Each result is bit-identical to `run(scenario)` alone: the engine path is chosen from
    each scenario by itself, never from its companions. `on_result(index, result)` is
    called as each run finishes. Once `should_stop()` is true, the runs in progress end
    "cancelled" and the runs not yet started are left out of the returned list.
    """
    results: dict[int, RunResult] = {}
    for group in _batches(scenarios):
        if should_stop is not None and should_stop():
            break
        first = scenarios[group[0]]
        rt = runtime.ensure(first.backend, first.threads, first.precision)
        make = fused_batch(first, rt.backend)
        if make is None:
            done = [run(first, should_stop=should_stop)]
        else:
            done = batch.run_batch(make, [scenarios[i] for i in group], backend=rt.backend,
                                   should_stop=should_stop)
        for i, res in zip(group, done, strict=True):
            results[i] = res
            if on_result is not None:
                on_result(i, res)
    return [results[i] for i in sorted(results)]


def _batches(scenarios: Sequence[Scenario]) -> list[list[int]]:
    """Indices grouped into launches: same backend, threads, precision and fused batch key,
    at most BATCH_AGENTS agents each; a per-step scenario is a group of its own."""
    groups: dict[tuple, list[list[int]]] = {}
    out: list[list[int]] = []
    for i, sc in enumerate(scenarios):
        key = _fused_key(sc)
        if key is None:
            out.append([i])
            continue
        lanes = groups.setdefault((sc.backend, sc.threads, sc.precision, key), [[]])
        if lanes[-1] and sum(scenarios[j].n_agents for j in lanes[-1]) + sc.n_agents > (
                BATCH_AGENTS):
            lanes.append([])
        lanes[-1].append(i)
    out.extend(g for lanes in groups.values() for g in lanes if g)
    return sorted(out)


def time_to_converge(t: np.ndarray, values: np.ndarray, tol: float) -> float | None:
    """First time after which `values` stays below `tol` to the end (None: never)."""
    if len(values) == 0 or not values[-1] < tol:
        return None
    above = np.nonzero(~(values < tol))[0]
    return float(t[0] if len(above) == 0 else t[above[-1] + 1])
