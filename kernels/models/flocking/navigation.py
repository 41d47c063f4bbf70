"""Paper 002's mission potential (a navigation function) over obstacles kept in their own grid.

For agent position x, destination r_d and obstacles o (p. 3 of paper 002):
  delta_o = |x - r_o| - rho_o                      (distance to the boundary; rho = 0: a point)
  beta_o  = (1 - lambda e^2 / (e^2 + 1))^m,  e = delta_o - d,  lambda = (d^2 + 1) / d^2,
            m = 1/2 (sign(d^2 - delta_o^2) + 1)    (beta_o = 1 unless delta_o^2 < d^2)
  B = prod_o beta_o,  a = |x - r_d|^2,  D = a^kappa + B
  V = a / D^(1/kappa)
  grad V = D^(-1/kappa) 2 (x - r_d) - (a / kappa) D^(-1/kappa - 1) grad D,
  grad D = 2 kappa a^(kappa - 1) (x - r_d) + grad B
  (kappa = 1: grad V = (2 (x - r_d) B - a grad B) / D^2)
B and grad B are folded over the obstacles within reach by the product rule,
(B, grad B) <- (B beta_o, beta_o grad B + B grad beta_o),
grad beta_o = dbeta/ddelta (x - r_o) / |x - r_o|,
so an obstacle with beta_o = 0 needs no division. Only obstacles with delta_o < d matter,
so obstacles are bucketed once in a uniform grid of cell d + max rho (kernels.space.grid, hashed:
memory per obstacle, not per unit area) and an agent outside their bounding box (grown by
one cell) skips the search: 10^4 obstacles and 10^6 agents cost O(N) per step.
"""

from functools import cache

import numpy as np
import taichi as ti

from ...runtime import DevicePolicy, as_real
from ...space.grid import Grid, make_visitor
from ...space.params import Slots

nd = ti.types.ndarray()
# The navigation parameter array: the obstacle range and its lambda, kappa, the destination
# (DX, DY), and the obstacles' bounding box (X0, Y0, X1, Y1).
NAV = Slots("RANGE", "LAMBDA", "KAPPA", "DX", "DY", "X0", "Y0", "X1", "Y1")
# "No obstacle within reach" for the minimum boundary distance.
FAR = 1e300


def nav_parameters(destination, obstacle_range: float, kappa: float, bbox) -> np.ndarray:
    x0, y0, x1, y1 = bbox
    return NAV.pack(RANGE=obstacle_range, LAMBDA=(obstacle_range**2 + 1.0) / obstacle_range**2,
                    KAPPA=kappa, DX=destination[0], DY=destination[1], X0=x0, Y0=y0, X1=x1,
                    Y1=y1)


class ObstacleGrid:
    """Static obstacles (centres and radii) in bucket order of their own grid."""

    def __init__(self, centers: np.ndarray, radii: np.ndarray, obstacle_range: float,
                 policy: DevicePolicy):
        self.m = m = len(centers)
        cell = obstacle_range + (float(radii.max()) if m else 0.0)
        self.cell = cell
        self.grid = Grid(max(m, 1), cell, None, policy)
        pos = ti.ndarray(float, shape=(max(m, 1), 2))
        rad = ti.ndarray(float, shape=max(m, 1))
        if m:
            c = np.ascontiguousarray(centers, dtype=np.float64)
            pos.from_numpy(as_real(c))
            self.grid.build(pos)
            perm = self.grid.perm.to_numpy()
            sc, sr = np.empty_like(c), np.empty(m)
            sc[perm], sr[perm] = c, radii
            pos.from_numpy(as_real(sc))
            rad.from_numpy(as_real(sr))
            lo, hi = c.min(axis=0) - cell, c.max(axis=0) + cell
            self.bbox = (lo[0], lo[1], hi[0], hi[1])
        else:
            self.bbox = (0.0, 0.0, -1.0, -1.0)  # empty: no agent is ever inside
        self.pos, self.rad = pos, rad

    def view(self) -> tuple:
        """Static tuple for kernels: (centres, radii, start, cell ids, gf, gi)."""
        return (self.pos, self.rad, *self.grid.view())


