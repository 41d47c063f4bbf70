"""Topological neighbours: each agent's k nearest other agents, on the uniform grid.

Metric-free interaction (Ballerini et al., PNAS 105, 1232, 2008): N_i = the k agents j != i
with the smallest |r_ij| (minimum image in the periodic box), equal distances ordered by
agent id, so N_i is one set whatever the storage order; with a cap r only agents with
|r_ij| < r (or <= r) count, and N_i may hold fewer than k. With N - 1 <= k every other
agent is a neighbour. `symmetric` adds the reverse edges: i ~ j when either is among the
other's k nearest (an undirected graph).

The search (any dimension, 2 or 3, the box or unbounded space), one thread per agent:
cells are sized for k (about CELL_AGENTS agents a cell at the mean density) and visited in
rings of Chebyshev distance m = 0, 1, 2, ... around agent i's cell c. Once rings 0..m are
read, every agent within G_m = m s + g of r_i has been seen (s the cell side, g the
distance from r_i to the nearest face of its own cell: the block of rings 0..m holds that
ball), less a hair for rounding in the cell coordinates (`grid.widen`). The search stops
when it holds k candidates and the k-th is within G_m (no unseen agent can be nearer, nor
as near with a smaller id), or when G_m reaches the cap, or when the rings cover every
cell. In the box a ring that would meet a cell twice (2m + 1 > cells across) hands over to
a scan of every agent (then the box is a few cells across: small N, or the agent's k
nearest span half the box). In unbounded space the rings are clipped to the swarm's
bounding box, so an isolated agent costs at most the cells of the box, about N / CELL_AGENTS.
No pair list is sorted: each candidate is offered to the agent's row of k, kept sorted by
(distance, id), by insertion from the end.

Output, in storage (grid) order: `nbr[i, t]` the slot of i's t-th nearest (t < cnt[i]),
and for `symmetric` the reverse edges that are not also forward ones as a slot-sorted CSR
(`in_start`, `in_src`), so any sum over N_i is gathered in one fixed order: the same bits
run to run.
"""

import math
from functools import cache

import numpy as np
import taichi as ti

from ..runtime import DevicePolicy, as_real
from .graph import find, link
from .grid import (
    _SCAN_BLOCK,
    Grid,
    _scan,
    _scan_blocked,
    bounding_box,
    cell_bucket,
    cell_id,
    flat_cell,
    periodic_cell,
    row,
    sort_segment,
    space_cell,
    widen,
)

nd = ti.types.ndarray()
# Agents a cell at the mean density. About half of them lie within the cell side s of an
# agent: with k / 2 a cell, rings 0 and 1 (9 cells in 2D, 27 in 3D) usually settle the k
# nearest (measured, bench/topological.py: fewer rings read more agents each).
CELL_AGENTS_PER_K = 0.5
# The search's parameters: the cap r^2 (inf: none), the rounding hair (a fraction of s),
# then the cells across of unbounded space's bounding box, per axis (from its corner).
R2, HAIR, HI = 0, 1, 2


def cell_side(n: int, k: int, extents: list[float], radius: float | None) -> float:
    """The cell side for N agents spread over a box of these extents: about
    CELL_AGENTS_PER_K * k agents a cell, no wider than the cap (whose ball then lies in
    rings 0..1)."""
    dim = len(extents)
    longest = max(extents)
    if longest <= 0.0 or not math.isfinite(longest):
        side = 1.0  # every agent at one point (or about to diverge): any side will do
    else:
        # Flat extents (a swarm on a line) count as the longest over N^(1/d): the cells
        # then stay at most N across on the long axis.
        floor = longest / max(n, 1) ** (1.0 / dim)
        volume = math.prod(max(e, floor) for e in extents)
        side = (volume * max(CELL_AGENTS_PER_K * k, 1.0) / max(n, 1)) ** (1.0 / dim)
    return side if radius is None else min(side, radius)


