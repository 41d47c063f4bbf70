"""The properties D1-D3 of an F2 formation around r^ (paper Sec. 3.2), from numpy arrays.

D1  no collision: the minimum pairwise distance is at least the collision distance.
D2  every agent has a neighbour, except possibly the one at r^.
D3  every connected component of the neighbour graph is a "connected formation around r^"
    (Definitions 3.1-3.2): for every line through r^, an agent strictly on one side implies
    one strictly on the other. Equivalently r^ lies in the relative interior of the convex
    hull of the component: the directions from r^ to its agents leave no angular gap
    larger than pi, and a gap of exactly pi is allowed only when every agent lies on one
    line through r^, on both sides. Agents within the tolerance of r^ count as at r^.
Components come from the engine's union-find forest (`roots`).

In 3D "line" becomes "plane through r^", and D3 is tested as an LP: by Stiemke's lemma no
plane through r^ has agents of a component strictly on one side only exactly when some
strictly positive weights lambda_k put r^ at the weighted mean of the directions u_k from r^
to its agents (sum lambda_k u_k = 0). `d3_holds_3d` maximises the smallest weight t
(sum lambda = 1) and requires t > 1e-9 / K for K agents (the analogue of the angular
tolerance in 2D).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from .norms import norms

_ANGLE_TOL = 1e-9


def roots(parent: np.ndarray) -> np.ndarray:
    """The root of every node of a union-find forest (pointer jumping)."""
    lab = parent
    while True:
        up = lab[lab]
        if np.array_equal(up, lab):
            return lab
        lab = up


def at_leader(rel: np.ndarray, tol: float) -> int:
    """Index of the agent at r^ (nearest, within tol), or -1. `rel` = r_i - r^."""
    dist = norms(rel)
    k = int(np.argmin(dist))
    return k if dist[k] <= tol else -1


def d2_isolated(degree: np.ndarray, exempt: int) -> int:
    """Agents without a neighbour, not counting the one at r^ (D2 holds when 0)."""
    lonely = np.count_nonzero(degree == 0)
    return int(lonely - (1 if exempt >= 0 and degree[exempt] == 0 else 0))


def d3_holds(rel: np.ndarray, labels: np.ndarray, tol: float) -> bool:
    """Whether every component (agents sharing a label) surrounds r^ (`rel` = r_i - r^)."""
    far = np.hypot(rel[:, 0], rel[:, 1]) > tol
    if not far.any():
        return True
    lab = labels[far]
    ang = np.arctan2(rel[far, 1], rel[far, 0])
    order = np.lexsort((ang, lab))
    lab, ang = lab[order], ang[order]
    first = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    last = np.r_[first[1:], len(lab)] - 1
    # gap from each agent to the next one counter-clockwise in its component
    nxt = np.arange(1, len(lab) + 1)
    nxt[last] = first
    gap = ang[nxt] - ang
    gap[last] += 2.0 * np.pi
    big = np.maximum.reduceat(gap, first)
    half_planes = np.add.reduceat((gap > np.pi - _ANGLE_TOL).astype(np.int64), first)
    inside = big < np.pi - _ANGLE_TOL
    on_line = (half_planes == 2) & (big <= np.pi + _ANGLE_TOL)
    return bool(np.all(inside | on_line))


def surrounds_3d(u: np.ndarray) -> bool:
    """Whether the origin is a strictly positive combination of the rows of u (unit
    3-vectors): every plane through it then has rows strictly on both sides or none off it."""
    k = len(u)
    if k == 1:
        return False
    # variables (lambda_1..lambda_K, t): maximise t, sum lambda u = 0, sum lambda = 1,
    # lambda_k >= t
    a_eq = np.zeros((4, k + 1))
    a_eq[:3, :k] = u.T
    a_eq[3, :k] = 1.0
    a_ub = np.concatenate([-np.eye(k), np.ones((k, 1))], axis=1)
    cost = np.zeros(k + 1)
    cost[k] = -1.0
    res = linprog(cost, A_ub=a_ub, b_ub=np.zeros(k), A_eq=a_eq, b_eq=[0.0, 0.0, 0.0, 1.0],
                  bounds=[(0.0, None)] * k + [(None, 1.0)], method="highs")
    return bool(res.status == 0 and -res.fun > _ANGLE_TOL / k)


def d3_holds_3d(rel: np.ndarray, labels: np.ndarray, tol: float) -> bool:
    """D3 in 3D: every component surrounds r^ (`rel` = r_i - r^, (N, 3))."""
    dist = norms(rel)
    far = dist > tol
    u = rel[far] / dist[far, None]
    lab = labels[far]
    return all(surrounds_3d(u[lab == c]) for c in np.unique(lab))