@ti.func
def _obstacle_pair(i, k, d, acc, S: ti.template()):
    """Fold obstacle k (d = r_o - x) into acc = (B, dB/dx, dB/dy, min delta)."""
    orad, nav = ti.static(S[0], S[1])
    dist = ti.sqrt(d.dot(d))
    delta = dist - orad[k]
    acc[3] = ti.min(acc[3], delta)
    rng = nav[NAV.RANGE]
    if delta * delta < rng * rng:  # m = 1; otherwise m = 0 and beta = 1
        e = delta - rng
        q = e * e + 1.0
        beta = 1.0 - nav[NAV.LAMBDA] * e * e / q
        dbeta = -2.0 * nav[NAV.LAMBDA] * e / (q * q)  # d beta / d delta
        g = (-dbeta / dist) * d  # grad_x beta = dbeta (x - r_o) / |x - r_o|
        b = acc[0]
        acc[1] = acc[1] * beta + b * g[0]
        acc[2] = acc[2] * beta + b * g[1]
        acc[0] = b * beta
    return acc


_visit_obstacles = make_visitor(_obstacle_pair)


@cache
def make_navigation(has_obstacles: bool, unit_kappa: bool):
    """Taichi function navigation(x, nav, OB) -> (V, dV/dx, dV/dy, min delta) with OB the
    obstacle grid's view; specialised for obstacle-free worlds and kappa = 1."""

    @ti.func
    def navigation(xi, nav: ti.template(), OB: ti.template()):
        acc = ti.math.vec4(1.0, 0.0, 0.0, FAR)
        if ti.static(has_obstacles):
            opos, orad, start, cid, gf, gi = ti.static(OB[0], OB[1], OB[2], OB[3], OB[4], OB[5])
            inside = (nav[NAV.X0] <= xi[0]) & (xi[0] <= nav[NAV.X1]) & (nav[NAV.Y0] <= xi[1]) \
                & (xi[1] <= nav[NAV.Y1])
            if inside:
                acc = _visit_obstacles(0, xi, acc, opos, ti.static((start, cid, gf, gi)),
                                       ti.static((orad, nav)), False)
        b = acc[0]
        gb = ti.math.vec2(acc[1], acc[2])
        y = ti.math.vec2(xi[0] - nav[NAV.DX], xi[1] - nav[NAV.DY])
        a = y.dot(y)
        v = 0.0
        g = ti.math.vec2(0.0)
        if ti.static(unit_kappa):
            dd = a + b
            v = a / dd
            g = (2.0 * b * y - a * gb) / (dd * dd)
        else:
            kappa = nav[NAV.KAPPA]
            dd = ti.pow(a, kappa) + b
            dk = ti.pow(dd, -1.0 / kappa)
            v = a * dk
            gd = 2.0 * kappa * ti.pow(a, kappa - 1.0) * y + gb
            g = dk * 2.0 * y - (a / kappa) * (dk / dd) * gd
        return ti.math.vec4(v, g[0], g[1], acc[3])

    return navigation


@cache
def nav_eval_kernel(has_obstacles: bool, unit_kappa: bool):
    """Kernel out[i] = (V, dV/dx, dV/dy, min delta) at points[i]."""
    navigation = make_navigation(has_obstacles, unit_kappa)

    @ti.kernel
    def nav_eval(points: nd, out: nd, nav: nd, opos: nd, orad: nd, start: nd, cid: nd,
                 gf: nd, gi: nd):
        for i in range(points.shape[0]):
            r = navigation(ti.math.vec2(points[i, 0], points[i, 1]), nav,
                           ti.static((opos, orad, start, cid, gf, gi)))
            for c in ti.static(range(4)):
                out[i, c] = r[c]

    return nav_eval