@ti.func
def _before(d2a, ida, d2b, idb):
    """(d2a, ida) < (d2b, idb) lexicographically: nearer, or as near with a smaller id."""
    res = d2a < d2b
    if d2a == d2b:
        res = ida < idb
    return res


@ti.func
def _offer(i, k, d2, cnt, worst, kk, ids: ti.template(), nbr: ti.template(),
           nd2: ti.template()):
    """Offer candidate slot k at squared distance d2 to i's row (cnt entries, sorted by
    (d2, id); `worst` the last one's d2 when the row is full, else inf). Returns the new
    (cnt, worst)."""
    if d2 <= worst:  # else farther than all k held: the common case, no memory touched
        idk = ids[k]
        take = cnt < kk
        if not take:
            take = _before(d2, idk, nd2[i, kk - 1], ids[nbr[i, kk - 1]])
        if take:
            t = ti.min(cnt, kk - 1)
            while t > 0:
                if not _before(d2, idk, nd2[i, t - 1], ids[nbr[i, t - 1]]):
                    break
                nbr[i, t] = nbr[i, t - 1]
                nd2[i, t] = nd2[i, t - 1]
                t -= 1
            nbr[i, t] = k
            nd2[i, t] = d2
            cnt = ti.min(cnt + 1, kk)
            if cnt == kk:
                worst = nd2[i, kk - 1]
    return cnt, worst


def _rings(periodic: bool, inclusive: bool, dim: int):
    """(consider, ring): offer agent k to agent i's row when it is within the radius, and
    offer every agent of the cells at one Chebyshev distance from i's cell."""

    @ti.func
    def consider(i, k, xi, cnt, worst, kk, L, prm: ti.template(), pos: ti.template(),
                 ids: ti.template(), nbr: ti.template(), nd2: ti.template()):
        d = row(pos, k, dim) - xi
        if ti.static(periodic):
            d -= L * ti.round(d / L)
        d2 = d.dot(d)
        ok = d2 < prm[R2]
        if ti.static(inclusive):
            ok = d2 <= prm[R2]
        if ok:
            cnt, worst = _offer(i, k, d2, cnt, worst, kk, ids, nbr, nd2)
        return cnt, worst

    @ti.func
    def scan_cell(i, t, xi, cnt, worst, kk, L, prm: ti.template(), pos: ti.template(),
                  ids: ti.template(), nbr: ti.template(), nd2: ti.template(),
                  start: ti.template(), cid: ti.template(), gi: ti.template()):
        """Offer every agent of cell t (coordinates: folded into the box, or unbounded
        space's, filtered by exact cell id) but i."""
        lo = 0
        hi = 0
        want = ti.i64(0)
        if ti.static(periodic):
            b = flat_cell(t, gi[0])
            lo = start[b]
            hi = start[b + 1]
        else:
            want = cell_id(t)
            b = cell_bucket(t, gi[1])
            lo = start[b]
            hi = start[b + 1]
        for k in range(lo, hi):
            take = k != i
            if ti.static(not periodic):
                take = take and cid[k] == want
            if take:
                cnt, worst = consider(i, k, xi, cnt, worst, kk, L, prm, pos, ids, nbr, nd2)
        return cnt, worst

    @ti.func
    def ring(i, m, c, lo, hi, xi, cnt, worst, kk, L, prm: ti.template(),
             pos: ti.template(), ids: ti.template(), nbr: ti.template(),
             nd2: ti.template(), start: ti.template(), cid: ti.template(),
             gi: ti.template()):
        """Offer the agents of the cells at Chebyshev distance exactly m from c, offsets
        clipped to [lo, hi] per axis: for each (y, z) offset, the whole x row where y or z
        is at distance m, else its two ends."""
        nc = gi[0]
        ez0, ez1 = 0, 0
        if ti.static(dim == 3):
            ez0, ez1 = lo[2], hi[2]
        for e in range(ez0, ez1 + 1):
            for b in range(lo[1], hi[1] + 1):
                edge = ti.max(ti.abs(b), ti.abs(e)) == m
                t = c
                t[1] = c[1] + b
                if ti.static(dim == 3):
                    t[2] = c[2] + e
                if ti.static(periodic):
                    for a in ti.static(range(1, dim)):
                        t[a] = (t[a] % nc + nc) % nc
                step = ti.select(edge, 1, 2 * m)  # m >= 1 off the edge rows
                a = -m
                while a <= m:
                    if lo[0] <= a and a <= hi[0]:
                        t[0] = c[0] + a
                        if ti.static(periodic):
                            t[0] = (t[0] % nc + nc) % nc
                        cnt, worst = scan_cell(i, t, xi, cnt, worst, kk, L, prm, pos, ids,
                                               nbr, nd2, start, cid, gi)
                    a += step
        return cnt, worst

    return consider, ring


