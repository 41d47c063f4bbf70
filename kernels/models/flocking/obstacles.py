"""M3 kernel: Tanner's flocking among obstacles towards a destination (paper 002).

Per step (after sorting the agents into the neighbour grid):
  1. at steps k > 0 with k % radius_every == 0, the adaptive radius of eq. 4, synchronously:
     R_i <- max(R_i / 2, floor) if |v_i| < stuck_speed and V_i > V_min,
     R_i <- max(R_i, R_j for j in N_i) otherwise;
  2. the control law of eq. 3,
     u_i = - sum_{j in N_i} [(v_i - v_j) + grad_{r_i} U_ij] - grad_{r_i} V_i - c_d v_i [region],
     N_i = {j : |r_ij| <= R_i}, U_ij saturated at R_i (kernels/models/flocking/forces.py), V_i the
     navigation function over the obstacle grid (kernels/models/flocking/navigation.py);
  3. the integrator (as M2).
The agent grid is built with the initial radius R, which bounds every R_i (eq. 4 only halves
or copies a neighbour's radius), so the 3x3 cells always hold N_i.
"""

from typing import Any

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from ...model import register_kernel
from ...runtime import DevicePolicy, as_real, wide
from ...space.initial import InitialState
from ...space.stream import PairwiseSum, Rows, blocks
from . import observe as fo
from .forces import DAMPING, RADIUS_RULES, P, radius_kernel
from .kernel import FlockingKernel, _i32, _real
from .navigation import NAV, ObstacleGrid, nav_eval_kernel, nav_parameters


