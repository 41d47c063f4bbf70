"""M2 kernel: Tanner–Jadbabaie–Pappas flocking, fixed or switching topology (paper 000).

State: positions r_i and velocities v_i (double integrator, eq. 1). Control (eq. 3):
  u_i = - sum_{j in N_i} (v_i - v_j) - sum_{j in N_i} grad_{r_i} V_ij(|r_ij|)
fixed     N_i from a CSR graph in agent-id order (no spatial search, no sorting).
switching N_i = {j : |r_ij| < R} on the neighbour grid (kernels/space/plane_grid.py; state
          kept in grid order; at small N over all pairs instead), V saturated at R
          (eq. 10): no force at R or beyond. With topological neighbours (neighbours.kind
          "topological"), N_i = the k nearest within R (kernels/space/knn.py, searched
          once per step on its own grid, and at each RK4 stage's positions).
One step: semi-implicit Euler (v' = v + dt u, r' = r + dt v') fused into one kernel, or
RK4 (kernels/space/integrate.py) with the neighbour sets re-evaluated at every stage (stages
2-4 on a grid built at the stage positions).
Observables at observation steps only: velocity statistics, W (eq. 5) or Q (eq. 10),
valencies, components, lambda_2, and the closest pair.
3D (space.dimension = 3): the same kernels and grids with dim = 3, and mean_velocity_z
beside mean_velocity_x and _y.

`Flock` is the double-integrator flock assembled from its parts: the topology (a fixed graph
or metric neighbours), the neighbourhood radius (radius.py) and the mission term
(mission.py). M2 is a flock with one radius R and no mission; M3 (obstacles.py) the metric
flock with per-agent radii under eq. 4 and paper 002's navigation function.
"""

from collections.abc import Mapping
from typing import Any

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from ...model import ModelKernel, register_kernel
from ...result import SimulationDiverged
from ...runtime import DevicePolicy, as_real, wide
from ...space.frame import point_mass_frame
from ...space.graph import count_roots, flatten, reset_parent
from ...space.initial import initial_state
from ...space.integrate import gather_rows, rk4_pair_step
from ...space.knn import TopologicalNeighbours
from ...space.plane_grid import PlaneGrid
from ...space.state import SortedState, permute_all
from ...space.stream import ArgMin, PairwiseSum, Rows, blocks
from . import observe as fo
from .forces import P, csr_accel, csr_euler, csr_potential, grid_kernels, grid_observe_kernel
from .fused import FlockingBatch
from .law import DIVERGED_CAUSE, OWN, UNIFORM
from .mission import Mission, NoMission
from .radius import AgentRadii, UniformRadius
from .topology import build_edges, to_csr


def _real(*shape: int) -> ti.Ndarray:
    return ti.ndarray(float, shape=shape)


def _i32(*shape: int) -> ti.Ndarray:
    return ti.ndarray(ti.i32, shape=shape)


