"""The Olfati-Saber kernel on the per-step schedule (law.py's equations, step.py's
kernels): one replica, parallel over its agents.

State: positions q_i and velocities p_i, kept in the order of a plane grid of cells of
side r, rebuilt each step. The virtual leader moves on its own (q_r(t) = q_r(0) + t p_r,
evaluated at t = step dt); obstacles are a small array of rows. Observables (observe.py)
at observation steps only: each agent's share of the deviation energy and its nearest
obstacle go to the state's spare buffers (dead until the next step writes them), the
graph's components to a union-find forest.
"""

from collections.abc import Mapping

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from ...model import ModelKernel, register_kernel
from ...result import SimulationDiverged
from ...runtime import DevicePolicy, as_real
from ...space.graph import count_roots, reset_parent
from ...space.initial import initial_state, unit_rows
from ...space.plane_grid import PlaneGrid
from ...space.state import SortedState
from . import law
from .fused import OlfatiSaberBatch
from .observe import observe
from .step import step_kernels


@register_kernel
class OlfatiSaberKernel(ModelKernel):
    """One Olfati-Saber replica (Algorithm 1, 2 or 3) on the plane grid."""

    kind = "olfati_saber"
    fused = OlfatiSaberBatch

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        super().__init__(scenario, policy)
        p = scenario.model
        self.n = n = scenario.n_agents
        self.dim = dim = scenario.dimension
        self.alg = p.algorithm
        self.d = p.d
        self.n_obst = len(p.obstacles)
        init = initial_state(scenario)
        self.state = SortedState({"pos": init.positions, "vel": init.velocities})
        self.prm_host = law.parameters(p, scenario.time.dt)
        self.prm = ti.ndarray(float, shape=law.P.size)
        self.prm.from_numpy(as_real(self.prm_host))
        rows = law.obstacle_rows(p)
        self.obst = ti.ndarray(float, shape=rows.shape)
        self.obst.from_numpy(as_real(rows))
        self.bad = ti.ndarray(ti.i32, shape=1)
        self.grid = PlaneGrid(n, p.r, policy, dim)
        self.parent = None  # the graph's forest, allocated at the first observation

    def _kernels(self):
        return step_kernels(self.dim, self.grid.layout, self.alg)

    def step(self, step: int) -> None:
        st = self.state
        st.sort(self.grid, step)
        self.bad.fill(0)
        euler, _ = self._kernels()
        t = step * self.scenario.time.dt
        euler(st["pos"], st["vel"], st.scratch("pos"), st.scratch("vel"), self.prm,
              self.obst, self.n_obst, t, self.bad, *self.grid.view())
        if self.bad.to_numpy()[0]:
            raise SimulationDiverged(step, "position/velocity", law.DIVERGED_CAUSE)
        st.swap("pos")
        st.swap("vel")

    def observe(self, step: int) -> dict[str, float]:
        st = self.state
        st.sort(self.grid, step)
        if self.parent is None:
            self.parent = ti.ndarray(ti.i32, shape=self.n)
        reset_parent(self.parent)
        share, gap = st.scratch("pos"), st.scratch("vel")
        _, kernel = self._kernels()
        kernel(st["pos"], st["vel"], self.prm, self.obst, self.n_obst, self.parent, share,
               gap, *self.grid.view())
        leader = None
        if self.alg >= 2:
            t = step * self.scenario.time.dt
            pr = self.prm_host[law.P.PR:law.P.PR + self.dim]
            leader = self.prm_host[law.P.QR:law.P.QR + self.dim] + t * pr
        return observe(st["pos"], st["vel"], share, gap, int(count_roots(self.parent)),
                       self.d, leader, self.n_obst > 0)

    def frame(self, arrays: list[str]) -> dict[str, np.ndarray]:
        ids = self.state.ids_numpy()
        out = {}
        if "position" in arrays:
            out["position"] = self.state.in_id_order("pos", ids)
        if "velocity" in arrays or "heading" in arrays:
            vel = self.state.in_id_order("vel", ids)
            if "velocity" in arrays:
                out["velocity"] = vel
            if "heading" in arrays:
                out["heading"] = (unit_rows(vel) if self.dim == 3
                                  else np.arctan2(vel[:, 1], vel[:, 0]))
        return out

    def save(self) -> dict[str, np.ndarray]:
        """Checkpoints: the state in its storage order with its ids."""
        return self.state.save()

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        self.state.load(state)

    def convergence_keys(self) -> list[str]:
        return ["velocity_mismatch"]
