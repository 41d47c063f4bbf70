"""The properties D1-D3 of an F2 formation around r^ (paper Sec. 3.2), from numpy arrays.

D1  no collision: the minimum pairwise distance is at least the collision distance.
D2  every agent has a neighbour, except possibly the one at r^.
D3  every connected component of the neighbour graph is a "connected formation around r^"
    (Definitions 3.1-3.2): for every line through r^, an agent strictly on one side implies
    one strictly on the other. Equivalently r^ lies in the relative interior of the convex
    hull of the component: the directions from r^ to its agents leave no angular gap
    larger than pi, and a gap of exactly pi is allowed only when every agent lies on one
    line through r^, on both sides. Agents within the tolerance of r^ count as at r^.
Components come from the engine's union-find forest, flattened to its roots.

In 3D "line" becomes "plane through r^", and D3 is tested as an LP: by Stiemke's lemma no
plane through r^ has agents of a component strictly on one side only exactly when some
strictly positive weights lambda_k put r^ at the weighted mean of the directions u_k from r^
to its agents (sum lambda_k u_k = 0), and that fails exactly when some w has u_k . w >= 0
for all k and > 0 for one. `surrounds_3d` solves the second (three variables, K
constraints) and counts a half-space whose agents' sum of u_k . w is at most 1e-7 as
"all on the plane".
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from ...space.stream import ArgMin
from .norms import norms

_ANGLE_TOL = 1e-9
# 3D: the largest sum of u_k . w over a half-space's agents that still counts as "on the
# plane" (rounding, and the LP's feasibility tolerance of 1e-10 per agent).
_PLANE_TOL = 1e-7


class Isolated:
    """D2's count, fed in blocks of agents: those without a neighbour, not counting the
    one at r^ (the agent nearest r^, if within tol). `add(dist, degree)`: the blocks'
    distances |r_i - r^| and degrees; `count()` once all arrived (D2 holds when 0)."""

    def __init__(self, tol: float):
        self.tol = tol
        self.nearest = ArgMin()
        self.lonely = 0
        self._seen = 0
        self._nearest_lonely = False

    def add(self, dist: np.ndarray, degree: np.ndarray) -> None:
        first = self.nearest.index
        self.nearest.add(dist)
        if self.nearest.index != first:
            self._nearest_lonely = bool(degree[self.nearest.index - self._seen] == 0)
        self.lonely += int(np.count_nonzero(degree == 0))
        self._seen += len(dist)

    def count(self) -> int:
        exempt = self.nearest.index >= 0 and self.nearest.value <= self.tol
        return self.lonely - (1 if exempt and self._nearest_lonely else 0)


def d3_holds(rel: np.ndarray, labels: np.ndarray, tol: float) -> bool:
    """Whether every component (agents sharing a label) surrounds r^ (`rel` = r_i - r^)."""
    far = np.hypot(rel[:, 0], rel[:, 1]) > tol
    return surrounds_2d(labels[far], np.arctan2(rel[far, 1], rel[far, 0]))


def surrounds_2d(lab: np.ndarray, ang: np.ndarray) -> bool:
    """D3 in 2D from the agents off r^: their components' labels and the angles of their
    directions from r^. Every component must leave no gap between consecutive directions
    above pi (exactly pi only with agents on both sides of one line)."""
    if not len(lab):
        return True
    order = np.lexsort((ang, lab))
    lab, ang = lab[order], ang[order]
    del order
    first = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    del lab
    last = np.r_[first[1:], len(ang)] - 1
    # gap from each agent to the next one counter-clockwise in its component
    nxt = np.arange(1, len(ang) + 1)
    nxt[last] = first
    gap = ang[nxt] - ang
    del nxt, ang
    gap[last] += 2.0 * np.pi
    big = np.maximum.reduceat(gap, first)
    half_planes = np.add.reduceat((gap > np.pi - _ANGLE_TOL).astype(np.int64), first)
    inside = big < np.pi - _ANGLE_TOL
    on_line = (half_planes == 2) & (big <= np.pi + _ANGLE_TOL)
    return bool(np.all(inside | on_line))


def surrounds_3d(u: np.ndarray) -> bool:
    """Whether the origin is a strictly positive combination of the rows of u (unit
    3-vectors): every plane through it then has rows strictly on both sides or none off it.
    By Stiemke's lemma that fails exactly when some w has u_k . w >= 0 for every k and > 0
    for one, so the test is the dual LP in three variables, max sum_k u_k . w subject to
    u_k . w >= 0, |w_i| <= 1: K constraints of 3 numbers each (the primal, K weights, took a
    dense K x K matrix: 6.6 TiB for a 10^6-agent component)."""
    k = len(u)
    if k == 1:
        return False  # the plane normal to u_0 has it on one side only
    c = u.sum(axis=0)
    norm = float(np.sqrt(c @ c))
    if norm > 0 and float((u @ (c / norm)).min()) > _ANGLE_TOL:
        return False  # every row strictly on the side of their mean direction
    res = linprog(-c, A_ub=-u, b_ub=np.zeros(k), bounds=[(-1.0, 1.0)] * 3, method="highs",
                  options={"primal_feasibility_tolerance": 1e-10,
                           "dual_feasibility_tolerance": 1e-10})
    return bool(res.status == 0 and -res.fun <= _PLANE_TOL)


def d3_holds_3d(rel: np.ndarray, labels: np.ndarray, tol: float) -> bool:
    """D3 in 3D: every component surrounds r^ (`rel` = r_i - r^, (N, 3))."""
    dist = norms(rel)
    far = dist > tol
    return surrounds_3d_all(labels[far], rel[far] / dist[far, None])


def surrounds_3d_all(lab: np.ndarray, u: np.ndarray) -> bool:
    """D3 in 3D from the agents off r^: their components' labels and unit directions."""
    order = np.argsort(lab, kind="stable")
    u, lab = u[order], lab[order]
    cuts = np.flatnonzero(lab[1:] != lab[:-1]) + 1
    sizes = np.diff(np.r_[0, cuts, len(lab)])
    if len(lab) and sizes.min() == 1:
        return False  # a lone agent off r^ (most components early in a run)
    return all(surrounds_3d(group) for group in np.split(u, cuts))
