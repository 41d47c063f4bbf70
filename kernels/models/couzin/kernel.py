"""Couzin's model on the per-step schedule (law.py's equations, step.py's kernel): one
replica, parallel over its agents.

State: positions x_i and unit directions e_i (velocity s e_i), kept in the order of a
plane grid of cells of side r_a, rebuilt each step. Observables (observe.py) at
observation steps only.
"""

from collections.abc import Mapping

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from ...model import ModelKernel, register_kernel
from ...result import SimulationDiverged
from ...runtime import DevicePolicy, as_real
from ...space.plane_grid import PlaneGrid
from ...space.state import SortedState
from . import law
from .fused import CouzinBatch
from .observe import observe
from .start import directions
from .step import step_kernel


@register_kernel
class CouzinKernel(ModelKernel):
    """One replica of Couzin's zone model on the plane grid."""

    kind = "couzin"
    fused = CouzinBatch

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        super().__init__(scenario, policy)
        p = scenario.model
        self.n = n = scenario.n_agents
        self.dim = dim = scenario.dimension
        pos, ew = directions(scenario)
        self.state = SortedState({"pos": pos, "ew": ew})
        del pos, ew
        self.prm = ti.ndarray(float, shape=law.P.size)
        self.prm.from_numpy(as_real(law.parameters(p, scenario.time.dt)))
        self.bad = ti.ndarray(ti.i32, shape=1)
        self.grid = PlaneGrid(n, p.r_a, policy, dim)
        self.speed = p.speed

    def step(self, step: int) -> None:
        st = self.state
        st.sort(self.grid, step)
        self.bad.fill(0)
        k0, k1, k2 = (int(k) for k in law.step_keys(self.scenario.seed, step))
        kernel = step_kernel(self.dim, self.grid.layout)
        kernel(st["pos"], st["ew"], st.ids, st.scratch("pos"), st.scratch("ew"), self.prm,
               k0, k1, k2, self.bad, *self.grid.view())
        if self.bad.to_numpy()[0]:
            raise SimulationDiverged(step, "position/direction", law.DIVERGED_CAUSE)
        st.swap("pos")
        st.swap("ew")

    def observe(self, step: int) -> dict[str, float]:
        return observe(self.state["pos"], self.state["ew"])

    def frame(self, arrays: list[str]) -> dict[str, np.ndarray]:
        ids = self.state.ids_numpy()
        out = {}
        if "position" in arrays:
            out["position"] = self.state.in_id_order("pos", ids)
        if "velocity" in arrays or "heading" in arrays:
            ew = self.state.in_id_order("ew", ids)
            if "velocity" in arrays:
                out["velocity"] = self.speed * ew
            if "heading" in arrays:
                out["heading"] = ew if self.dim == 3 else np.arctan2(ew[:, 1], ew[:, 0])
        return out

    def save(self) -> dict[str, np.ndarray]:
        """Checkpoints: the state in its storage order with its ids."""
        return self.state.save()

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        self.state.load(state)
