"""Cell blocks: the agents of one cell visit their neighbour cells together.

Agents in one cell share their 3x3 (3D: 3x3x3) block of cells, in grid order contiguous
rows of three cells. The per-agent visit (grid.make_visitor, plane_grid.make_dense_visitor)
repeats, for every agent, every row's bounds, loop and candidate loads; here up to
BLOCK_LANES agents of a cell (the "lanes") share one pass over the rows, and each candidate
k is loaded once for all of them. The lanes are independent sums side by side, which the
compiler turns into vector instructions.

Each lane's sum adds the same terms in the same order as the per-agent visit of that agent,
with the same displacement bits: p - x_i, p = r_k plus the periodic image shift exactly as
grid.make_visitor adds it. So a step by blocks is bit for bit the step by agents (which
the observation steps keep using, with their graph bookkeeping).

A kernel loops over cells (`for bucket in range(n_cells)`), cuts each cell's agents into
blocks of BLOCK_LANES (the last one short: its spare lanes repeat its last agent, computed
and not written), and calls `visit_block(c, I, X, acc, pos, G, S)`: acc (BLOCK_LANES x
width) += pair(k, p, I, X, ...) over the block's candidates. `lanes(pair)` turns a model's
per-agent pair function into such a pair.

Layouts: "box" (the periodic box with at least 3 cells across: Grid.blocks) and "dense"
(plane_grid.DenseGrid). The hashed grid of sprawling swarms keeps the per-agent visit: its
buckets mix cells.

Measured (Vicsek, 10^6 agents, float64, one process, the two kernels alternated): 0.60 of
the per-agent step's time in 3D, 0.77 in 2D.
"""

import taichi as ti

from .grid import PERIODIC_REACH, box_layer, row, shifted, wrap_cell

BLOCK_LANES = 4  # agents per block: four doubles fill an AVX2 register


