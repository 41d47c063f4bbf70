"""The per-step schedule's Taichi kernels of the Cucker–Smale law (law.py): parallel over
the agents of one replica, one launch per pass.

Agent i's sums S_i run over every agent (all-to-all: slots 0 .. N - 1 in order, no grid)
or over the 3x3 (3D: 3x3x3) cells of the plane grid around it, cells of side the cutoff
(kernels/space/plane_grid.py: dense rows while the swarm is compact, else the hashed
grid; the state kept in grid order). `euler` writes the semi-implicit Euler step,
`accel` u alone for the RK4 stages (kernels/space/integrate.py). A non-finite result
increments bad[0]; the caller raises SimulationDiverged.
"""

from functools import cache

import taichi as ti

from ...space.grid import put, row
from ...space.integrate import nonfinite
from ...space.plane_grid import visitor
from . import law

nd = ti.types.ndarray()


@cache
def step_kernels(dim: int, search: str, local: bool):
    """(euler, accel) for `search` ("all_pairs", "hash" or "dense") in dimension `dim`;
    `local`: Motsch–Tadmor's normalisation (compile-time)."""

    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        # S = (vel, q, v_i): q and v_i are the agent's values, read once, not per pair.
        return law.pair_term(acc, d, row(S[0], k, dim), S[2], S[1])

    visit = visitor(pair, search, dim)

    @ti.func
    def accel_of(i, pos: ti.template(), vel: ti.template(), prm: ti.template(),
                 G: ti.template()):
        xi = row(pos, i, dim)
        q = law.load(prm)
        vi = row(vel, i, dim)
        acc = visit(i, xi, ti.Vector.zero(float, dim + 1), pos, G, (vel, q, vi), False)
        return xi, law.acceleration(acc, q, local)

    @ti.kernel
    def euler(pos: nd, vel: nd, pos_out: nd, vel_out: nd, prm: nd, bad: nd,
              start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi, u = accel_of(i, pos, vel, prm, ti.static((start, cid, gf, gi)))
            x, v = law.euler(xi, row(vel, i, dim), u, prm[law.P.DT])
            put(pos_out, i, x)
            put(vel_out, i, v)
            if nonfinite(x, v):
                ti.atomic_add(bad[0], 1)

    @ti.kernel
    def accel(pos: nd, vel: nd, acc_out: nd, prm: nd, bad: nd,
              start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi, u = accel_of(i, pos, vel, prm, ti.static((start, cid, gf, gi)))
            put(acc_out, i, u)
            if nonfinite(u, xi):
                ti.atomic_add(bad[0], 1)

    return euler, accel
