"""The per-step schedule as `Replicas`: one replica, one launch per pass (large N, GPUs).

A `ModelKernel` (kernels/model.py) holds one replica's state and advances it one step at a
time, parallel over its agents. `PerStep` presents it to the driver as a set of one
replica, in the per-step order of old: at step s, observe (when due), then the frame (the
driver records it at the window's end, so a window ending at s observes s first), then
step. A `SimulationDiverged` from a step or an observation ends the replica there.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from flocklab.schemas import Scenario

from . import runtime
from .checkpoint import CheckpointUnsupported
from .model import ModelKernel, kernel_for
from .result import SimulationDiverged

# status() slots
DONE, OBSERVED, END = 0, 1, 2


class PerStep:
    """One scenario's `ModelKernel`, driven window by window."""

    QUEUED = False
    # A step here is a dozen launches or more: the first window is one step, and the
    # driver sizes the next ones from its time.
    FIRST_WINDOW = 1

    def __init__(self, scenarios: list[Scenario]):
        if len(scenarios) != 1:
            raise ValueError("the per-step schedule runs one replica at a time")
        self.scenarios = scenarios
        sc = scenarios[0]
        self.model: ModelKernel = kernel_for(sc.model.kind)(sc, runtime.current().policy)
        self.every = sc.recording.observables_every
        self.end = sc.time.steps
        self.done = 0  # steps taken
        self.observed = -1  # the last step observed
        self.series: dict[str, list[float]] = {"step": []}
        self.error: tuple[int, str, str] | None = None

    def _observe(self, step: int) -> None:
        values = self.model.observe(step)
        self.series["step"].append(step)
        for k, v in values.items():
            self.series.setdefault(k, []).append(v)
        self.observed = step

    def _due(self, step: int) -> bool:
        return step != self.observed and (step % self.every == 0 or step == self.end)

    def advance(self, s0: int, s1: int) -> None:
        """Steps s0 .. s1 - 1 (observed when due, then stepped), and step s1 observed when
        due: the frame the driver records at s1 then follows its observation, as it always
        has on this path."""
        if self.error is not None:
            return
        try:
            for s in range(s0, min(s1, self.end + 1)):
                if self._due(s):
                    self._observe(s)
                if s < self.end:
                    self.model.step(s)
                    self.done = s + 1
            if s1 <= self.end and self._due(s1):
                self._observe(s1)
        except SimulationDiverged as exc:
            self.error = (exc.step, exc.quantity, exc.cause)

    def end_at(self, step: int) -> None:
        self.end = min(self.end, step)

    def status(self) -> np.ndarray:
        return np.array([self.done, self.observed, self.end], dtype=np.int64)

    def observables(self, b: int, status: np.ndarray) -> dict[str, np.ndarray]:
        rec = self.scenarios[0].recording
        return {k: np.asarray(v, dtype=np.float64) for k, v in self.series.items()
                if k == "step" or rec.wants(k)}

    def frame(self, b: int, arrays: list[str], step: int) -> dict[str, np.ndarray]:
        values = self.model.frame(arrays)
        derived = self.scenarios[0].recording.derived
        if derived:
            values.update(self.model.derived_arrays(step, derived))
        return values

    def save(self) -> dict[str, np.ndarray]:
        """The counters, the series so far (their names in order) and the model's state."""
        if self.error is not None:
            raise CheckpointUnsupported("a diverged replica is not checkpointed")
        keys = list(self.series)
        return {"per_step/counters": np.array([self.done, self.observed, self.end], np.int64),
                "per_step/series": np.array(keys),
                **{f"series/{k}": np.asarray(self.series[k], np.float64) for k in keys},
                **{f"model/{k}": v for k, v in self.model.save().items()}}

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        self.done, self.observed, self.end = (int(v) for v in state["per_step/counters"])
        # Python floats again: the series' values as `observe` gave them, bit for bit.
        self.series = {str(k): state[f"series/{k}"].tolist() for k in state["per_step/series"]}
        self.series["step"] = [int(s) for s in self.series["step"]]
        self.model.load({k.removeprefix("model/"): v for k, v in state.items()
                         if k.startswith("model/")})

    def convergence_keys(self) -> list[str]:
        return self.model.convergence_keys()

    def extra(self, b: int, status: np.ndarray) -> dict[str, Any]:
        return self.model.extra()

    def divergence(self, b: int, status: np.ndarray) -> tuple[int, str, str] | None:
        return self.error