@register_kernel
class ObstacleFlockingKernel(FlockingKernel):
    kind = "flocking_obstacles"

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        super().__init__(scenario, policy)
        p = self.p
        self.mission_k = nav_eval_kernel(self.flags["has_obstacles"],
                                         self.flags["unit_kappa"], self.dim, grad=False)
        self.counts = _i32(2)
        self.counts.fill(0)
        self.adaptive = p.adaptive_radius

    def _fixed_topology(self) -> bool:
        return False

    def _initial_arrays(self, init: InitialState) -> dict[str, np.ndarray]:
        rad = np.full(self.n, self.scenario.neighbours.radius)
        return {"pos": init.positions, "vel": init.velocities, "rad": rad}

    def _parameters(self) -> np.ndarray:
        prm = super()._parameters()
        p = self.p
        prm[P.CD], prm[P.VMIN] = p.c_d, p.V_min
        prm[P.STUCK2], prm[P.FLOOR] = p.stuck_speed**2, p.radius_floor
        return prm

    def _grid_flags(self) -> dict[str, Any]:
        p = self.p
        return dict(rule=RADIUS_RULES[p.radius_rule], inclusive=self.scenario.inclusive,
                    mission=True, damping=DAMPING[p.damping_region],
                    has_obstacles=bool(p.obstacles or p.discs), unit_kappa=p.kappa == 1.0)

    def _init_navigation(self) -> None:
        p = self.p
        centers = np.array([*p.obstacles, *(d.center for d in p.discs)],
                           dtype=np.float64).reshape(-1, self.dim)
        radii = np.array([0.0] * len(p.obstacles) + [d.radius for d in p.discs])
        self.obstacles = ObstacleGrid(centers, radii, p.obstacle_range, self.policy)
        self.nav = _real(NAV.size)
        self.nav.from_numpy(as_real(nav_parameters(p.destination, p.obstacle_range, p.kappa,
                                                   self.obstacles.bbox)))

    def _evaluate_mission(self) -> ti.Ndarray:
        """(V_i, min boundary distance) at the current positions, per slot, into the step's
        spare position buffer (dead until the step's motion writes it), returned."""
        out = self.state.scratch("pos")
        self.mission_k(self.state["pos"], out, self.nav, *self.obstacles.view())
        return out

    def _before_motion(self, step: int) -> None:
        """Eq. 4 at its cadence, before the step's motion."""
        if not self.adaptive or step == 0 or step % self.p.radius_every:
            return
        st = self.state
        mission = self._evaluate_mission()
        update = radius_kernel(self.flags["rule"], self.flags["inclusive"],
                               self._search(self.grid), self.dim)
        update(st["pos"], st["vel"], st["rad"], st.scratch("rad"), mission, self.prm,
               self.counts, *self.grid.view())
        st.swap("rad")

    def _q_constant(self) -> float:
        """1/2 sum_i sum_{j != i} V(R_ij), the saturated value of every U_ij (eq. 5):
        R_ij = R_i (own), or min(R_i, R_j), where the k-th smallest radius is the smaller
        one of its pairs with the N - 1 - k larger ones."""
        n = self.n
        total = PairwiseSum(n)
        if self.p.radius_rule == "own":
            rows = Rows(self.state["rad"])
            for lo, hi in blocks(n):
                total.add(self._saturated(rows.wide(lo, hi)))
            return 0.5 * (n - 1) * total.total()
        rad = np.sort(wide(self.state["rad"]), kind="stable")  # = rad[argsort(rad)]
        for lo, hi in blocks(n):
            total.add(self._saturated(rad[lo:hi]) * (n - 1 - np.arange(lo, hi)))
        return total.total()

    def _saturated(self, rad: np.ndarray) -> np.ndarray:
        """V(R) of paper 002's potential, a / R^2 + log R^2 + c, per radius."""
        return self.a / rad**2 + np.log(rad**2) + self.c

    def observe(self, step: int) -> dict[str, float]:
        obs = super().observe(step)
        st = self.state
        n, dim = self.n, self.dim
        mission = Rows(self._evaluate_mission())
        pos, rad = Rows(st["pos"]), Rows(st["rad"])
        dest = np.asarray(self.p.destination)
        v_sum, dist_sum, rad_sum = PairwiseSum(n), PairwiseSum(n), PairwiseSum(n)
        inside, ext = 0, {k: (np.inf, -np.inf) for k in ("V", "dist", "delta", "rad")}

        def extremes(key: str, x: np.ndarray) -> None:
            lo, hi = ext[key]
            ext[key] = (np.minimum(lo, x.min()), np.maximum(hi, x.max()))

        for lo, hi in blocks(n):
            m, x, r = mission.wide(lo, hi), pos.wide(lo, hi), rad.wide(lo, hi)
            v_sum.add(m[:, 0])
            inside += int(np.count_nonzero(m[:, 0] <= self.p.V_min))
            extremes("V", m[:, 0])
            extremes("delta", m[:, 1])
            if dim == 3:
                dist = np.linalg.norm(x - dest, axis=1)
            else:
                dist = np.hypot(x[:, 0] - dest[0], x[:, 1] - dest[1])
            dist_sum.add(dist)
            extremes("dist", dist)
            rad_sum.add(r)
            extremes("rad", r)
        mission_sum = v_sum.total()
        obs["Q_reduced"] += mission_sum  # eq. 5: + sum_i V_i
        obs["Q"] += mission_sum
        cap = self.obstacles.cell
        obs.update({
            "destination_distance_mean": dist_sum.total() / n,
            "destination_distance_max": float(ext["dist"][1]),
            "inside_vmin_fraction": inside / n,
            "mission_potential_max": float(ext["V"][1]),
            # Exact below the obstacle grid's cell; capped there (no obstacle closer).
            "obstacle_distance_min": float(min(ext["delta"][0], cap)),
            "radius_min": float(ext["rad"][0]),
            "radius_mean": rad_sum.total() / n,
            "radius_max": float(ext["rad"][1]),
            **fo.component_disagreement(st["vel"], self.component_labels()),
        })
        return obs

    def convergence_keys(self) -> list[str]:
        return ["velocity_disagreement_components"]

    def extra(self) -> dict[str, Any]:
        halved, increased = (int(x) for x in self.counts.to_numpy())
        return {**super().extra(),
                "adaptive_radius": {"halvings": halved, "increases": increased}}