@cache
def search_kernel(periodic: bool, inclusive: bool, dim: int):
    """Kernel: every agent's k nearest (the module's doc) into nbr, nd2, cnt."""
    consider, ring = _rings(periodic, inclusive, dim)

    @ti.func
    def nearest(i, kk, pos: ti.template(), ids: ti.template(), nbr: ti.template(),
                nd2: ti.template(), prm: ti.template(), start: ti.template(),
                cid: ti.template(), gf: ti.template(), gi: ti.template()):
        """Agent i's row of up to kk nearest; returns its count."""
        xi = row(pos, i, dim)
        s = gf[0]
        L = gf[1]
        nc = gi[0]
        c = ti.Vector.zero(ti.i32, dim)
        g = ti.math.inf  # distance from xi to its own cell's nearest face
        if ti.static(periodic):
            c = periodic_cell(xi, gf, nc)
        else:
            c = space_cell(xi, gf, 2)
        reach = 0  # rings beyond this many hold no cell (unbounded space: bounding box)
        for a in ti.static(range(dim)):
            origin = 0.0
            if ti.static(not periodic):
                origin = gf[2 + a]
                top = ti.cast(prm[HI + a], ti.i32)
                reach = ti.max(reach, ti.max(c[a], top - c[a]))
            below = xi[a] - (origin + c[a] * s)
            g = ti.min(g, ti.min(below, s - below))
        g = ti.max(g, 0.0) - prm[HAIR] * s
        cnt = 0
        worst = ti.math.inf
        m = 0
        scan_all = False
        while True:
            if ti.static(periodic):
                if 2 * m + 1 > nc:
                    scan_all = True
                    break
            lo = ti.Vector([-m] * dim)
            hi = ti.Vector([m] * dim)
            if ti.static(not periodic):
                for a in ti.static(range(dim)):
                    lo[a] = ti.max(-m, -c[a])
                    hi[a] = ti.min(m, ti.cast(prm[HI + a], ti.i32) - c[a])
            cnt, worst = ring(i, m, c, lo, hi, xi, cnt, worst, kk, L, prm, pos, ids, nbr,
                              nd2, start, cid, gi)
            seen = m * s + g  # every agent this near has been offered
            if seen > 0.0:
                if cnt == kk and worst <= seen * seen:
                    break
                if seen * seen >= prm[R2]:
                    break
            if ti.static(periodic):
                if 2 * m + 1 >= nc:
                    break  # the rings have covered the box
            else:
                if m >= reach:
                    break  # ... the bounding box
            m += 1
        if scan_all:
            cnt = 0
            worst = ti.math.inf
            for k in range(pos.shape[0]):
                if k != i:
                    cnt, worst = consider(i, k, xi, cnt, worst, kk, L, prm, pos, ids, nbr,
                                          nd2)
        return cnt

    @ti.kernel
    def search(pos: nd, ids: nd, nbr: nd, nd2: nd, cnt: nd, prm: nd, kk: ti.i32,
               start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            n_i = 0
            if kk > 0:
                n_i = nearest(i, kk, pos, ids, nbr, nd2, prm, start, cid, gf, gi)
            cnt[i] = n_i

    return search


@ti.func
def in_row(nbr: ti.template(), cnt: ti.template(), j, x):
    """Whether slot x is among j's k nearest."""
    found = False
    for t in range(cnt[j]):
        if nbr[j, t] == x:
            found = True
    return found


def make_knn_visitor(pair, symmetric: bool, dim: int = 2):
    """grid.make_visitor's interface over the k-NN lists of `TopologicalNeighbours.view()`
    (G = (nbr, cnt, in_start, in_src)): `acc = pair(i, k, d, acc, S)` folded over N_i,
    nearest first, then (`symmetric`) the reverse-only edges by slot, d = pos[k] - xi.
    Unbounded space only (no minimum image): the models with a metric visitor in the
    plane take their topological neighbours from here."""

    @ti.func
    def visit(i, xi, acc, pos: ti.template(), G: ti.template(), S: ti.template(),
              periodic: ti.template()):
        ti.static_assert(not periodic, "the k-NN visitor runs in unbounded space")
        nbr, cnt, in_start, in_src = ti.static(G[0], G[1], G[2], G[3])
        for t in range(cnt[i]):
            k = nbr[i, t]
            acc = pair(i, k, row(pos, k, dim) - xi, acc, S)
        if ti.static(symmetric):
            for e in range(in_start[i], in_start[i + 1]):
                k = in_src[e]
                acc = pair(i, k, row(pos, k, dim) - xi, acc, S)
        return acc

    return visit


@ti.kernel
def _count_reverse(nbr: nd, cnt: nd, in_cnt: nd):
    """in_cnt[j] = the agents i with j among their k nearest but not i among j's."""
    for j in range(in_cnt.shape[0]):
        in_cnt[j] = 0
    for i in range(cnt.shape[0]):
        for t in range(cnt[i]):
            j = nbr[i, t]
            if not in_row(nbr, cnt, j, i):
                ti.atomic_add(in_cnt[j], 1)


@ti.kernel
def _scatter_reverse(nbr: nd, cnt: nd, cursor: nd, in_start: nd, in_src: nd):
    """The reverse-only edges into j's segment of in_src, then each segment sorted by slot
    (atomic slots land in any order; sorted, the sums are gathered in one order)."""
    for i in range(cnt.shape[0]):
        for t in range(cnt[i]):
            j = nbr[i, t]
            if not in_row(nbr, cnt, j, i):
                in_src[ti.atomic_add(cursor[j], 1)] = i
    for j in range(cnt.shape[0]):
        sort_segment(in_src, in_start[j], in_start[j + 1])


@ti.kernel
def union_forward(nbr: nd, cnt: nd, ids: nd, parent: nd, by_id: ti.template()):
    """Union every edge i -> nbr[i, t] into `parent` (indexed by agent id with `by_id`,
    else by slot): the components of the (weakly connected, or symmetric) graph."""
    for i in range(cnt.shape[0]):
        for t in range(cnt[i]):
            u = i
            v = nbr[i, t]
            if ti.static(by_id):
                u = ids[u]
                v = ids[v]
            ru = find(parent, u)
            rv = find(parent, v)
            if ru != rv:
                link(parent, ru, rv)


class KnnGrid(Grid):
    """The uniform grid with cells sized for k nearest: fixed in the box (the mean
    density), from each step's bounding box in unbounded space."""

    def __init__(self, n: int, k: int, radius: float | None, periodic_L: float | None,
                 policy: DevicePolicy, dim: int):
        self.k = k
        self.cap = radius
        extents = [float(periodic_L)] * dim if periodic_L is not None else [1.0] * dim
        # Grid sizes cells radius * widen(): ask for the side over widen().
        super().__init__(n, cell_side(n, k, extents, radius) / widen(), periodic_L, policy,
                         dim)
        self.hi = [0] * dim  # unbounded space: cells across the bounding box, per axis

    def build(self, pos: ti.Ndarray, step: int = 0, bb: np.ndarray | None = None) -> None:
        if not self.periodic:
            d = self.dim
            if bb is None:
                bb = bounding_box(pos, self._bb_part)
            ext = [float(bb[d + a] - bb[a]) for a in range(d)]
            if all(math.isfinite(e) for e in ext):
                side = cell_side(self.n, self.k, ext, self.cap)
                self.gf[0] = side
                # one more than floor(extent / side): rounding in the cell coordinate
                self.hi = [int(e / side) + 1 for e in ext]
        super().build(pos, step, bb)


class TopologicalNeighbours:
    """The k nearest of every agent (module doc) on a `KnnGrid` (`grid`, which also sorts
    the state). `search(pos, ids)` after each sort; `view()` is what a gathering kernel
    reads: (nbr, cnt, in_start, in_src)."""

    def __init__(self, n: int, k: int, radius: float | None, inclusive: bool,
                 symmetric: bool, periodic_L: float | None, policy: DevicePolicy, dim: int):
        self.n = n
        self.kk = min(k, n - 1)
        self.symmetric = symmetric
        self.serial = policy.serial_scatter
        self.grid = KnnGrid(n, k, radius, periodic_L, policy, dim)
        self.kernel = search_kernel(periodic_L is not None, inclusive, dim)
        width = max(self.kk, 1)
        self.nbr = ti.ndarray(ti.i32, shape=(n, width))
        self.nd2 = ti.ndarray(float, shape=(n, width))
        self.cnt = ti.ndarray(ti.i32, shape=n)
        self.prm_np = np.zeros(HI + dim)
        self.prm_np[R2] = np.inf if radius is None else radius * radius
        self.prm_np[HAIR] = 2.0 * (widen() - 1.0)
        self.prm = ti.ndarray(float, shape=HI + dim)
        self.in_cnt = ti.ndarray(ti.i32, shape=n if symmetric else 1)
        self.in_start = ti.ndarray(ti.i32, shape=n + 1 if symmetric else 1)
        self.in_cursor = ti.ndarray(ti.i32, shape=n if symmetric else 1)
        self.in_src = ti.ndarray(ti.i32, shape=n * width if symmetric else 1)
        self._scan_part = None if self.serial or not symmetric else ti.ndarray(
            ti.i32, shape=-(-n // _SCAN_BLOCK))

    def search(self, pos: ti.Ndarray, ids: ti.Ndarray) -> None:
        """Every agent's k nearest, for positions `pos` in the grid's (just built) order."""
        self.prm_np[HI:] = self.grid.hi
        self.prm.from_numpy(as_real(self.prm_np))
        self.kernel(pos, ids, self.nbr, self.nd2, self.cnt, self.prm, self.kk,
                    *self.grid.view())
        if self.symmetric:
            _count_reverse(self.nbr, self.cnt, self.in_cnt)
            if self.serial:
                _scan(self.in_cnt, self.in_start, self.in_cursor)
            else:
                _scan_blocked(self.in_cnt, self.in_start, self.in_cursor, self._scan_part)
            _scatter_reverse(self.nbr, self.cnt, self.in_cursor, self.in_start, self.in_src)

    def view(self) -> tuple:
        return (self.nbr, self.cnt, self.in_start, self.in_src)

    def union_edges(self, ids: ti.Ndarray, parent: ti.Ndarray, by_id: bool) -> None:
        """Union every edge of the current graph into `parent` (not reset here)."""
        union_forward(self.nbr, self.cnt, ids, parent, by_id)

    def lists(self, ids: np.ndarray) -> list[list[int]]:
        """Each agent's neighbours as agent ids (`ids`: the agent of each slot), nearest
        first (symmetric: then the reverse-only ones by slot), indexed by agent id."""
        nbr, cnt = self.nbr.to_numpy(), self.cnt.to_numpy()
        out: list[list[int]] = [[] for _ in range(self.n)]
        start = self.in_start.to_numpy() if self.symmetric else None
        src = self.in_src.to_numpy() if self.symmetric else None
        for s in range(self.n):
            got = [int(ids[j]) for j in nbr[s, :cnt[s]]]
            if start is not None:
                got += [int(ids[j]) for j in src[start[s]:start[s + 1]]]
            out[int(ids[s])] = got
        return out
