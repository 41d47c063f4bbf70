"""What one engine run returns, and the errors it raises. numpy only."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np

Status = Literal["completed", "cancelled", "diverged"]


class FrameSink(Protocol):
    """Receives recorded frames as they are produced (agent-id order)."""

    def frame(self, step: int, time: float, arrays: dict[str, np.ndarray]) -> None: ...


@dataclass
class RunResult:
    """Outcome of `kernels.run`.

    `observables` maps a name to a 1-D array over evaluation times; it always holds
    "step" and "time". `final` is the last value of every observable; `convergence` maps a
    converging quantity to the first time after which it stays below the tolerance (None
    when it never does). `error` is set when status is "diverged".
    """

    status: Status
    backend: str
    steps: int
    wall_seconds: float
    n_agents: int
    observables: dict[str, np.ndarray]
    final: dict[str, Any]
    convergence: dict[str, float | None]
    extra: dict[str, Any] = field(default_factory=dict)
    error: dict[str, Any] | None = None

    @property
    def agent_steps_per_second(self) -> float:
        return self.n_agents * self.steps / self.wall_seconds if self.wall_seconds > 0 else 0.0

    def summary(self) -> dict[str, Any]:
        """The JSON-ready summary (documented in docs/OUTPUTS.md, written as summary.json)."""
        return {
            "status": self.status,
            "backend": self.backend,
            "n_agents": self.n_agents,
            "steps": self.steps,
            "wall_seconds": self.wall_seconds,
            "agent_steps_per_second": self.agent_steps_per_second,
            "final": {k: v if np.isfinite(v) else None for k, v in self.final.items()},
            "convergence": self.convergence,
            "error": self.error,
            **self.extra,
        }


class SimulationDiverged(RuntimeError):
    """A step produced a non-finite or runaway value. Carries the step and likely cause."""

    def __init__(self, step: int, quantity: str, cause: str):
        self.step = step
        self.quantity = quantity
        self.cause = cause
        super().__init__(f"step {step}: non-finite or runaway {quantity}; likely cause: {cause}")


class BackendUnavailable(RuntimeError):
    """The requested Taichi backend cannot run on this machine."""
