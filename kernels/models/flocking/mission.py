"""The mission term of a metric flock's control law (kernel.py takes one of these as a part).

NoMission (M2): u_i has no mission term; an empty obstacle grid and a navigation parameter
  array the kernels never read fill their signature.
Mission (M3, paper 002 eq. 3): u_i gains
    - grad_{r_i} V_i - c_d v_i [damping region],
  V_i the navigation function to the destination over the obstacle grid (navigation.py),
  the damping where V_i > V_min (as printed), V_i <= V_min, or everywhere. Q gains
  sum_i V_i (eq. 5). The obstacles may split the flock, and each component synchronises
  on its own: convergence is measured per component.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import taichi as ti

from flocklab.schemas.obstacles import ObstacleFlockingParams

from ...runtime import DevicePolicy, as_real
from ...space.state import SortedState
from ...space.stream import PairwiseSum, Rows, blocks
from .forces import P
from .law import DAMPING, NO_DAMPING
from .navigation import NAV, ObstacleGrid, nav_eval_kernel, nav_parameters

if TYPE_CHECKING:
    from .parts import FlockView


class NoMission:
    """No navigation, no obstacles, no damping (M2)."""

    per_component = False  # convergence of the flock as a whole

    def __init__(self, dim: int, policy: DevicePolicy):
        self.flags = dict(mission=False, damping=NO_DAMPING, has_obstacles=False,
                          unit_kappa=True)
        self.obstacles = ObstacleGrid(np.zeros((0, dim)), np.zeros(0), 1.0, policy)
        self.nav = ti.ndarray(float, shape=NAV.size)

    def parameters(self, prm: np.ndarray) -> None:
        """No slot of its own."""

    def observe(self, flock: FlockView, obs: dict[str, float]) -> None:
        """Nothing to add."""


class Mission:
    """Paper 002's navigation function over point and disc (sphere) obstacles, and damping."""

    per_component = True  # the obstacles may split the flock

    def __init__(self, p: ObstacleFlockingParams, dim: int, policy: DevicePolicy):
        self.p = p
        self.flags = dict(mission=True, damping=DAMPING[p.damping_region],
                          has_obstacles=bool(p.obstacles or p.discs), unit_kappa=p.kappa == 1.0)
        centers = np.array([*p.obstacles, *(d.center for d in p.discs)],
                           dtype=np.float64).reshape(-1, dim)
        radii = np.array([0.0] * len(p.obstacles) + [d.radius for d in p.discs])
        self.obstacles = ObstacleGrid(centers, radii, p.obstacle_range, policy)
        self.nav = ti.ndarray(float, shape=NAV.size)
        self.nav.from_numpy(as_real(nav_parameters(p.destination, p.obstacle_range, p.kappa,
                                                   self.obstacles.bbox)))
        self.evaluate_k = nav_eval_kernel(self.flags["has_obstacles"], self.flags["unit_kappa"],
                                          dim, grad=False)

    def parameters(self, prm: np.ndarray) -> None:
        prm[P.CD], prm[P.VMIN] = self.p.c_d, self.p.V_min

    def evaluate(self, state: SortedState) -> ti.Ndarray:
        """(V_i, min boundary distance) at the state's positions, per slot, into its spare
        position buffer (dead until the step's motion writes it), returned."""
        out = state.scratch("pos")
        self.evaluate_k(state["pos"], out, self.nav, *self.obstacles.view())
        return out

    def observe(self, flock: FlockView, obs: dict[str, float]) -> None:
        """sum_i V_i into Q (eq. 5); the destination distance, the share inside V_min, the
        largest V_i and the closest obstacle boundary."""
        n, dim = flock.n, flock.dim
        mission, pos = Rows(self.evaluate(flock.state)), Rows(flock.state["pos"])
        dest = np.asarray(self.p.destination)
        v_sum, dist_sum = PairwiseSum(n), PairwiseSum(n)
        inside, ext = 0, {k: (np.inf, -np.inf) for k in ("V", "dist", "delta")}

        def extremes(key: str, x: np.ndarray) -> None:
            lo, hi = ext[key]
            ext[key] = (np.minimum(lo, x.min()), np.maximum(hi, x.max()))

        for lo, hi in blocks(n):
            m, x = mission.wide(lo, hi), pos.wide(lo, hi)
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
        mission_sum = v_sum.total()
        obs["Q_reduced"] += mission_sum  # eq. 5: + sum_i V_i
        obs["Q"] += mission_sum
        obs.update({
            "destination_distance_mean": dist_sum.total() / n,
            "destination_distance_max": float(ext["dist"][1]),
            "inside_vmin_fraction": inside / n,
            "mission_potential_max": float(ext["V"][1]),
            # Exact below the obstacle grid's cell; capped there (no obstacle closer).
            "obstacle_distance_min": float(min(ext["delta"][0], self.obstacles.cell)),
        })
