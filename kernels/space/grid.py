"""Uniform-grid neighbour search: count -> scan -> stable scatter -> visit.

One source for 2D and 3D: the dimension (`dim`, 2 or 3) is a compile-time parameter, and
every position is a dim-vector. The 2D specialisation does exactly the arithmetic, in the
same order, that the 2D-only grid did (the bits of every 2D run are unchanged).

Build (once per step, from the positions in their current storage order):
  1. every agent gets a cell, and a bucket (the periodic box or cube: cell index itself;
     unbounded space: a hash of the cell's integer coordinates, so a swarm spread over
     10^6 radii costs no memory per unit of area or volume);
  2. an exclusive scan of the bucket counts gives each bucket's start;
  3. a *stable* scatter gives each agent its slot in bucket order (`perm`).
The engine then permutes the state into bucket order, so neighbour reads are contiguous,
and that order is the next step's storage order. Stability makes the order, and hence
every floating-point sum, identical run to run: the same seed gives the same trajectory.

Visit: `make_visitor(pair)` returns a Taichi function that calls `pair` for every agent k
in the 3x3 block (3D: 3x3x3) of cells around agent i, with the minimum-image displacement
d = r_k - r_i. `pair` applies the distance test itself (models differ: < or <=, per-agent
radii). On the plane, hash collisions are filtered by comparing exact cell ids, so no
agent is ever visited twice. No bucket has a fixed capacity: nothing can overflow.
In the box, once fewer than 3 cells fit across (r > L/3, or a sparse box's capped cell
count), the 3x3 block would meet a cell twice: the visit then reads every cell once and
takes each agent's minimum image, so any radius is right, r > L/2 and past the
half-diagonal included (one image per pair). It is a branch per agent on the cell count,
not per pair: the common case's loops are the same code as before.
kernels/space/blocks.py visits the same cells for the agents of one cell together.

Cells are a hair wider than the radius (`widen()`), so rounding in floor() can never
place two agents within the radius two cells apart. The rounding of a cell coordinate is
relative to the cells across, so the hair depends on the precision: 1e-9 in float64 (up to
2^30 cells across), 2^-7 in float32, where 1 + 1e-9 is 1 and a cell coordinate carries
about 3 n 2^-24 of error at n cells across (both agents: under 2^-7 up to 2^14 across).
"""

import math

import numpy as np
import taichi as ti

from .. import runtime
from ..result import SimulationDiverged
from ..runtime import DevicePolicy

nd = ti.types.ndarray()
# Cells a hair wider than the radius, per precision (see above).
_WIDEN = {"float64": 1.0 + 1e-9, "float32": 1.0 + 2.0**-7}
# Beyond this many cells across, i32 cell coordinates (and float precision) run out; in 3D
# three coordinates share the 64-bit cell id, 21 bits each.
_MAX_CELLS_ACROSS = {"float64": 2**30, "float32": 2**14}
MAX_CELLS_ACROSS_3D = 2**20


def widen() -> float:
    """The factor cells are wider than the radius in the running precision (called at
    kernel compile time too: a kernel compiled for float32 gets the float32 hair)."""
    return _WIDEN[runtime.current().precision]


def max_cells_across(dim: int = 2) -> int:
    """Cells across beyond which a swarm counts as runaway in the running precision."""
    limit = _MAX_CELLS_ACROSS[runtime.current().precision]
    return limit if dim == 2 else min(limit, MAX_CELLS_ACROSS_3D)


def runaway_cause(extent: float, dim: int = 2) -> str:
    """The one wording of a runaway swarm, on every path, in the running precision."""
    limit = max_cells_across(dim).bit_length() - 1
    tail = "; float32's limit: precision float64 allows 2^30" if limit < 20 else ""
    return (f"the swarm spans {extent:.3g} length units, over 2^{limit} neighbour radii "
            f"(agents escaping: dt too large or forces unbounded{tail})")
PERIODIC_REACH = 1  # cells per radius in the periodic box


def _next_pow2(x: int) -> int:
    return 1 << max(4, (x - 1).bit_length())


def vector_rows(a) -> bool:
    """Whether a kernel's array argument holds vectors ((N,) of dim-vectors, one load per
    row) rather than scalars ((N, dim), one load per component). Compile-time."""
    return len(a.element_shape()) == 1