class Flock(ModelKernel):
    """Double integrators under u_i = alignment + pair forces [+ mission term], from parts:
    `fixed` (N_i from the scenario's graph) or metric neighbours within `radii`, and
    `mission`. The registered models below and in obstacles.py choose the parts."""

    fused = FlockingBatch  # M2 and M3 on the fused small-N path

    def __init__(self, scenario: Scenario, policy: DevicePolicy, fixed: bool,
                 radii: UniformRadius | AgentRadii, mission: NoMission | Mission):
        super().__init__(scenario, policy)
        p = scenario.model
        self.p = p
        self.n = n = scenario.n_agents
        self.dim = scenario.dimension
        self.wants_lambda2 = scenario.recording.wants("lambda2")  # an eigensolve each time
        self.dt = scenario.time.dt
        self.a, self.c = p.potential.coefficients()
        self.fixed = fixed
        self.radii, self.mission = radii, mission
        init = initial_state(scenario)
        self.state = SortedState({"pos": init.positions, "vel": init.velocities,
                                  **radii.arrays(n)})
        prm = P.pack(DT=self.dt, A=self.a, C=self.c)
        radii.parameters(prm)
        mission.parameters(prm)
        self.prm = _real(P.size)
        self.prm.from_numpy(as_real(prm))
        self.bad = _i32(1)
        self.closest: dict[str, Any] = {}
        self.knn: TopologicalNeighbours | None = None  # topological neighbours' lists
        self._knn_for = -1  # the step whose state the k-NN lists are of
        if self.fixed:
            self._init_graph(scenario)
        else:
            self._init_grid(scenario)
        if p.integrator == "rk4":
            self.rk4 = {k: _real(n, self.dim) for k in ("xs", "vs", "a", "xk", "vk")}
        else:
            self.rk4 = None

    # --- set-up -------------------------------------------------------------------------

    def _init_graph(self, scenario: Scenario) -> None:
        n = self.n
        u, v = build_edges(self.p.graph, n, scenario.seed)
        indptr, indices = to_csr(n, u, v)
        self.indptr = ti.ndarray(ti.i32, shape=n + 1)
        self.indptr.from_numpy(indptr)
        self.indices = _i32(max(len(indices), 1))
        if len(indices):
            self.indices.from_numpy(indices)
        self.fixed_degree = np.diff(indptr).astype(np.int32)  # agent-id order, for ever
        self.pot = _real(n)  # V_i of eq. 4, at observations
        adj = fo.graph_matrix(n, u, v)
        n_comp = fo.components(adj)
        self.graph_info = {
            "edges": len(u),
            "components": n_comp,
            "lambda2": fo.algebraic_connectivity(adj, n_comp, self.p.lambda2_max_agents),
        }
        self.graph_obs = {
            "components": float(n_comp),
            "lambda2": self.graph_info["lambda2"],
            **fo.valency_stats(self.fixed_degree, self.p.valency_per_agent_max),
        }

    def _init_grid(self, scenario: Scenario) -> None:
        n = self.n
        # Compile-time choices of the grid kernels.
        self.flags = dict(rule=self.radii.rule, inclusive=scenario.inclusive,
                          **self.mission.flags)
        nb = scenario.neighbours
        self.grid_radius = r = nb.radius
        if nb.topological:
            # The k nearest within R, on a grid with cells sized for k (the state's sort);
            # RK4's stages search their own positions' k nearest on a second one.
            self.all_pairs = False
            knn = lambda: TopologicalNeighbours(  # noqa: E731
                n, nb.k, r, scenario.inclusive, nb.symmetric, None, self.policy, self.dim)
            self.knn = knn()
            self.grid = self.knn.grid
            self.stage_knn = knn() if self.p.integrator == "rk4" else None
            self.stage_grid = self.stage_knn.grid if self.stage_knn else None
            self.stage_ids = _i32(n) if self.stage_knn else None  # ids in its order
        else:
            self.all_pairs = self.p.uses_all_pairs(n)
            # All pairs: the grid is never built; its arrays only fill the kernels' signature.
            self.grid = self._new_grid(1 if self.all_pairs else n, r)
            rk4_grid = self.p.integrator == "rk4" and not self.all_pairs
            self.stage_grid = self._new_grid(n, r) if rk4_grid else None
            self.stage_knn = None
        self.per_agent_radius = self.radii.rule != UNIFORM
        self._no_rad = _real(1)
        self.parent = _i32(n)  # the metric graph's union-find forest, at observations
        self.stage = None

    def _new_grid(self, n: int, r: float) -> PlaneGrid:
        """The unbounded space's grid: dense while the swarm is compact, else hashed."""
        return PlaneGrid(n, r, self.policy, self.dim)

    # --- stepping -----------------------------------------------------------------------

    def _rad(self) -> ti.Ndarray:
        return self.state["rad"] if self.per_agent_radius else self._no_rad

    def search(self, grid: PlaneGrid) -> str:
        """The visitor for positions bucketed in `grid` (all pairs: no grid; topological:
        the k-NN lists)."""
        if self.knn is not None:
            return "knn_symmetric" if self.knn.symmetric else "knn"
        return "all_pairs" if self.all_pairs else getattr(grid, "layout", "hash")

    def _grid_view(self) -> tuple:
        """What the metric kernels read of the neighbourhoods: the grid, or the k-NN lists."""
        return self.grid.view() if self.knn is None else self.knn.view()

    def _kernels(self, grid: PlaneGrid):
        """(euler, accel) for the grid's current layout (compiled once per layout)."""
        return grid_kernels(**self.flags, search=self.search(grid), dim=self.dim)

    def _sort(self, step: int) -> None:
        """Grid order for this step's positions (fixed graphs and all pairs need none)."""
        if not (self.fixed or self.all_pairs):
            self.state.sort(self.grid, step)
        if self.knn is not None and self._knn_for != step:
            self.knn.search(self.state["pos"], self.state.ids)
            self._knn_for = step

    def step(self, step: int) -> None:
        self._sort(step)
        if not self.fixed:
            self.radii.update(self, step)
        st = self.state
        self.bad.fill(0)
        pos_out, vel_out = st.scratch("pos"), st.scratch("vel")
        if self.rk4 is not None:
            self._rk4_step(step, pos_out, vel_out)
        elif self.fixed:
            csr_euler(st["pos"], st["vel"], pos_out, vel_out, self.indptr, self.indices,
                      self.prm, self.bad, self.dim)
        else:
            euler, _ = self._kernels(self.grid)
            euler(st["pos"], st["vel"], self._rad(), pos_out, vel_out, self.prm, self.mission.nav,
                  self.bad, *self._grid_view(), *self.mission.obstacles.view())
        if self.bad.to_numpy()[0]:
            raise SimulationDiverged(step, "position/velocity", DIVERGED_CAUSE)
        st.swap("pos")
        st.swap("vel")

    def _rk4_step(self, step: int, pos_out: ti.Ndarray, vel_out: ti.Ndarray) -> None:
        rk4_pair_step(self.state["pos"], self.state["vel"], self.rk4, self.dt,
                      lambda x, v, out, at_state: self._accel(x, v, out, step, at_state),
                      pos_out, vel_out, self.bad)

    def _accel(self, pos: ti.Ndarray, vel: ti.Ndarray, out: ti.Ndarray, step: int,
               at_state: bool) -> None:
        """u(pos, vel) into out, all in storage order. at_state: pos is the sorted state,
        whose grid is built; otherwise a stage grid is built at pos and undone after (all
        pairs: no grid, pos is read as it is)."""
        if self.fixed:
            csr_accel(pos, vel, out, self.indptr, self.indices, self.prm, self.bad, self.dim)
            return
        if at_state or self.all_pairs:
            _, accel = self._kernels(self.grid)
            accel(pos, vel, self._rad(), out, self.prm, self.mission.nav, self.bad,
                  *self._grid_view(), *self.mission.obstacles.view())
            return
        if self.stage is None:
            self.stage = _real(self.n, self.dim)  # u in the stage grid's order
        st, g = self.state, self.stage_grid
        # The stage state in g's order goes to the state's spare buffers: the step writes
        # them only at its end (rk4_finish), and M3's radius once before the stages.
        s = {"pos": st.scratch("pos"), "vel": st.scratch("vel"), "a": self.stage,
             "rad": st.scratch("rad") if self.per_agent_radius else self._no_rad}
        g.build(pos, step)
        moved = [(pos, s["pos"]), (vel, s["vel"])]
        if self.per_agent_radius:
            moved.append((self.state["rad"], s["rad"]))
        view = g.view()
        if self.stage_knn is not None:  # the stage's k nearest, ties by agent id
            moved.append((st.ids, self.stage_ids))
        permute_all(g.perm, moved)
        if self.stage_knn is not None:
            self.stage_knn.search(s["pos"], self.stage_ids)
            view = self.stage_knn.view()
        _, accel = self._kernels(g)
        accel(s["pos"], s["vel"], s["rad"], s["a"], self.prm, self.mission.nav, self.bad,
              *view, *self.mission.obstacles.view())
        gather_rows(s["a"], out, g.perm)

    # --- observables --------------------------------------------------------------------

    def observe(self, step: int) -> dict[str, float]:
        self._sort(step)
        st = self.state
        obs, kinetic = fo.velocity_stats(st["vel"])
        if self.fixed:
            csr_potential(st["pos"], self.indptr, self.indices, self.prm, self.pot, self.dim)
            obs["W"] = 0.5 * float(wide(self.pot).sum()) + kinetic  # eq. 5
            obs.update(self.graph_obs)
            self._closest(step, *fo.closest_pair(wide(st["pos"])), obs)
        else:
            obs.update(self._observe_grid(step, kinetic))
            self.mission.observe(self, obs)
            self.radii.observe(self, obs)
            if self.mission.per_component:
                obs.update(fo.component_disagreement(st["vel"], self.component_labels()))
        return obs

    def _observe_grid(self, step: int, kinetic: float) -> dict[str, float]:
        st = self.state
        n = self.n
        near, counts = self._grid_observation()
        n_comp = count_roots(self.parent)
        pot, nearest = PairwiseSum(n), ArgMin()
        val = fo.Valencies(n, self.p.valency_per_agent_max)
        near_rows, count_rows = Rows(near), Rows(counts)
        for lo, hi in blocks(n):
            x = near_rows.wide(lo, hi)
            nearest.add(x[:, 0])
            pot.add(x[:, 1])
            val.add(count_rows(lo, hi)[:, 0].astype(np.int32))
        reduced = 0.5 * pot.total() + kinetic
        obs = {"Q_reduced": reduced, "Q": reduced + self.radii.q_constant(self),
               "components": float(n_comp)}
        obs.update(val.stats(self._by_id(counts) if val.per_agent else None))
        # The 3x3 (3x3x3) cells hold every pair closer than the grid radius: exact below it.
        k = nearest.index
        if self.all_pairs or nearest.value < self.grid_radius**2:
            j = int(counts[k, 1])
            self._closest(step, float(np.sqrt(nearest.value)), int(st.ids[k]), int(st.ids[j]),
                          obs)
        else:
            ids = st.ids_numpy()
            dist, a, b = fo.closest_pair(wide(st["pos"]))
            self._closest(step, dist, int(ids[a]), int(ids[b]), obs)
        lam = fo.NOT_COMPUTED
        if self.n <= self.p.lambda2_max_agents and self.wants_lambda2:
            u, v = self._edges()
            lam = fo.algebraic_connectivity(fo.graph_matrix(self.n, u, v), n_comp,
                                            self.p.lambda2_max_agents)
        obs["lambda2"] = lam
        return obs

    def _edges(self) -> tuple[np.ndarray, np.ndarray]:
        """The interaction graph's edges in agent ids, for lambda_2 (which takes it
        undirected): the proximity graph, or the k-NN lists' edges."""
        st = self.state
        if self.knn is not None:
            lists = self.knn.lists(st.ids_numpy())
            u = np.repeat(np.arange(self.n), [len(nb) for nb in lists])
            v = np.fromiter((j for nb in lists for j in nb), np.int64, len(u))
            return u, v
        radii = wide(st["rad"]) if self.per_agent_radius else self.grid_radius
        rule = "own" if self.flags["rule"] == OWN else "min"
        u, v = fo.proximity_edges(wide(st["pos"]), radii, rule, self.flags["inclusive"])
        # proximity_edges gives slots of the sorted state; lambda_2 does not mind the order.
        return u, v

    def _grid_observation(self) -> tuple[ti.Ndarray, ti.Ndarray]:
        """Run the observation kernel on the sorted state: components into `parent`, and
        (nearest d^2, potential sum) and (valency, nearest slot) per slot into the step's
        spare position and velocity buffers (dead until the step writes them), returned."""
        st = self.state
        reset_parent(self.parent)
        observe = grid_observe_kernel(self.flags["rule"], self.flags["inclusive"],
                                      self.search(self.grid), self.dim)
        near, counts = st.scratch("pos"), st.scratch("vel")
        observe(st["pos"], self._rad(), self.prm, self.parent, near, counts,
                *self._grid_view())
        return near, counts

    def _by_id(self, counts: ti.Ndarray) -> np.ndarray:
        """The valencies in agent-id order (the first column of `counts`, slot order)."""
        deg = np.empty(self.n, dtype=np.int32)
        deg[self.state.ids_numpy()] = counts.to_numpy()[:, 0].astype(np.int32)
        return deg

    def derived_arrays(self, step: int, names: list[str]) -> dict[str, np.ndarray]:
        """degree: |N_i| as the valency observables count it (the fixed graph's degree, or
        the metric graph's from the same observation kernel); radius (M3): R_i."""
        self._sort(step)  # the sort step(step) would do: no bit of the run changes
        out = {}
        if "degree" in names:
            out["degree"] = (self.fixed_degree.copy() if self.fixed
                             else self._by_id(self._grid_observation()[1]))
        if "radius" in names:
            out["radius"] = self.state.in_id_order("rad")
        return out

    def component_labels(self) -> np.ndarray:
        """Connected-component label (a root slot) of each slot, from the last
        observation's union-find forest, flattened in place."""
        flatten(self.parent)
        return self.parent.to_numpy()

    def _closest(self, step: int, dist: float, i: int, j: int, obs: dict[str, float]) -> None:
        i, j = min(i, j), max(i, j)
        obs.update({"min_distance": dist, "min_pair_i": float(i), "min_pair_j": float(j)})
        if not self.closest or dist < self.closest["distance"]:
            self.closest = {"distance": dist, "pair": [i, j], "time": step * self.dt}

    def frame(self, arrays: list[str]) -> dict[str, np.ndarray]:
        ids = self.state.ids_numpy()
        return point_mass_frame(lambda: self.state.in_id_order("pos", ids),
                                lambda: self.state.in_id_order("vel", ids), arrays, self.dim)

    def save(self) -> dict[str, np.ndarray]:
        """Checkpoints: the sorted state with its ids, the closest approach so far and
        M3's radius counters (everything else is rebuilt each step)."""
        out = self.state.save()
        if self.closest:
            c = self.closest
            out["closest"] = np.array([c["distance"], *c["pair"], c["time"]], np.float64)
        if isinstance(self.radii, AgentRadii):
            out["radius_counts"] = self.radii.counts.to_numpy()
        return out

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        self.state.load(state)
        if "closest" in state:
            d, i, j, t = state["closest"].tolist()
            self.closest = {"distance": d, "pair": [int(i), int(j)], "time": t}
        if isinstance(self.radii, AgentRadii):
            self.radii.counts.from_numpy(state["radius_counts"])

    def convergence_keys(self) -> list[str]:
        if self.mission.per_component:
            return ["velocity_disagreement_components"]
        return ["velocity_disagreement"]

    def extra(self) -> dict[str, Any]:
        out: dict[str, Any] = {"closest_approach": self.closest}
        if self.fixed:
            out["graph"] = self.graph_info
        return {**out, **self.radii.extra()}


@register_kernel
class FlockingKernel(Flock):
    """M2: one radius R for every pair (switching) or the scenario's graph (fixed), and no
    mission term."""

    kind = "flocking"

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        fixed = scenario.model.topology == "fixed"
        radius = None if fixed else scenario.neighbours.radius
        super().__init__(scenario, policy, fixed, UniformRadius(radius),
                         NoMission(scenario.dimension, policy))
