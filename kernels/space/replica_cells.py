"""The fused schedules' per-replica cell list: one replica's agents in cells, inside one
CPU task (kernels/space/cells.py's stable counting sort, no atomics).

`make_replica_cells(...)` gives `build(a0, n, c0, cap, w0, L, src, cell, cstart, cidx, S)`
for the replica whose agents are rows a0 .. a0 + n of `src` (positions in columns
0 .. dim), whose cells are cstart's entries c0 .. c0 + cap (a budget of `cap` cells):
  periodic  the box [0, L)^dim in nc = min(floor(L / w0), cap^(1/dim)) cells across, of
            side L / nc (fewer than three across: no cells);
  plane     cells of side w0 over the bounding box (numbered x fastest, then y, then z),
            while they fit the budget; past it, `cap` hashed buckets of the same cells
            (`may_hash`: every agent checked against its exact cell in the visit) or cells
            widened until they fit (a swarm spread over 10^6 radii then shares a few large
            cells: slower, never wrong); under three cells every way: no cells. A swarm
            over max_cells_across cells of w0 wide (or NaN) ran away: nothing is built;
  no cells  every pair is visited, slots in id order (also at n <= min_n).
cidx[a0 + k] is the agent in slot k, slots in cell order and, within a cell, in id order,
and cell c holds slots cstart[c0 + c] .. cstart[c0 + c + 1]; `place(slot, agent, S)` is
called for each agent as it lands, if given (a family copying its state into slot order
on the way). `build` returns the grid vector, read with the G_ slots: cells across
(G_NX: 0 no cells, -1 ran away; hashed: the bucket count, with G_NY = -1), the cell side,
the swarm's widest extent (the plane) and the grid's origin.
"""

import taichi as ti

from .cells import clear_cells, make_cell_sort
from .grid import max_cells_across

# The grid vector's slots: cells across each way (nz = 1 in 2D), cell side, extent, then
# the origin (dim values).
G_NX, G_NY, G_NZ, G_W, G_SPAN, G_O = range(6)


@ti.func
def bucket(c, nb):
    """The hashed bucket of the integer cell c among nb (as kernels/space/grid.py's
    buckets: the 3D hash adds Teschner et al.'s third prime)."""
    h = (ti.cast(c[0], ti.u32) * ti.u32(73856093)) ^ (ti.cast(c[1], ti.u32) * ti.u32(19349663))
    if ti.static(c.n == 3):
        h ^= ti.cast(c[2], ti.u32) * ti.u32(83492791)
    h ^= h >> ti.u32(13)
    return ti.cast(h % ti.cast(nb, ti.u32), ti.i32)


@ti.func
def cells_for(ext, w):
    """Cells of side w over a box of extent ext: prod (ext / w + 1) (a float: no overflow)."""
    cells = (ext[0] / w + 1.0) * (ext[1] / w + 1.0)
    if ti.static(ext.n == 3):
        cells *= ext[2] / w + 1.0
    return cells


@ti.func
def _full(x, dim: ti.template()):
    """The dim-vector (x, ..., x) of the float type."""
    return ti.Vector([x for _ in ti.static(range(dim))], dt=float)


@ti.func
def _per_axis(cap, dim: ti.template()):
    """The cells across a periodic box within a budget of cap: its square (cube) root."""
    per_axis = ti.cast(ti.sqrt(cap), ti.i32)
    if ti.static(dim == 3):  # the integer cube root of the cell budget
        per_axis = ti.cast(ti.pow(ti.cast(cap, float), 1.0 / 3.0), ti.i32)
        while (per_axis + 1) ** 3 <= cap:
            per_axis += 1
        while per_axis**3 > cap:
            per_axis -= 1
    return per_axis