@ti.func
def box_cell(bucket, nc, dim: ti.template()):
    """The periodic cell whose bucket is `bucket` (grid.flat_cell's inverse)."""
    c = ti.Vector.zero(ti.i32, dim)
    c[0] = bucket % nc
    if ti.static(dim == 2):
        c[1] = bucket // nc
    else:
        c[1] = (bucket // nc) % nc
        c[2] = bucket // (nc * nc)
    return c


@ti.func
def dense_cell(bucket, gi: ti.template(), dim: ti.template()):
    """The DenseGrid cell whose bucket is `bucket` (x fastest, then y, then z)."""
    c = ti.Vector.zero(ti.i32, dim)
    c[0] = bucket % gi[0]
    if ti.static(dim == 2):
        c[1] = bucket // gi[0]
    else:
        c[1] = (bucket // gi[0]) % gi[1]
        c[2] = bucket // (gi[0] * gi[1])
    return c


@ti.func
def dense_row_start(ry, rz, gi: ti.template()):
    """The bucket of DenseGrid cell (0, ry, rz): rows of x-cells are contiguous."""
    return gi[0] * (ry + gi[1] * rz)


@ti.func
def n_cells(G: ti.template(), layout: ti.template(), dim: ti.template()):
    """The cells of the grid view G (a DenseGrid's arrays may hold more than it uses)."""
    gi = ti.static(G[3])
    m = gi[0]
    if ti.static(layout == "box"):
        for _ in ti.static(range(1, dim)):
            m *= gi[0]
    else:
        for a in ti.static(range(1, dim)):
            m *= gi[a]
    return m


@ti.func
def cell_of(bucket, G: ti.template(), layout: ti.template(), dim: ti.template()):
    c = ti.Vector.zero(ti.i32, dim)
    if ti.static(layout == "box"):
        c = box_cell(bucket, ti.static(G[3])[0], dim)
    else:
        c = dense_cell(bucket, ti.static(G[3]), dim)
    return c


@ti.func
def load_block(pos: ti.template(), i0, m, dim: ti.template()):
    """The block of agents i0 .. i0 + m - 1 (m <= BLOCK_LANES): their slots I and positions
    X (one row a lane); the spare lanes repeat the last agent."""
    X = ti.Matrix.zero(float, BLOCK_LANES, dim)
    Iv = ti.Vector.zero(ti.i32, BLOCK_LANES)
    for q in ti.static(range(BLOCK_LANES)):
        Iv[q] = i0 + ti.min(q, m - 1)
        x = row(pos, Iv[q], dim)
        for a in ti.static(range(dim)):
            X[q, a] = x[a]
    return Iv, X


@ti.func
def lane(M, q: ti.template()):
    """Row q of the matrix M as a vector."""
    return ti.Vector([M[q, a] for a in ti.static(range(M.m))])


def lanes(pair):
    """A block pair from a per-agent pair `pair(i, k, d, acc, S) -> acc`: each lane q
    folds its own agent I[q] with d = p - X[q] into its row of acc. A short block's spare
    lanes (I[q] = I[q - 1]) are skipped: a branch the same for the block's every
    candidate, for a pair too costly to compute for nothing (a division, say)."""

    @ti.func
    def block_pair(k, p, Iv, X: ti.template(), acc: ti.template(), S: ti.template()):
        for q in ti.static(range(BLOCK_LANES)):
            live = True
            if ti.static(q > 0):
                live = Iv[q] != Iv[q - 1]
            if live:
                a = pair(Iv[q], k, p - lane(X, q), lane(acc, q), S)
                for j in ti.static(range(acc.m)):
                    acc[q, j] = a[j]

    return block_pair


def make_block_visitor(pair, dim: int, layout: str):
    """Return `visit_block(c, I, X, acc, pos, G, S)`: `pair(k, p, I, X, acc, S)` (acc
    updated in place) for every candidate k of the block of agents in cell c, in the
    per-agent visit's order, p = r_k as that visit sees it from c (the periodic image)."""
    R = PERIODIC_REACH
    layers = range(-1, 2) if dim == 3 else range(1)

    @ti.func
    def visit_box(c, Iv, X: ti.template(), acc: ti.template(), pos: ti.template(),
                  G: ti.template(), S: ti.template()):
        start, gf, gi = ti.static(G[0], G[2], G[3])
        nc = gi[0]
        L = gf[1]
        for e in ti.static(layers):
            s = ti.Vector.zero(float, dim)
            layer = box_layer(c, e, nc, L, s)
            for b in range(-R, R + 1):
                by, sy = wrap_cell(c[1] + b, nc, L)
                s[1] = sy
                row0 = nc * by + layer
                if c[0] - R >= 0 and c[0] + R < nc:  # the row's cells are contiguous
                    for k in range(start[row0 + c[0] - R], start[row0 + c[0] + R + 1]):
                        pair(k, shifted(pos, k, s, 1), Iv, X, acc, S)
                else:
                    for a in range(-R, R + 1):
                        bx, sx = wrap_cell(c[0] + a, nc, L)
                        s[0] = sx
                        for k in range(start[row0 + bx], start[row0 + bx + 1]):
                            pair(k, shifted(pos, k, s, 0), Iv, X, acc, S)

    @ti.func
    def visit_dense(c, Iv, X: ti.template(), acc: ti.template(), pos: ti.template(),
                    G: ti.template(), S: ti.template()):
        start, gi = ti.static(G[0], G[3])
        lo = ti.max(c[0] - 1, 0)
        hi = ti.min(c[0] + 1, gi[0] - 1)
        for e in ti.static(layers):
            rz = 0
            inside = lo <= hi
            if ti.static(dim == 3):
                rz = c[2] + e
                inside = inside & (rz >= 0) & (rz < gi[2])
            for b in range(3):
                ry = c[1] + b - 1
                if inside & (ry >= 0) & (ry < gi[1]):
                    r0 = dense_row_start(ry, rz, gi)
                    for k in range(start[r0 + lo], start[r0 + hi + 1]):
                        pair(k, row(pos, k, dim), Iv, X, acc, S)

    return visit_box if layout == "box" else visit_dense
