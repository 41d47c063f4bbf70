"""F2's neighbour graph |r_ij| < d (<= d if inclusive) as a union-find forest, on the step's
own grid (either PlaneGrid layout), for the components behind D3.

Each edge is united once, from its member in the lower storage slot (k > i), with the
engine's atomic hooking (kernels/space/graph.py: parent[x] <= x, exact under any thread
interleaving). The degrees come from the observation kernel, so none are kept here.
"""

from functools import cache

import taichi as ti

from ...space.graph import find, link
from ...space.grid import make_visitor, row, within
from ...space.plane_grid import make_dense_visitor

nd = ti.types.ndarray()


@cache
def union_kernel(inclusive: bool, dim: int, search: str):
    """Kernel (pos, parent, r2, *grid view): unite every edge of the metric graph into
    `parent` (slot-indexed, reset by the caller), over the layout `search` ("dense", "hash")."""

    @ti.func
    def pair(i, k, dv, acc, S: ti.template()):
        # acc: a root of i's tree, found once per agent rather than once per edge.
        parent, r2 = ti.static(S[0], S[1])
        if k > i and within(dv.dot(dv), r2[0], inclusive):
            rk = find(parent, k)
            if rk != acc:
                acc = link(parent, acc, rk)
        return acc

    visit = make_dense_visitor(pair, dim) if search == "dense" else make_visitor(pair, dim=dim)

    @ti.kernel
    def unite(pos: nd, parent: nd, r2: nd, start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            visit(i, row(pos, i, dim), find(parent, i), pos, ti.static((start, cid, gf, gi)),
                  ti.static((parent, r2)), False)

    return unite