@ti.func
def sort_segment(a: ti.template(), lo, hi):
    """Insertion sort of a[lo:hi], ascending: the stable order back after atomic slots
    filled a segment in any order (short segments: a cell's agents, an agent's edges)."""
    for k in range(lo + 1, hi):
        v = a[k]
        m = k - 1
        while m >= lo and a[m] > v:
            a[m + 1] = a[m]
            m -= 1
        a[m + 1] = v


@ti.func
def row(a: ti.template(), k, dim: ti.template()):
    """Row k of an (N, dim) array, or element k of an (N,) array of dim-vectors, as a
    dim-vector."""
    v = ti.Vector.zero(float, dim)
    if ti.static(vector_rows(a)):
        v = a[k]
    else:
        for c in ti.static(range(dim)):
            v[c] = a[k, c]
    return v


@ti.func
def put(a: ti.template(), i, x):
    """Row i of the (N, dim) array a = the dim-vector x (row's inverse)."""
    for c in ti.static(range(x.n)):
        a[i, c] = x[c]


@ti.func
def set_row(a: ti.template(), k, v):
    """Store the vector v as row k of `a` (either layout of `row`)."""
    if ti.static(vector_rows(a)):
        a[k] = v
    else:
        for c in ti.static(range(v.n)):
            a[k, c] = v[c]


@ti.func
def space_cell(xi, gf: ti.template(), origin: ti.template()):
    """Integer cell coordinates of point xi in unbounded space: cells of width gf[0] from
    the corner gf[origin:] (the hashed grid's view keeps it at 2, the dense grid's at 1)."""
    inv = 1.0 / gf[0]
    c = ti.Vector.zero(ti.i32, xi.n)
    for a in ti.static(range(xi.n)):
        c[a] = int(ti.floor((xi[a] - gf[origin + a]) * inv))
    return c


@ti.func
def plane_cell(x, y, gf: ti.template()):
    return space_cell(ti.math.vec2(x, y), gf, 2)


@ti.func
def plane_cell_id(cx, cy):
    # +1 keeps the coordinates of the 3x3 block around any agent non-negative.
    return ti.cast(cx + 1, ti.i64) | (ti.cast(cy + 1, ti.i64) << 32)


@ti.func
def plane_bucket(cx, cy, mask):
    h = (ti.cast(cx, ti.u32) * ti.u32(73856093)) ^ (ti.cast(cy, ti.u32) * ti.u32(19349663))
    h ^= h >> ti.u32(13)
    return ti.cast(h & ti.cast(mask, ti.u32), ti.i32)


@ti.func
def cell_id(c):
    """The exact 64-bit id of cell c (2 or 3 coordinates, each >= -1)."""
    res = ti.i64(0)
    if ti.static(c.n == 2):
        res = plane_cell_id(c[0], c[1])
    else:  # 21 bits a coordinate: MAX_CELLS_ACROSS_3D + 2 fits
        res = (ti.cast(c[0] + 1, ti.i64) | (ti.cast(c[1] + 1, ti.i64) << 21)
               | (ti.cast(c[2] + 1, ti.i64) << 42))
    return res


@ti.func
def cell_bucket(c, mask):
    """The hash bucket of cell c (the 3D hash adds Teschner et al.'s third prime)."""
    res = 0
    if ti.static(c.n == 2):
        res = plane_bucket(c[0], c[1], mask)
    else:
        h = ((ti.cast(c[0], ti.u32) * ti.u32(73856093))
             ^ (ti.cast(c[1], ti.u32) * ti.u32(19349663))
             ^ (ti.cast(c[2], ti.u32) * ti.u32(83492791)))
        h ^= h >> ti.u32(13)
        res = ti.cast(h & ti.cast(mask, ti.u32), ti.i32)
    return res


@ti.func
def periodic_cell(xi, gf: ti.template(), nc):
    inv = 1.0 / gf[0]
    # x < L, yet x / cell can round up to nc for an x within rounding of L (in float32,
    # about one agent per step at N = 10^7): that agent is in the last cell, and "% nc"
    # alone would put it in cell 0, across the seam from its neighbours.
    c = ti.Vector.zero(ti.i32, xi.n)
    for a in ti.static(range(xi.n)):
        c[a] = ti.min(int(ti.floor(xi[a] * inv)), nc - 1)
        # "% nc" (floored, as Python's) changes only a negative coordinate: a branch, not
        # an integer division per coordinate (two a step in the build and the visit
        # each: a tenth of a float32 step at 10^6).
        if c[a] < 0:
            c[a] %= nc
    return c


