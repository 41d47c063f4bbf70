"""The per-step schedule's Taichi kernels of the Olfati-Saber law (law.py): parallel over
the agents of one replica, one launch per pass.

Agent i's alpha sum runs over the 3x3 (3D: 3x3x3) cells of the plane grid around it,
cells of side r (kernels/space/plane_grid.py: dense rows while the swarm is compact,
else the hashed grid; the state kept in grid order). `euler` writes the semi-implicit
Euler step at time t; a non-finite result increments bad[0] (the caller raises
SimulationDiverged). `observe` writes each agent's share of the quality measures and
unions the proximity graph's edges (kernels/space/graph.py) for its components.
"""

from functools import cache

import taichi as ti

from ...space.graph import find, link
from ...space.grid import put, row
from ...space.integrate import nonfinite
from ...space.plane_grid import visitor
from . import law

nd = ti.types.ndarray()


@cache
def step_kernels(dim: int, search: str, alg: int):
    """(euler, observe) for `search` ("hash" or "dense") in dimension `dim`, Algorithm
    `alg` (compile-time)."""

    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        # S = (vel, q, p_i): q and p_i are the agent's values, read once, not per pair.
        return law.pair_term(acc, d, row(S[0], k, dim), S[2], S[1])

    visit = visitor(pair, search, dim)

    @ti.kernel
    def euler(pos: nd, vel: nd, pos_out: nd, vel_out: nd, prm: nd, obst: nd, n_obst: ti.i32,
              t: ti.f64, bad: nd, start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi = row(pos, i, dim)
            vi = row(vel, i, dim)
            q = law.load(prm)
            alpha = visit(i, xi, ti.Vector.zero(float, dim), pos,
                          ti.static((start, cid, gf, gi)), (vel, q, vi), False)
            u = law.acceleration(alpha, xi, vi, t, q, obst, 0, n_obst, alg)
            x, v = law.euler(xi, vi, u, q[law.P.DT])
            put(pos_out, i, x)
            put(vel_out, i, v)
            if nonfinite(x, v):
                ti.atomic_add(bad[0], 1)

    @ti.func
    def edge_pair(i, k, d, acc, S: ti.template()):
        # S = (parent, q): the edge's deviation share for i; each edge unioned once (k < i).
        if k != i:
            e = law.edge(d, S[1])
            acc += e
            if k < i and e[1] > 0.0:
                ri = find(S[0], i)
                rk = find(S[0], k)
                if ri != rk:
                    link(S[0], ri, rk)
        return acc

    visit_edges = visitor(edge_pair, search, dim)

    @ti.kernel
    def observe(pos: nd, vel: nd, prm: nd, obst: nd, n_obst: ti.i32, parent: nd,
                share: nd, gap: nd, start: nd, cid: nd, gf: nd, gi: nd):
        """share[i] = (sum_j (|q_ij| - d)^2, |N_i|); gap[i, 0] = i's distance to the
        nearest obstacle surface (+inf without obstacles); `parent` the graph's forest."""
        for i in range(pos.shape[0]):
            q = law.load(prm)
            xi = row(pos, i, dim)
            acc = visit_edges(i, xi, ti.math.vec2(0.0, 0.0), pos,
                              ti.static((start, cid, gf, gi)), (parent, q), False)
            share[i, 0] = acc[0]
            share[i, 1] = acc[1]
            gap[i, 0] = law.obstacle_distance(xi, row(vel, i, dim), obst, 0, n_obst)

    return euler, observe