def make_replica_cells(dim: int, periodic: bool = False, may_hash: bool = False,
                       min_n: int = 0, reciprocal: bool = False, place=None):
    """`build` (see the module) for one geometry and dimension. `min_n`: at n <= min_n no
    cells (fewer operations than cells; 0: the caller decides). `reciprocal`: an agent's
    cell coordinate is (x - o) * (1 / w) (Vicsek's schedule) instead of (x - o) / w
    (flocking's): the two round differently, and each family keeps the bits it has always
    had."""
    sort, in_id_order = make_cell_sort(place)

    @ti.func
    def box(n, cap, w0, L):
        """(nx, w) of the periodic box: nx = 0 under three cells across."""
        nx = 0
        w = w0
        if n > min_n:
            nc = ti.min(ti.cast(ti.floor(L / w), ti.i32), _per_axis(cap, dim))
            if nc >= 3:  # fewer: the 3x3 block would meet a cell twice
                nx = nc
                w = L / nc
        return nx, w

    @ti.func
    def plane(a0, n, cap, w0, src: ti.template()):
        """(cells across, cell side, extent, origin) over the bounding box of the
        replica's positions."""
        lo = _full(ti.math.inf, dim)
        hi = _full(-ti.math.inf, dim)
        for i in range(a0, a0 + n):
            p = ti.Vector([src[i, c] for c in ti.static(range(dim))], dt=float)
            lo = ti.min(lo, p)
            hi = ti.max(hi, p)
        ext = hi - lo
        w = w0
        nc = ti.math.ivec3(0, 0, 1)
        hashed = 0
        span = ti.max(ext[0], ext[1])
        if ti.static(dim == 3):
            span = ti.max(span, ext[2])
        gridded = n > min_n
        if not (span < ti.static(max_cells_across(dim)) * w):  # NaN included
            nc[0] = -1
        elif gridded:
            if cells_for(ext, w) > cap:
                if ti.static(may_hash):
                    hashed = 1
                else:
                    while cells_for(ext, w) > cap:
                        w *= 2.0
            if hashed:
                nc[0] = cap
                nc[1] = -1
            else:
                for c in ti.static(range(dim)):
                    nc[c] = ti.cast(ti.floor(ext[c] / w), ti.i32) + 1
                if nc[0] < 3 and nc[1] < 3 and nc[2] < 3:
                    nc[0] = 0
        return nc, w, span, lo

    @ti.func
    def build(a0, n, c0, cap, w0, L, src: ti.template(), cell: ti.template(),
              cstart: ti.template(), cidx: ti.template(), S: ti.template()):
        nc = ti.math.ivec3(0, 0, 1)
        w = w0
        span = 0.0
        o = _full(0.0, dim)
        if ti.static(periodic):
            nx, w = box(n, cap, w0, L)
            if nx > 0:
                for c in ti.static(range(dim)):
                    nc[c] = nx
        else:
            nc, w, span, o = plane(a0, n, cap, w0, src)
        if nc[0] > 0:
            nb = nc[0] * nc[1] * nc[2]
            if ti.static(may_hash):
                if nc[1] < 0:
                    nb = cap
            clear_cells(c0, nb, cstart)
            inv = 1.0 / w
            for i in range(a0, a0 + n):
                cc = _cell(i, nc, nb, w, inv, o, src)
                cell[i] = cc
                cstart[c0 + cc + 1] = cstart[c0 + cc + 1] + 1
            sort(a0, n, c0, nb, cell, cstart, cidx, S)
        elif nc[0] == 0:
            in_id_order(a0, n, cidx, S)
        return ti.Vector([ti.cast(nc[0], float), ti.cast(nc[1], float),
                          ti.cast(nc[2], float), w, span] + [o[c] for c in ti.static(range(dim))],
                         dt=float)

    @ti.func
    def _cell(i, nc, nb, w, inv, o, src: ti.template()):
        """Agent i's cell (its bucket, hashed) among the nc cells across."""
        c = ti.Vector([0 for _ in ti.static(range(dim))])
        for a in ti.static(range(dim)):
            if ti.static(reciprocal):
                c[a] = ti.cast(ti.floor((src[i, a] - o[a]) * inv), ti.i32)
            else:
                c[a] = ti.cast(ti.floor((src[i, a] - o[a]) / w), ti.i32)
        cc = 0
        if ti.static(may_hash):
            if nc[1] < 0:
                cc = bucket(c, nb)
        if nc[1] >= 0:
            cc = ti.max(ti.min(c[0], nc[0] - 1), 0) + nc[0] * ti.max(ti.min(c[1], nc[1] - 1), 0)
            if ti.static(dim == 3):
                cc += nc[0] * nc[1] * ti.max(ti.min(c[2], nc[2] - 1), 0)
        return cc

    return build