@ti.func
def flat_cell(c, nc):
    """Bucket of periodic cell c: x fastest, so x-adjacent cells are adjacent buckets."""
    res = c[0] + nc * c[1]
    if ti.static(c.n == 3):
        res = c[0] + nc * (c[1] + nc * c[2])
    return res


_BBOX_BLOCK = 4096  # agents per block of the bounding-box reduction


@ti.kernel
def _bbox_blocks(pos: nd, part: nd, dim: ti.template()):
    # Each block reduces its agents serially in registers; one shared atomic min/max per
    # agent instead cost 130 ms at N = 10^6 (every thread hammering the same four words).
    for blk in range(part.shape[0]):
        lo = ti.Vector([ti.math.inf] * dim, float)
        hi = ti.Vector([-ti.math.inf] * dim, float)
        for i in range(blk * _BBOX_BLOCK, ti.min((blk + 1) * _BBOX_BLOCK, pos.shape[0])):
            p = row(pos, i, dim)
            lo = ti.min(lo, p)
            hi = ti.max(hi, p)
        for c in ti.static(range(dim)):
            part[blk, c] = lo[c]
            part[blk, dim + c] = hi[c]


def bbox_buffer(n: int, dim: int = 2) -> ti.Ndarray:
    """Scratch for `bounding_box` of N agents (owned by a grid: Taichi arrays must not
    outlive the runtime that made them)."""
    return ti.ndarray(float, shape=(-(-n // _BBOX_BLOCK), 2 * dim))


def bounding_box(pos: ti.Ndarray, part: ti.Ndarray) -> np.ndarray:
    """(min x, min y, max x, max y) of an (N, 2) array, (min x, min y, min z, max x, ...)
    of an (N, 3) one: exact and order-independent."""
    dim = part.shape[1] // 2
    _bbox_blocks(pos, part, dim)
    p = part.to_numpy()
    return np.concatenate([p[:, :dim].min(axis=0), p[:, dim:].max(axis=0)])


@ti.kernel
def _assign(
    pos: nd, key: nd, cid: nd, count: nd, gf: nd, gi: nd, periodic: ti.template(),
    dim: ti.template()
):
    for b in range(count.shape[0]):
        count[b] = 0
    for i in range(pos.shape[0]):
        b = 0
        xi = row(pos, i, dim)
        if ti.static(periodic):
            nc = gi[0]
            b = flat_cell(periodic_cell(xi, gf, nc), nc)
        else:
            c = space_cell(xi, gf, 2)
            b = cell_bucket(c, gi[1])
            cid[i] = cell_id(c)
        key[i] = b
        ti.atomic_add(count[b], 1)


@ti.kernel
def _scan(count: nd, start: nd, cursor: nd):
    # Exclusive scan; serial (taichi's PrefixSumExecutor raises on the CPU backend).
    ti.loop_config(serialize=True)
    acc = 0
    for b in range(count.shape[0]):
        start[b] = acc
        cursor[b] = acc
        acc += count[b]
    start[count.shape[0]] = acc


_SCAN_BLOCK = 256  # buckets per block of the parallel scan


@ti.kernel
def _scan_blocked(count: nd, start: nd, cursor: nd, part: nd):
    # A GPU's exclusive scan (issue 8: the serial one is one thread on a GPU): each block
    # sums its counts in parallel, one thread scans the block sums (N / 256 of them at
    # most), and each block then scans its own counts from its offset. Integers: exactly
    # the serial scan's starts.
    nb = count.shape[0]
    for blk in range(part.shape[0]):
        s = 0
        for b in range(blk * _SCAN_BLOCK, ti.min((blk + 1) * _SCAN_BLOCK, nb)):
            s += count[b]
        part[blk] = s
    acc = 0
    ti.loop_config(serialize=True)
    for blk in range(part.shape[0]):
        s = part[blk]
        part[blk] = acc
        acc += s
    start[nb] = acc
    for blk in range(part.shape[0]):
        a = part[blk]
        for b in range(blk * _SCAN_BLOCK, ti.min((blk + 1) * _SCAN_BLOCK, nb)):
            start[b] = a
            cursor[b] = a
            a += count[b]


@ti.kernel
def _scatter_serial(key: nd, cursor: nd, perm: nd):
    # Stable counting-sort scatter: agents keep their relative order inside a bucket.
    ti.loop_config(serialize=True)
    for i in range(key.shape[0]):
        b = key[i]
        perm[i] = cursor[b]
        cursor[b] += 1


@ti.kernel
def _scatter_parallel(key: nd, cursor: nd, perm: nd, src: nd, start: nd):
    # GPU variant: atomic slots, then each bucket sorted by old index -> the stable order.
    for i in range(key.shape[0]):
        src[ti.atomic_add(cursor[key[i]], 1)] = i
    for b in range(start.shape[0] - 1):
        sort_segment(src, start[b], start[b + 1])
    for k in range(key.shape[0]):
        perm[src[k]] = k


@ti.kernel
def permute_rows(src: nd, dst: nd, perm: nd):
    """dst[perm[i], :] = src[i, :] for an (N, C) array."""
    for i in range(src.shape[0]):
        for c in range(src.shape[1]):
            dst[perm[i], c] = src[i, c]


@ti.kernel
def permute(src: nd, dst: nd, perm: nd):
    """dst[perm[i]] = src[i] for an (N,) array (of scalars or of vectors)."""
    for i in range(src.shape[0]):
        dst[perm[i]] = src[i]


def _icbrt(x: int) -> int:
    """floor(x^(1/3)) for a non-negative integer, exactly."""
    m = round(x ** (1.0 / 3.0))
    while m**3 > x:
        m -= 1
    while (m + 1) ** 3 <= x:
        m += 1
    return m


class Grid:
    """Neighbour grid for N agents with interaction radius `radius`, in `dim` = 2 or 3.

    `periodic_L` set: the box [0, L)^dim with wrap-around; None: unbounded space.
    After `build(pos)`, `perm[i]` is agent i's slot in bucket order, and `view()` is what a
    visitor needs (bucket starts, cell ids, geometry) as a static tuple for kernels.
    `policy.serial_scatter` picks the build: a serial scan and a serial stable scatter (the
    CPU's), or a blocked parallel scan and atomic slots then a per-bucket sort by old index
    (a GPU's); both give the same `start` and `perm`.
    """

    def __init__(self, n: int, radius: float, periodic_L: float | None,
                 policy: DevicePolicy, dim: int = 2):
        self.n = n
        self.dim = dim
        self.radius = float(radius)
        self.periodic = periodic_L is not None
        self.serial = policy.serial_scatter
        # Cells of side r (a hair more) and the 3x3 (3x3x3) block. Trimming each row to the
        # cells within reach of the agent (in 3D 23.5 % fewer candidates, counted) measured
        # no faster for Vicsek at 10^6 (slower in 2D), so the visit reads the whole block.
        self.reach = PERIODIC_REACH if self.periodic else 1
        cell = self.radius * widen() / self.reach
        if self.periodic:
            L = float(periodic_L)
            # Cap the cell count near 4 per agent: a sparse box then gets wider cells
            # (more candidates each) instead of memory per unit of area.
            root = math.isqrt if dim == 2 else _icbrt
            nc = max(1, min(int(L / cell), root(max(4 * n, 16))))
            self.nc = nc
            n_buckets = nc**dim
            cell = L / nc
        else:
            L = 0.0
            self.nc = 0
            n_buckets = _next_pow2(2 * n)
        self.n_buckets = n_buckets
        # blocks.make_block_visitor's case: a cell's 3x3 (3x3x3) block all distinct.
        self.blocks = self.periodic and self.nc >= 2 * self.reach + 1
        # gf: cell width, L, then the origin of unbounded space's cells (dim coordinates).
        self.gf = np.array([cell, L] + [0.0] * dim, dtype=runtime.real())
        self.gi = np.array([self.nc, n_buckets - 1], dtype=np.int32)
        self._gf_nd = ti.ndarray(float, shape=2 + dim)
        self._gi_nd = ti.ndarray(ti.i32, shape=2)
        self._gi_nd.from_numpy(self.gi)
        self._gf_nd.from_numpy(self.gf)
        self.key = ti.ndarray(ti.i32, shape=n)
        self.perm = ti.ndarray(ti.i32, shape=n)
        self.count = ti.ndarray(ti.i32, shape=n_buckets)
        self.start = ti.ndarray(ti.i32, shape=n_buckets + 1)
        self.cursor = ti.ndarray(ti.i32, shape=n_buckets)
        # Exact cell ids filter hash collisions on the plane (unused in the box).
        self.cid = ti.ndarray(ti.i64, shape=n if not self.periodic else 1)
        self.cid_sorted = ti.ndarray(ti.i64, shape=n if not self.periodic else 1)
        self._src = None if self.serial else ti.ndarray(ti.i32, shape=n)
        self._scan_part = None if self.serial else ti.ndarray(
            ti.i32, shape=-(-n_buckets // _SCAN_BLOCK))
        self._bb_part = None if self.periodic else bbox_buffer(n, dim)

    def build(self, pos: ti.Ndarray, step: int = 0, bb: np.ndarray | None = None) -> None:
        """Bucket the agents at `pos` ((N, dim), current storage order), compute `perm`.
        bb: their bounding box (`bounding_box`), when the caller has it already."""
        if not self.periodic:
            d = self.dim
            if bb is None:
                bb = bounding_box(pos, self._bb_part)
            extent = max(bb[d + c] - bb[c] for c in range(d))
            if not np.isfinite(extent):
                raise SimulationDiverged(step, "position", "a position became non-finite")
            if extent / self.gf[0] > max_cells_across(d):
                raise SimulationDiverged(step, "position", runaway_cause(extent, d))
            self.gf[2:] = bb[:d]
            self._gf_nd.from_numpy(self.gf)
        _assign(pos, self.key, self.cid, self.count, self._gf_nd, self._gi_nd, self.periodic,
                self.dim)
        if self.serial:
            _scan(self.count, self.start, self.cursor)
            _scatter_serial(self.key, self.cursor, self.perm)
        else:
            _scan_blocked(self.count, self.start, self.cursor, self._scan_part)
            _scatter_parallel(self.key, self.cursor, self.perm, self._src, self.start)
        if not self.periodic:
            permute(self.cid, self.cid_sorted, self.perm)

    def view(self) -> tuple:
        """Static tuple for kernels: (start, cell ids in bucket order, gf, gi)."""
        return (self.start, self.cid_sorted, self._gf_nd, self._gi_nd)


@ti.func
def shifted(pos: ti.template(), k, s, first: ti.template()):
    """pos[k] + s per component, the shift s skipped below component `first`."""
    p = row(pos, k, s.n)
    for a in ti.static(range(first, s.n)):
        p[a] = p[a] + s[a]
    return p


@ti.func
def _image(pos: ti.template(), k, xi, s, first: ti.template()):
    """d = pos[k] + s - xi per component, the shift s skipped below component `first`
    (the same additions, in the same order, as the 2D-only code wrote out)."""
    return shifted(pos, k, s, first) - xi


@ti.func
def wrap_cell(b, nc, L):
    """Cell coordinate b folded into [0, nc), and the shift (0 or +-L) that makes the
    folded cell's agents the images nearest to a point of the unfolded cell."""
    shift = 0.0
    if b < 0:
        b += nc
        shift = -L
    elif b >= nc:
        b -= nc
        shift = L
    return b, shift


@ti.func
def box_layer(c, e: ti.template(), nc, L, s: ti.template()):
    """The first bucket of the box's layer c[2] + e (3D; 0 in 2D), with that layer's seam
    shift put into s[2]."""
    layer = 0
    if ti.static(c.n == 3):
        bz, sz = wrap_cell(c[2] + e, nc, L)
        s[2] = sz
        layer = nc * nc * bz
    return layer


def make_visitor(pair, half: bool = False, dim: int = 2):
    """Return a Taichi function `visit(i, xi, acc, pos, G, S, periodic)` that folds
    `acc = pair(i, k, d, acc, S)` over every agent k in the cells around position xi
    (a dim-vector), where pos is in bucket order and d = pos[k] - xi (minimum image in the
    box).

    `half=True` visits each unordered pair once, from its first member: only the cells
    "after" i's (the rest of its row, the rows above in its layer and, in 3D, the layers
    above) and, in i's own cell, k > i. Symmetric relations (degrees, components) then cost
    half the candidates.

    The z layers of 3D are unrolled at compile time (`e` a Python int, 0 alone in 2D), so
    2D compiles to the 2D-only code's loops."""
    R = PERIODIC_REACH
    box_layers = range(0 if half else -R, R + 1) if dim == 3 else range(1)
    plane_layers = range(0 if half else -1, 2) if dim == 3 else range(1)

    @ti.func
    def visit(i, xi, acc, pos: ti.template(), G: ti.template(), S: ti.template(),
              periodic: ti.template()):
        start, cid, gf, gi = ti.static(G[0], G[1], G[2], G[3])
        if ti.static(periodic):
            nc = gi[0]
            L = gf[1]
            c = periodic_cell(xi, gf, nc)
            if nc >= 2 * R + 1:
                # Rows of x-adjacent cells are one contiguous bucket range unless the row
                # crosses the seam; a cell across the seam is read with the shift +-L
                # that makes r_k + shift the image nearest r_i.
                for e in ti.static(box_layers):
                    s = ti.Vector.zero(float, dim)
                    layer = box_layer(c, e, nc, L, s)
                    own_layer = ti.static(half and e == 0)
                    for b in range(ti.static(0 if own_layer else -R), R + 1):
                        by, sy = wrap_cell(c[1] + b, nc, L)
                        s[1] = sy
                        row0 = nc * by + layer
                        a0 = -R
                        if ti.static(own_layer):
                            if b == 0:
                                a0 = 0  # own cell and those to its right
                        if c[0] + a0 >= 0 and c[0] + R < nc:
                            k0 = start[row0 + c[0] + a0]
                            if ti.static(own_layer):
                                if b == 0:
                                    k0 = i + 1
                            for k in range(k0, start[row0 + c[0] + R + 1]):
                                acc = pair(i, k, _image(pos, k, xi, s, 1), acc, S)
                        else:
                            for a in range(a0, R + 1):
                                bx, sx = wrap_cell(c[0] + a, nc, L)
                                s[0] = sx
                                k0 = start[row0 + bx]
                                if ti.static(own_layer):
                                    if b == 0 and a == 0:
                                        k0 = i + 1
                                for k in range(k0, start[row0 + bx + 1]):
                                    acc = pair(i, k, _image(pos, k, xi, s, 0), acc, S)
            else:
                # At most 2R cells across: visit each once, minimum image per pair.
                for off in ti.grouped(ti.ndrange(*([nc] * dim))):
                    bucket = flat_cell((c + off) % nc, nc)
                    for k in range(start[bucket], start[bucket + 1]):
                        if ti.static(half):
                            if k <= i:
                                continue
                        d = row(pos, k, dim) - xi
                        d -= L * ti.round(d / L)
                        acc = pair(i, k, d, acc, S)
        else:
            c = space_cell(xi, gf, 2)
            t = c
            for e in ti.static(plane_layers):
                if ti.static(dim == 3):
                    t[2] = c[2] + e
                own_layer = ti.static(half and e == 0)
                for b in range(ti.static(0 if own_layer else -1), 2):
                    t[1] = c[1] + b
                    for a in range(-1, 2):
                        if ti.static(own_layer):
                            if b == 0 and a < 0:
                                continue
                        t[0] = c[0] + a
                        want = cell_id(t)
                        bucket = cell_bucket(t, gi[1])
                        k0 = start[bucket]
                        if ti.static(own_layer):
                            if a == 0 and b == 0:
                                k0 = i + 1  # i's own cell: i is in this bucket
                        for k in range(k0, start[bucket + 1]):
                            if cid[k] == want:
                                acc = pair(i, k, row(pos, k, dim) - xi, acc, S)
        return acc

    return visit


@ti.func
def within(d2, r2, inclusive: ti.template()):
    """The neighbourhood test as an i32: |d|^2 <= r^2 (inclusive) or |d|^2 < r^2.
    `inclusive` is a compile-time bool (one comparison compiled) or a runtime value
    (nonzero: inclusive; a fused batch's replicas may differ)."""
    res = 0
    if ti.static(isinstance(inclusive, (bool, int))):
        if ti.static(inclusive):
            res = ti.cast(d2 <= r2, ti.i32)
        else:
            res = ti.cast(d2 < r2, ti.i32)
    else:
        res = ti.select(inclusive != 0, ti.cast(d2 <= r2, ti.i32), ti.cast(d2 < r2, ti.i32))
    return res
