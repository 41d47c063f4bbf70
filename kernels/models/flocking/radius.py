"""The neighbourhood radius of a metric flock (kernel.py takes one of these as a part).

UniformRadius (M2, paper 000 section 5): N_i = {j : |r_ij| < R}, U_ij saturated at R
  (eq. 10); one R in the force parameters, no state.
AgentRadii (M3, paper 002): each agent's own R_i, kept in the state as "rad", R_i = R at
  the start; R_ij = R_i (own, as printed) or min(R_i, R_j). With adaptive_radius, eq. 4
  at steps k > 0 with k % radius_every == 0, before that step's motion, synchronously:
    R_i <- max(R_i / 2, floor) if |v_i| < stuck_speed and V_i > V_min,
    R_i <- max(R_i, R_j for j in N_i) otherwise.
  Eq. 4 only halves or copies a neighbour's radius, so R bounds every R_i and the grid
  built with R always holds N_i.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import taichi as ti

from flocklab.schemas.obstacles import ObstacleFlockingParams

from ...runtime import wide
from ...space.stream import PairwiseSum, Rows, blocks
from .forces import P, radius_kernel
from .law import RADIUS_RULES, UNIFORM

if TYPE_CHECKING:
    from .parts import FlockView


class UniformRadius:
    """One radius R for every pair (the grid's radius, packed in the force parameters)."""

    rule = UNIFORM

    def __init__(self, radius: float | None):
        self.radius = radius  # None on a fixed graph, which has no radius

    def arrays(self, n: int) -> dict[str, np.ndarray]:
        return {}

    def parameters(self, prm: np.ndarray) -> None:
        prm[P.R2] = 0.0 if self.radius is None else self.radius**2

    def update(self, flock: FlockView, step: int) -> None:
        """R never changes."""

    def q_constant(self, flock: FlockView) -> float:
        """The constant part of Q, 1/2 sum_i sum_{j != i} V(R) (eq. 10)."""
        return 0.5 * flock.n * (flock.n - 1) * flock.p.potential.value(self.radius)

    def observe(self, flock: FlockView, obs: dict[str, float]) -> None:
        """Nothing beyond R itself, which the scenario states."""

    def extra(self) -> dict[str, Any]:
        return {}


class AgentRadii:
    """Per-agent radii R_i (state "rad"), updated by eq. 4 at its cadence."""

    def __init__(self, p: ObstacleFlockingParams, radius: float):
        self.p = p
        self.radius = radius
        self.rule = RADIUS_RULES[p.radius_rule]
        self.counts = ti.ndarray(ti.i32, shape=2)  # (halvings, increases) over the run
        self.counts.fill(0)

    def arrays(self, n: int) -> dict[str, np.ndarray]:
        return {"rad": np.full(n, self.radius)}

    def parameters(self, prm: np.ndarray) -> None:
        prm[P.STUCK2], prm[P.FLOOR] = self.p.stuck_speed**2, self.p.radius_floor

    def update(self, flock: FlockView, step: int) -> None:
        """Eq. 4 at its cadence, on the sorted state, before the step's motion."""
        p = self.p
        if not p.adaptive_radius or step == 0 or step % p.radius_every:
            return
        st = flock.state
        mission = flock.mission.evaluate(st)
        update = radius_kernel(self.rule, flock.flags["inclusive"], flock.search(flock.grid),
                               flock.dim)
        update(st["pos"], st["vel"], st["rad"], st.scratch("rad"), mission, flock.prm,
               self.counts, *flock.grid.view())
        st.swap("rad")

    def q_constant(self, flock: FlockView) -> float:
        """1/2 sum_i sum_{j != i} V(R_ij), the saturated value of every U_ij (eq. 5):
        R_ij = R_i (own), or min(R_i, R_j), where the k-th smallest radius is the smaller
        one of its pairs with the N - 1 - k larger ones."""
        n = flock.n
        total = PairwiseSum(n)
        if self.p.radius_rule == "own":
            rows = Rows(flock.state["rad"])
            for lo, hi in blocks(n):
                total.add(self._saturated(flock, rows.wide(lo, hi)))
            return 0.5 * (n - 1) * total.total()
        rad = np.sort(wide(flock.state["rad"]), kind="stable")  # = rad[argsort(rad)]
        for lo, hi in blocks(n):
            total.add(self._saturated(flock, rad[lo:hi]) * (n - 1 - np.arange(lo, hi)))
        return total.total()

    @staticmethod
    def _saturated(flock: FlockView, rad: np.ndarray) -> np.ndarray:
        """V(R) of paper 002's potential, a / R^2 + log R^2 + c, per radius."""
        return flock.a / rad**2 + np.log(rad**2) + flock.c

    def observe(self, flock: FlockView, obs: dict[str, float]) -> None:
        """radius_min, radius_mean, radius_max over the agents."""
        n = flock.n
        rows, total = Rows(flock.state["rad"]), PairwiseSum(n)
        lo_r, hi_r = np.inf, -np.inf
        for lo, hi in blocks(n):
            r = rows.wide(lo, hi)
            total.add(r)
            lo_r, hi_r = np.minimum(lo_r, r.min()), np.maximum(hi_r, r.max())
        obs.update({"radius_min": float(lo_r), "radius_mean": total.total() / n,
                    "radius_max": float(hi_r)})

    def extra(self) -> dict[str, Any]:
        halved, increased = (int(x) for x in self.counts.to_numpy())
        return {"adaptive_radius": {"halvings": halved, "increases": increased}}
