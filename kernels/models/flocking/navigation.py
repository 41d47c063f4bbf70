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
In 3D (dim = 3, the same source) the obstacles are points and spheres, and every vector
above has three components.
"""

from functools import cache

import numpy as np
import taichi as ti

from ...runtime import DevicePolicy, as_real
from ...space.grid import Grid, make_visitor, row
from ...space.params import Slots
from . import law

nd = ti.types.ndarray()
# The navigation parameter array: the obstacle range and its lambda, kappa, the destination
# (DX, DY), and the obstacles' bounding box (X0, Y0, X1, Y1); in 3D also DZ, Z0, Z1.
NAV = Slots("RANGE", "LAMBDA", "KAPPA", "DX", "DY", "X0", "Y0", "X1", "Y1", "DZ", "Z0", "Z1")
DEST = (NAV.DX, NAV.DY, NAV.DZ)  # the destination's slots, by coordinate
LOW = (NAV.X0, NAV.Y0, NAV.Z0)  # the bounding box's
HIGH = (NAV.X1, NAV.Y1, NAV.Z1)
# "No obstacle within reach" for the minimum boundary distance.
FAR = 1e300


def nav_parameters(destination, obstacle_range: float, kappa: float, bbox) -> np.ndarray:
    """bbox: (low..., high...) with one coordinate per dimension of the destination."""
    dim = len(destination)
    prm = NAV.pack(RANGE=obstacle_range, LAMBDA=(obstacle_range**2 + 1.0) / obstacle_range**2,
                   KAPPA=kappa)
    for c in range(dim):
        prm[DEST[c]], prm[LOW[c]], prm[HIGH[c]] = destination[c], bbox[c], bbox[dim + c]
    return prm


class ObstacleGrid:
    """Static obstacles (centres and radii) in bucket order of their own grid."""

    def __init__(self, centers: np.ndarray, radii: np.ndarray, obstacle_range: float,
                 policy: DevicePolicy):
        self.m = m = len(centers)
        dim = centers.shape[1]
        cell = obstacle_range + (float(radii.max()) if m else 0.0)
        self.cell = cell
        self.grid = Grid(max(m, 1), cell, None, policy, dim)
        pos = ti.ndarray(float, shape=(max(m, 1), dim))
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
            self.bbox = (*lo, *hi)
        else:
            self.bbox = (0.0,) * dim + (-1.0,) * dim  # empty: no agent is ever inside
        self.pos, self.rad = pos, rad

    def view(self) -> tuple:
        """Static tuple for kernels: (centres, radii, start, cell ids, gf, gi)."""
        return (self.pos, self.rad, *self.grid.view())


@ti.func
def _obstacle_pair(i, k, d, acc, S: ti.template()):
    """Fold obstacle k (d = r_o - x) into acc = (B, grad B, min delta)."""
    orad, nav = ti.static(S[0], S[1])
    return law.fold_obstacle(acc, d, orad[k], nav[NAV.RANGE], nav[NAV.LAMBDA])


_visit_obstacles = {dim: make_visitor(_obstacle_pair, dim=dim) for dim in (2, 3)}


@cache
def make_navigation(has_obstacles: bool, unit_kappa: bool, dim: int = 2):
    """Taichi function navigation(x, nav, OB) -> (V, grad V, min delta) (dim + 2 values)
    with OB the obstacle grid's view; specialised for obstacle-free worlds and kappa = 1."""
    visit_obstacles = _visit_obstacles[dim]

    @ti.func
    def navigation(xi, nav: ti.template(), OB: ti.template()):
        acc = ti.Vector.zero(float, dim + 2)
        acc[0] = 1.0
        acc[dim + 1] = FAR
        if ti.static(has_obstacles):
            opos, orad, start, cid, gf, gi = ti.static(OB[0], OB[1], OB[2], OB[3], OB[4], OB[5])
            inside = (nav[NAV.X0] <= xi[0]) & (xi[0] <= nav[NAV.X1]) & (nav[NAV.Y0] <= xi[1]) \
                & (xi[1] <= nav[NAV.Y1])
            if ti.static(dim == 3):
                inside = inside & (nav[NAV.Z0] <= xi[2]) & (xi[2] <= nav[NAV.Z1])
            if inside:
                acc = visit_obstacles(0, xi, acc, opos, ti.static((start, cid, gf, gi)),
                                      ti.static((orad, nav)), False)
        b = acc[0]
        gb = ti.Vector.zero(float, dim)
        y = ti.Vector.zero(float, dim)
        for c in ti.static(range(dim)):
            gb[c] = acc[1 + c]
            y[c] = xi[c] - nav[DEST[c]]
        v, g = law.navigation_value(y, b, gb, nav[NAV.KAPPA], unit_kappa)
        out = ti.Vector.zero(float, dim + 2)
        out[0] = v
        for c in ti.static(range(dim)):
            out[1 + c] = g[c]
        out[dim + 1] = acc[dim + 1]
        return out

    return navigation


@cache
def nav_eval_kernel(has_obstacles: bool, unit_kappa: bool, dim: int = 2, grad: bool = True):
    """Kernel out[i] = (V, grad V, min delta) at points[i]; without `grad`, (V, min delta)
    in out's first two columns (what the observables and the adaptive radius read)."""
    navigation = make_navigation(has_obstacles, unit_kappa, dim)

    @ti.kernel
    def nav_eval(points: nd, out: nd, nav: nd, opos: nd, orad: nd, start: nd, cid: nd,
                 gf: nd, gi: nd):
        for i in range(points.shape[0]):
            r = navigation(row(points, i, dim), nav,
                           ti.static((opos, orad, start, cid, gf, gi)))
            if ti.static(grad):
                for c in ti.static(range(dim + 2)):
                    out[i, c] = r[c]
            else:
                out[i, 0] = r[0]
                out[i, 1] = r[dim + 1]

    return nav_eval
