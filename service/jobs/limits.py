"""Admission limits: what a scenario may ask of this service (R12, R13).

The schema bounds what is meaningful; these bound what this deployment accepts. The API
checks them before enqueueing and the worker checks them again before running, so a job
stored by an older, laxer configuration cannot run past the current limits. Pure Python
(no FastAPI, no Taichi) because both processes import it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from schemas import FieldError, Scenario

# Components per agent of each recordable array.
COMPONENTS = {"position": 2, "velocity": 2, "heading": 1}
# Bytes per stored value: the engine may keep float32, but the estimate stays conservative.
BYTES_PER_VALUE = 8
# Per-agent working set of the engine: state arrays double-buffered, the cell grid's
# count/offset/sorted-index arrays and per-agent observables scratch. Measured peak RSS
# growth by `python -m bench.bench` at N = 10^6: 130-140 B (Vicsek) to 370 B (M2/M3).
ENGINE_BYTES_PER_AGENT = 400
# Fixed cost of a worker with Taichi loaded and kernels compiled.
ENGINE_BASE_BYTES = 256 * 2**20


@dataclass(frozen=True)
class Limits:
    """Per-job maxima; all are checked, the first violated ones are reported by field.
    A sweep's every run is held to them, and the sweep as a whole to the `max_sweep_*`
    ones (see `sweep_limits`)."""

    max_agents: int
    max_steps: int
    max_trajectory_bytes: int
    max_memory_bytes: int
    max_sweep_runs: int = 100_000
    max_sweep_agent_steps: int = 10**12

    def to_dict(self) -> dict[str, int]:
        return asdict(self)


def recorded_components(scenario: Scenario) -> int:
    """Values stored per agent and frame: the recorded arrays the model actually has."""
    has = set(type(scenario.model).state_arrays)
    return sum(COMPONENTS[a] for a in set(scenario.recording.arrays) if a in has)


def trajectory_bytes(scenario: Scenario) -> int:
    """Size of the recorded frames: frames x N x components x 8 bytes."""
    return scenario.n_frames * scenario.n_agents * recorded_components(scenario) * BYTES_PER_VALUE


def estimated_memory_bytes(scenario: Scenario) -> int:
    """Peak memory of a run: engine state plus one frame in flight (frames stream to disk)."""
    n = scenario.n_agents
    frame = n * recorded_components(scenario) * BYTES_PER_VALUE
    return ENGINE_BASE_BYTES + n * ENGINE_BYTES_PER_AGENT + frame


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
                           f"{recorded_components(scenario)} values x {BYTES_PER_VALUE} B), "
                           f"over the limit of {_size(limits.max_trajectory_bytes)}; record "
                           f"less often or fewer arrays"))
    mem = estimated_memory_bytes(scenario)
    if mem > limits.max_memory_bytes:
        errors.append(_err("initial.N", f"the run needs about {_size(mem)} of memory, over "
                                        f"the limit of {_size(limits.max_memory_bytes)}"))
    return errors


def _err(loc: str, msg: str) -> FieldError:
    return FieldError(loc=loc, msg=msg, type="limit_exceeded")


def _size(n: float) -> str:
    units = ["B", "KiB", "MiB", "GiB", "TiB"]
    while n >= 1024 and len(units) > 1:
        n /= 1024
        units.pop(0)
    return f"{n:.0f} {units[0]}" if units[0] == "B" else f"{n:.1f} {units[0]}"
