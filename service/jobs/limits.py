"""Admission limits: what a scenario may ask of this service (R12, R13).

The schema bounds what is meaningful; these bound what this deployment accepts, and what
a run costs (trajectory bytes, memory, observable rows). `admission.admit` applies them,
in the API before storing a job and in the worker before running it. Pure Python (no
FastAPI, no Taichi) because both processes import it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from flocklab.schemas import FieldError, Scenario

# Recordable arrays with one value per coordinate; the others (heading, degree, radius)
# have one value per agent.
VECTOR_ARRAYS = frozenset({"position", "velocity"})
# Bytes per stored value of the frames (`recording.precision`).
BYTES_PER_VALUE = {"float64": 8, "float32": 4}
# The periodic image (one int32 per coordinate) that goes with each recorded position in a
# periodic box (written when it is exact; counted whenever it may be, to stay conservative).
IMAGE_BYTES_PER_AXIS = 4
# Per-agent working set of the engine: state arrays double-buffered, the cell grid's
# count/offset/sorted-index arrays and per-agent observables scratch. Measured peak RSS
# growth (`bench/memory.py`, via `python -m bench.bench` and `bench.dimensions`) at
# N = 10^6, float64: 105-157 B in 2D, 150-180 B in 3D; 250 keeps a margin for the
# allocator's leftovers.
ENGINE_BYTES_PER_AGENT = 250
# Fixed cost of a worker with Taichi loaded and kernels compiled.
ENGINE_BASE_BYTES = 256 * 2**20
# An agent may move at most this many interaction radii in one step (and never more than
# a periodic box's side): beyond that no neighbour relation survives a step and the run
# only produces huge coordinates (v0 = 1e300 gave positions near 1e283 in a box of 7).
MAX_STEP_RADII = 10.0


@dataclass(frozen=True)
class Limits:
    """Per-job maxima; all are checked, the first violated ones are reported by field.
    A sweep's every run is held to them, and the sweep as a whole to the `max_sweep_*`
    ones (see `admission`)."""

    max_agents: int
    max_steps: int
    max_trajectory_bytes: int
    max_memory_bytes: int
    # Rows of the observables time series (CSV, /metrics): steps / observables_every.
    max_observable_rows: int = 1_000_000
    max_sweep_runs: int = 100_000
    max_sweep_agent_steps: int = 10**12

    def to_dict(self) -> dict[str, int]:
        return asdict(self)


def recorded_components(scenario: Scenario) -> int:
    """Values stored per agent and frame: the recorded arrays the model actually has."""
    model = type(scenario.model)
    has = {*model.state_arrays, *model.derived_arrays}
    return sum(scenario.dimension if a in VECTOR_ARRAYS else 1
               for a in set(scenario.recording.arrays) if a in has)


def trajectory_bytes(scenario: Scenario) -> int:
    """Size of the recorded frames, uncompressed: frames x N x (components x the bytes of
    `recording.precision`, plus the periodic image beside the positions)."""
    per_agent = recorded_components(scenario) * BYTES_PER_VALUE[scenario.recording.precision]
    if "position" in scenario.recording.arrays and scenario.space.kind == "periodic":
        per_agent += IMAGE_BYTES_PER_AXIS * scenario.dimension
    return scenario.n_frames * scenario.n_agents * per_agent


def estimated_memory_bytes(scenario: Scenario) -> int:
    """Peak memory of a run: engine state plus one frame in flight (frames stream to disk)."""
    n = scenario.n_agents
    frame = n * recorded_components(scenario) * 8  # the engine hands frames over in float64
    return ENGINE_BASE_BYTES + n * ENGINE_BYTES_PER_AGENT + frame


def observable_rows(scenario: Scenario) -> int:
    """Rows of the observables series: every `observables_every` steps, plus the start and
    the end."""
    return scenario.time.steps // scenario.recording.observables_every + 2


def _speeds(scenario: Scenario) -> list[tuple[str, float]]:
    """Every speed the scenario sets, with the field that sets it."""
    out = []
    v0 = getattr(scenario.model, "v0", None)
    if isinstance(v0, int | float):
        out.append(("model.v0", float(v0)))
    if "velocity" in type(scenario.model).state_arrays:  # double integrators start moving
        initial = scenario.initial
        speed_range = getattr(initial, "speed_range", None)
        if speed_range is not None:
            out.append(("initial.speed_range", float(speed_range[1])))
        velocities = getattr(initial, "velocities", None)
        if velocities:
            out.append(("initial.velocities",
                        max(math.hypot(vx, vy) for vx, vy in velocities)))
    return out


def max_step_length(scenario: Scenario) -> float | None:
    """The longest distance an agent may travel in one step: MAX_STEP_RADII radii, at most
    the periodic box's side; None when the scenario has neither length scale."""
    scales = []
    if scenario.neighbours is not None:
        scales.append(MAX_STEP_RADII * scenario.neighbours.radius)
    side = getattr(scenario.space, "L", None)
    if side is not None:
        scales.append(float(side))
    return min(scales) if scales else None


def check_limits(scenario: Scenario, limits: Limits) -> list[FieldError]:
    """Every limit the scenario exceeds, as field errors (empty when admissible)."""
    errors = []
    n, steps = scenario.n_agents, scenario.time.steps
    if n > limits.max_agents:
        errors.append(_err("initial.N", f"N = {n} exceeds this service's limit of "
                                        f"{limits.max_agents} agents"))
    if steps > limits.max_steps:
        errors.append(_err("time.steps", f"steps = {steps} exceeds this service's limit of "
                                         f"{limits.max_steps}"))
    traj = trajectory_bytes(scenario)
    if traj > limits.max_trajectory_bytes:
        errors.append(_err("recording.every", f"the trajectory would take {_size(traj)} "
                           f"({scenario.n_frames} frames x {n} agents x "
                           f"{recorded_components(scenario)} values x "
                           f"{BYTES_PER_VALUE[scenario.recording.precision]} B), "
                           f"over the limit of {_size(limits.max_trajectory_bytes)}; record "
                           f"less often or fewer arrays"))
    mem = estimated_memory_bytes(scenario)
    if mem > limits.max_memory_bytes:
        errors.append(_err("initial.N", f"the run needs about {_size(mem)} of memory, over "
                                        f"the limit of {_size(limits.max_memory_bytes)}"))
    rows = observable_rows(scenario)
    if rows > limits.max_observable_rows:
        errors.append(_err("recording.observables_every", (
            f"the observables would have {rows} rows (steps / observables_every), over this "
            f"service's limit of {limits.max_observable_rows}; evaluate them less often")))
    longest = max_step_length(scenario)
    if longest is not None:
        dt = scenario.time.dt
        for loc, speed in _speeds(scenario):
            if speed * dt > longest:
                errors.append(FieldError(loc=loc, type="speed_too_large", msg=(
                    f"a speed of {speed:g} moves an agent {speed * dt:g} per step (dt = "
                    f"{dt:g}), more than {longest:g} ({MAX_STEP_RADII:g} neighbour radii, at "
                    f"most the box side): lower the speed or dt")))
    return errors


def _err(loc: str, msg: str) -> FieldError:
    return FieldError(loc=loc, msg=msg, type="limit_exceeded")


def _size(n: float) -> str:
    units = ["B", "KiB", "MiB", "GiB", "TiB"]
    while n >= 1024 and len(units) > 1:
        n /= 1024
        units.pop(0)
    return f"{n:.0f} {units[0]}" if units[0] == "B" else f"{n:.1f} {units[0]}"
