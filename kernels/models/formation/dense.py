"""The dense regime: a cap on the pair work per agent, by coarse-graining far cells.

F2 squeezes every agent towards one point: at equilibrium the neighbour count grows like
d sqrt(6 N k / k_g) (continuum estimate), so an exact step costs O(N^1.5) pair visits at
large N. When the densest neighbour cell (side d) would make an agent visit more than
`max_exact_candidates` candidates (9 x its count), the step switches to cells of side
h = d/m and a (2m+1)^2 stencil:
  - the 3x3 sub-cells around the agent, and any sub-cell holding at most 2 agents, are summed
    exactly (the singular close range, hence D1, stays exact);
  - every other sub-cell within reach contributes as its centroid carrying its count,
    n_c g(|c - r_i|) (c - r_i)/|c - r_i| if |c - r_i| < d (the monopole of eq. 4's sum).
m = round((2.25 M)^(1/4)) minimises 9 M/m^2 + (2m+1)^2, the per-agent work, for M agents in
the densest d-cell; m is clipped to [2, 16]. Sub-cells come from the engine's hashed grid; a
bucket holding agents of two cells (a hash collision) is summed exactly. Effect: far pairs are
lumped, so the pair forces are no longer exactly antisymmetric (the centroid law for linear
f and the monotonicity of V1/V2 hold only approximately while the cap is active).
"""

from functools import cache

import taichi as ti

from ...space.grid import plane_bucket, plane_cell, plane_cell_id, within
from .forces import P, attract, g_over_s, leader

nd = ti.types.ndarray()
M_MAX = 16
_MONOPOLE_MIN = 3  # sub-cells with fewer agents are summed exactly


def stencil_reach(densest: int) -> int:
    """m for a densest d-cell holding `densest` agents."""
    return int(min(max(round((2.25 * densest) ** 0.25), 2), M_MAX))


@ti.kernel
def max_count(start: nd, buckets: ti.i32) -> ti.i32:
    """The most agents in one of the first `buckets` buckets, from their starts (the
    exclusive scan of their counts, one entry longer): the grid may reuse its counts once
    scanned, and a dense grid's start array may be longer than its cells."""
    m = 0
    for b in range(buckets):
        ti.atomic_max(m, start[b + 1] - start[b])
    return m


@ti.kernel
def bucket_aggregates(pos: nd, start: nd, cid: nd, agg: nd, agg_cid: nd):
    """Per bucket: sum of x, sum of y, 1 if every agent shares one cell; that cell's id."""
    for b in range(agg.shape[0]):
        lo, hi = start[b], start[b + 1]
        sx, sy, pure = 0.0, 0.0, 1.0
        first = ti.cast(-1, ti.i64)
        if hi > lo:
            first = cid[lo]
        for k in range(lo, hi):
            sx += pos[k, 0]
            sy += pos[k, 1]
            if cid[k] != first:
                pure = 0.0
        agg[b, 0] = sx
        agg[b, 1] = sy
        agg[b, 2] = pure
        agg_cid[b] = first


@cache
def coarse_euler(fkind: int, gkind: int, f1: bool, blend: bool, inclusive: bool):
    """One explicit Euler step with the far field coarse-grained on cells of side d/m."""

    @ti.func
    def exact_cell(i, xi, acc, lo, hi, want, pos: ti.template(), cid: ti.template(),
                   prm: ti.template()):
        for k in range(lo, hi):
            if cid[k] == want and k != i:
                dv = ti.math.vec2(pos[k, 0] - xi[0], pos[k, 1] - xi[1])
                d2 = dv.dot(dv)
                if within(d2, prm[P.D2], inclusive):
                    if d2 > 0.0:
                        w = g_over_s(ti.sqrt(d2), prm, gkind)
                        acc += ti.math.vec3(w * dv[0], w * dv[1], 0.0)
                    else:
                        acc[2] += 1.0
        return acc

    @ti.kernel
    def step(pos: nd, ids: nd, ba: nd, bb: nd, pos_out: nd, prm: nd, bad: nd, m: ti.i32,
             agg: nd, agg_cid: nd, start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi = ti.math.vec2(pos[i, 0], pos[i, 1])
            c = plane_cell(xi[0], xi[1], gf)
            h = gf[0]
            r2 = prm[P.D2]
            acc = ti.math.vec3(0.0)
            for a in range(-m, m + 1):
                tx = c[0] + a
                x_lo = gf[2] + tx * h
                gx = ti.max(x_lo - xi[0], 0.0, xi[0] - (x_lo + h))
                for b in range(-m, m + 1):
                    ty = c[1] + b
                    y_lo = gf[3] + ty * h
                    gy = ti.max(y_lo - xi[1], 0.0, xi[1] - (y_lo + h))
                    if gx * gx + gy * gy < r2:  # the sub-cell reaches into the disc
                        bucket = plane_bucket(tx, ty, gi[1])
                        lo, hi = start[bucket], start[bucket + 1]
                        want = plane_cell_id(tx, ty)
                        own = agg[bucket, 2] > 0.5 and agg_cid[bucket] == want
                        far = ti.abs(a) > 1 or ti.abs(b) > 1
                        if far and own and hi - lo >= _MONOPOLE_MIN:
                            n_c = ti.cast(hi - lo, float)
                            dv = ti.math.vec2(agg[bucket, 0], agg[bucket, 1]) / n_c - xi
                            d2 = dv.dot(dv)
                            if d2 < r2 and d2 > 0.0:
                                w = n_c * g_over_s(ti.sqrt(d2), prm, gkind)
                                acc += ti.math.vec3(w * dv[0], w * dv[1], 0.0)
                        elif hi > lo and (own or agg[bucket, 2] < 0.5):
                            acc = exact_cell(i, xi, acc, lo, hi, want, pos, cid, prm)
            v = attract(leader(i, ids, ba, bb, prm, 0, f1, blend) - xi, prm, fkind)
            x = xi[0] + prm[P.DT] * (v[0] + acc[0])
            y = xi[1] + prm[P.DT] * (v[1] + acc[1])
            pos_out[i, 0] = x
            pos_out[i, 1] = y
            if acc[2] > 0.0:
                ti.atomic_add(bad[1], 1)
            s = x + y
            if ti.math.isnan(s) or ti.math.isinf(s):
                ti.atomic_add(bad[0], 1)

    return step
