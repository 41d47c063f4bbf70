"""The interface every model kernel implements, and the kernel registry.

A `ModelKernel` is one replica on the per-step schedule (kernels/per_step.py drives it
through `observe -> step -> ... -> observe`); the engine knows
nothing of any model's equations. A new model family is one module with a subclass
decorated `@register_kernel` in its package under `kernels/models/`, named in `MODULES`
below.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from flocklab.schemas import Scenario

from .checkpoint import CheckpointUnsupported
from .runtime import DevicePolicy


class ModelKernel(ABC):
    """One model's state and step on the Taichi backend.

    Subclasses allocate their state in `__init__` (from `kernels.space.initial`), advance it in
    `step`, and report observables at the current state in `observe`.
    """

    kind: ClassVar[str]
    # The model's other schedules (`Replicas` classes, kernels/replicas.py), where it has
    # them: fused (many steps of many replicas per launch, one replica per CPU task) and
    # batched (every replica's agents in one launch per step).
    fused: ClassVar[Any] = None
    batched: ClassVar[Any] = None

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        self.scenario = scenario
        self.policy = policy  # how this device builds the grids (runtime.Runtime.policy)

    @abstractmethod
    def step(self, step: int) -> None:
        """Advance from step `step` to `step + 1`. Raises SimulationDiverged on blow-up."""

    @abstractmethod
    def observe(self, step: int) -> dict[str, float]:
        """Observables of the current state (time step * dt). Scalars only."""

    @abstractmethod
    def frame(self, arrays: list[str]) -> dict[str, np.ndarray]:
        """The requested per-agent arrays this model has, in agent-id order."""

    def derived_arrays(self, step: int, names: list[str]) -> dict[str, np.ndarray]:
        """The requested per-agent arrays computed from the state at `step` (names from
        `recording.derived`: "degree", "radius"), in agent-id order. Called after
        `observe(step)` when both are due, before `step(step)`; it must leave the
        trajectory unchanged. The schema refuses a name the model does not list in its
        `derived_arrays`, so a model without any never gets here."""
        raise NotImplementedError(f"model {self.kind} records no derived arrays")

    def save(self) -> dict[str, np.ndarray]:
        """Everything the next `step` and `observe` read, as named arrays (checkpoints,
        kernels/checkpoint.py); `load` puts it back into a kernel built from the same
        scenario. A model that does not implement them has no checkpoints."""
        raise CheckpointUnsupported(f"model {self.kind!r} saves no checkpoints on the "
                                    "per-step schedule")

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        raise CheckpointUnsupported(f"model {self.kind!r} loads no checkpoints")

    def convergence_keys(self) -> list[str]:
        """Observables that go to zero on convergence (time-to-converge is reported)."""
        return []

    def extra(self) -> dict[str, Any]:
        """Run-level results beyond the time series (added to the summary)."""
        return {}


KERNELS: dict[str, type[ModelKernel]] = {}
# Each family's module, which registers its kernel on import (one line per family). The
# engine imports a family only when a scenario of that kind runs: importing them all costs
# about a second of Python at every start, which a short run or a sweep worker would pay.
MODULES = {
    "vicsek": "flocklab.kernels.models.vicsek.kernel",
    "flocking": "flocklab.kernels.models.flocking.kernel",
    "flocking_obstacles": "flocklab.kernels.models.flocking.obstacles",
    "formation": "flocklab.kernels.models.formation.kernel",
    "cucker_smale": "flocklab.kernels.models.cucker_smale.kernel",
    "couzin": "flocklab.kernels.models.couzin.kernel",
    "olfati_saber": "flocklab.kernels.models.olfati_saber.kernel",
}


def kernel_for(kind: str) -> type[ModelKernel]:
    """The kernel class of model `kind`, importing its family's module on first use."""
    if kind not in KERNELS:
        importlib.import_module(MODULES[kind])
    return KERNELS[kind]


def all_kernels() -> dict[str, type[ModelKernel]]:
    """The full registry, every family imported (for tooling and tests)."""
    for kind in MODULES:
        kernel_for(kind)
    return KERNELS


def register_kernel(cls: type[ModelKernel]) -> type[ModelKernel]:
    if cls.kind in KERNELS:
        raise RuntimeError(f"kernel for {cls.kind!r} registered twice")
    KERNELS[cls.kind] = cls
    return cls
