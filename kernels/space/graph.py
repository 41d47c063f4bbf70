"""Graph observables on the neighbour grid: connected components and degrees.

Union-find with atomic_min hooking (parent[x] <= x always, so no cycles can form): a
union that loses a race simply retries with the root it lost to. The component count is
exact whatever the thread interleaving.
"""

from functools import cache

import numpy as np
import taichi as ti

from ..runtime import as_real
from .grid import Grid, make_visitor, row, within

nd = ti.types.ndarray()


@ti.func
def find(parent: ti.template(), x):
    while parent[x] != x:
        p = parent[x]
        parent[x] = parent[p]  # path halving: only ever points further up the same tree
        x = p
    return x


@ti.func
def link(parent: ti.template(), u, v):
    """Join the trees of u and v (roots, or nodes of them); returns the joined root."""
    while u != v:
        if u < v:
            u, v = v, u
        old = ti.atomic_min(parent[u], v)
        if old == u:
            break  # hooked root u under v
        # u was hooked elsewhere meanwhile: join what it now points to with v.
        u = find(parent, old)
        v = find(parent, v)
    return find(parent, v)


@ti.func
def find_serial(parent: ti.template(), x):
    """The root of x, for one thread per forest (the fused batches: one replica per task)."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]  # path halving
        x = parent[x]
    return x


@ti.func
def union_serial(parent: ti.template(), u, v):
    """Join the trees of u and v under the smaller root (one thread per forest)."""
    ru = find_serial(parent, u)
    rv = find_serial(parent, v)
    if ru != rv:
        parent[ti.max(ru, rv)] = ti.min(ru, rv)


@ti.kernel
def reset_parent(parent: nd):
    for i in range(parent.shape[0]):
        parent[i] = i


@ti.kernel
def flatten(parent: nd):
    """parent[i] = the root of i's tree, in place: the forest's component labels without a
    second array. Safe in parallel: a concurrent find only moves a pointer up its own tree,
    whose root no thread changes."""
    for i in range(parent.shape[0]):
        parent[i] = find(parent, i)


@ti.kernel
def count_roots(parent: nd) -> ti.i32:
    n = 0
    for i in range(parent.shape[0]):
        if parent[i] == i:
            n += 1
    return n


@cache
def metric_graph_kernel(inclusive: bool, periodic: bool, by_id: bool, dim: int = 2):
    """Kernel: for the metric graph |d| < r (or <= r) on a built grid, write each agent's
    degree (bucket order) and union every edge into `parent`, indexed by storage slot
    (cache-friendly; enough for this step's components) or by agent id (for unions that
    accumulate across steps, whose storage order changes)."""

    @ti.func
    def node(ids: ti.template(), k):
        res = k
        if ti.static(by_id):
            res = ids[k]
        return res

    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        # Each pair once (half stencil, k "after" i). acc = (i's degree count, a root of
        # i's tree): i's root is found once per agent, not once per edge.
        ids, parent, deg, r2 = ti.static(S[0], S[1], S[2], S[3])
        if within(d.dot(d), r2[0], inclusive):
            acc[0] += 1
            ti.atomic_add(deg[k], 1)
            rk = find(parent, node(ids, k))
            if rk != acc[1]:
                acc[1] = link(parent, acc[1], rk)
        return acc

    visit = make_visitor(pair, half=True, dim=dim)

    @ti.kernel
    def graph(pos: nd, ids: nd, parent: nd, deg: nd, r2: nd,
              start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            deg[i] = 0
        for i in range(pos.shape[0]):
            xi = row(pos, i, dim)
            acc = ti.math.ivec2(0, find(parent, node(ids, i)))
            acc = visit(i, xi, acc, pos, ti.static((start, cid, gf, gi)),
                        ti.static((ids, parent, deg, r2)), periodic)
            ti.atomic_add(deg[i], acc[0])

    return graph


class MetricGraph:
    """Components and degrees of the graph |r_ij| < r (or <=) over the same grid."""

    def __init__(self, n: int, radius: float, inclusive: bool, periodic: bool, dim: int = 2):
        self.kernel = metric_graph_kernel(inclusive, periodic, False, dim)
        self.kernel_by_id = metric_graph_kernel(inclusive, periodic, True, dim)
        self.r2 = ti.ndarray(float, shape=1)
        self.r2.from_numpy(as_real([radius * radius]))
        self.parent = ti.ndarray(ti.i32, shape=n)
        self.deg = ti.ndarray(ti.i32, shape=n)

    def union_edges(self, grid: Grid, pos_sorted, ids_sorted, parent=None) -> None:
        """Union every edge of the current graph into `parent`, an id-indexed forest kept
        across steps; default: this step's own slot-indexed forest, reset first."""
        kernel = self.kernel_by_id
        if parent is None:
            parent, kernel = self.parent, self.kernel
            reset_parent(parent)
        kernel(pos_sorted, ids_sorted, parent, self.deg, self.r2, *grid.view())

    def observe(self, grid: Grid, pos_sorted, ids_sorted) -> dict[str, float]:
        self.union_edges(grid, pos_sorted, ids_sorted)
        return self.summary()

    def summary(self) -> dict[str, float]:
        """Components and degree statistics from `parent` and `deg` as last filled (by
        `union_edges`, or by a model kernel that fuses the same work into its step)."""
        deg = self.deg.to_numpy()
        return {
            "components": float(count_roots(self.parent)),
            "degree_mean": float(deg.mean()),
            "degree_min": float(deg.min()),
            "degree_max": float(deg.max()),
            "isolated": float(np.count_nonzero(deg == 0)),
        }
