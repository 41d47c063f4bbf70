"""The per-step schedule's Taichi kernel of Couzin's law (law.py): parallel over the agents
of one replica, one launch per step.

Agent i's zone sums run over the 3x3 (3D: 3x3x3) cells of the plane grid around it, cells
of side r_a (kernels/space/plane_grid.py: dense rows while the group is compact, else the
hashed grid; the state kept in grid order, `ids` giving each slot's agent for the noise).
Every agent reads the state at t and writes its (x', e') into the spare buffers (the
paper's synchronous update). A non-finite result increments bad[0]; the caller raises
SimulationDiverged.
"""

from functools import cache

import taichi as ti

from ...space.grid import put, row
from ...space.integrate import nonfinite
from ...space.plane_grid import visitor
from . import law

nd = ti.types.ndarray()


@cache
def step_kernel(dim: int, search: str):
    """The step for `search` ("hash", "dense" or "all_pairs") in dimension `dim`."""

    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        # S = (ew, q, e_i): q and e_i are the agent's values, read once, not per pair.
        return law.zone_term(acc, d, row(S[0], k, dim), S[2], S[1])

    visit = visitor(pair, search, dim)

    @ti.kernel
    def step(pos: nd, ew: nd, ids: nd, pos_out: nd, ew_out: nd, prm: nd, k0: ti.u32,
             k1: ti.u32, k2: ti.u32, bad: nd, start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi = row(pos, i, dim)
            ei = row(ew, i, dim)
            q = law.load(prm)
            acc = visit(i, xi, law.zero_acc(dim), pos, ti.static((start, cid, gf, gi)),
                        (ew, q, ei), False)
            x, e = law.agent_step(xi, ei, acc, ids[i], ti.Vector([k0, k1, k2], dt=ti.u32), q)
            put(pos_out, i, x)
            put(ew_out, i, e)
            if nonfinite(x, e):
                ti.atomic_add(bad[0], 1)

    return step
