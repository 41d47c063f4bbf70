"""The Cucker–Smale kernel on the per-step schedule (law.py's equations, step.py's
kernels): one replica, parallel over its agents.

State: positions x_i and velocities v_i. All-to-all (model.cutoff null): the state stays
in agent-id order and every sum runs over slots 0 .. N - 1. With a cutoff: the state is
kept in the order of a plane grid of cells of side the cutoff, rebuilt each step (and,
under RK4, at each stage's positions, its sums gathered back into the state's order).
Observables (observe.py) at observation steps only.
"""

from collections.abc import Mapping

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from ...model import ModelKernel, register_kernel
from ...result import SimulationDiverged
from ...runtime import DevicePolicy, as_real
from ...space.frame import point_mass_frame
from ...space.initial import initial_state
from ...space.integrate import gather_rows, rk4_pair_step
from ...space.plane_grid import PlaneGrid
from ...space.state import SortedState, permute_all
from . import law
from .fused import CuckerSmaleBatch
from .observe import observe
from .step import step_kernels


def _real(*shape: int) -> ti.Ndarray:
    return ti.ndarray(float, shape=shape)


@register_kernel
class CuckerSmaleKernel(ModelKernel):
    """One Cucker–Smale replica, all-to-all or with a cutoff on the grid."""

    kind = "cucker_smale"
    fused = CuckerSmaleBatch

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        super().__init__(scenario, policy)
        p = scenario.model
        self.n = n = scenario.n_agents
        self.dim = dim = scenario.dimension
        self.local = p.normalization == "local"
        self.cutoff = p.cutoff
        init = initial_state(scenario)
        self.state = SortedState({"pos": init.positions, "vel": init.velocities})
        self.prm = _real(law.P.size)
        self.prm.from_numpy(as_real(law.parameters(p, n, scenario.time.dt)))
        self.bad = ti.ndarray(ti.i32, shape=1)
        # All-to-all: the grid is never built; its arrays only fill the kernels' signature.
        self.grid = PlaneGrid(n if self.cutoff else 1, self.cutoff or 1.0, policy, dim)
        self.rk4 = ({k: _real(n, dim) for k in ("xs", "vs", "a", "xk", "vk")}
                    if p.integrator == "rk4" else None)
        self.stage_grid = (PlaneGrid(n, self.cutoff, policy, dim)
                           if self.rk4 is not None and self.cutoff else None)
        self.stage = None  # u in the stage grid's order (RK4 with a cutoff)

    def _kernels(self, grid: PlaneGrid):
        search = getattr(grid, "layout", "hash") if self.cutoff else "all_pairs"
        return step_kernels(self.dim, search, self.local)

    def _sort(self, step: int) -> None:
        if self.cutoff:
            self.state.sort(self.grid, step)

    def step(self, step: int) -> None:
        self._sort(step)
        st = self.state
        self.bad.fill(0)
        pos_out, vel_out = st.scratch("pos"), st.scratch("vel")
        if self.rk4 is not None:
            self._rk4_step(step, pos_out, vel_out)
        else:
            euler, _ = self._kernels(self.grid)
            euler(st["pos"], st["vel"], pos_out, vel_out, self.prm, self.bad,
                  *self.grid.view())
        if self.bad.to_numpy()[0]:
            raise SimulationDiverged(step, "position/velocity", law.DIVERGED_CAUSE)
        st.swap("pos")
        st.swap("vel")

    def _rk4_step(self, step: int, pos_out: ti.Ndarray, vel_out: ti.Ndarray) -> None:
        rk4_pair_step(self.state["pos"], self.state["vel"], self.rk4, self.scenario.time.dt,
                      lambda x, v, out, at_state: self._accel(x, v, out, step, at_state),
                      pos_out, vel_out, self.bad)

    def _accel(self, pos: ti.Ndarray, vel: ti.Ndarray, out: ti.Ndarray, step: int,
               at_state: bool) -> None:
        """u(pos, vel) into out, in storage order: on the state's grid (at_state, or
        all-to-all), else on a stage grid built at pos, its u gathered back."""
        if at_state or not self.cutoff:
            _, accel = self._kernels(self.grid)
            accel(pos, vel, out, self.prm, self.bad, *self.grid.view())
            return
        if self.stage is None:
            self.stage = _real(self.n, self.dim)
        st, g = self.state, self.stage_grid
        # The stage state in g's order goes to the state's spare buffers: the step writes
        # them only at its end (rk4_finish).
        sp, sv = st.scratch("pos"), st.scratch("vel")
        g.build(pos, step)
        permute_all(g.perm, [(pos, sp), (vel, sv)])
        _, accel = self._kernels(g)
        accel(sp, sv, self.stage, self.prm, self.bad, *g.view())
        gather_rows(self.stage, out, g.perm)

    def observe(self, step: int) -> dict[str, float]:
        self._sort(step)
        return observe(self.state["pos"], self.state["vel"])

    def frame(self, arrays: list[str]) -> dict[str, np.ndarray]:
        ids = self.state.ids_numpy()
        return point_mass_frame(lambda: self.state.in_id_order("pos", ids),
                                lambda: self.state.in_id_order("vel", ids), arrays, self.dim)

    def save(self) -> dict[str, np.ndarray]:
        """Checkpoints: the state in its storage order with its ids."""
        return self.state.save()

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        self.state.load(state)

    def convergence_keys(self) -> list[str]:
        return ["velocity_diameter"]
