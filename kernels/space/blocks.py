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

A kernel loops over cells (`for bucket in range(n_cells)`) and calls a `make_cell_pass`
function: it cuts the cell's agents into blocks of BLOCK_LANES (the last one short: its
spare lanes repeat its last agent, computed and not written), calls `visit_block(c, I, X,
acc, pos, G, S)`: acc (BLOCK_LANES x width) += the block's candidates' terms, and then the
model's update for each agent. Two visitors:
- `make_block_visitor(pair, dim)`, the periodic box with at least 3 cells across
  (Grid.blocks): a block pair `pair(k, p, I, X, acc, S)` for every candidate (Vicsek's
  step: its pair is a few multiplications, written four lanes wide).
- `make_sieved_visitor(sieve, pair, dim)`, plane_grid.DenseGrid: a branch-free distance
  test for every lane and candidate lists each lane's neighbours, and the model's
  per-agent pair runs for those alone (M2 and M3: a division and a branch each).
The hashed grid of sprawling swarms keeps the per-agent visit: its buckets mix cells.

Measured (10^6 agents, float64, one process, the kernels alternated): Vicsek's step 0.60
of the per-agent step's time in 3D, 0.77 in 2D; M2's Euler step, sieved, 0.60 of the
blocks without the sieve in 3D and 2D (that itself 0.82-0.94 of the per-agent step).
"""

import taichi as ti

from .grid import PERIODIC_REACH, box_layer, row, shifted, wrap_cell

BLOCK_LANES = 4  # agents per block: four doubles fill an AVX2 register
SIEVE_CAP = 64  # candidates a sieved visit lists per lane before it runs the pair
# Listed neighbours whose terms a sieved visit computes side by side: M2's step ran as fast
# with 4 (3D 0.8-0.9 of one at a time) and took 2-3 s longer to compile.
PAIRS_AT_ONCE = 2


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
    """The cell numbered `bucket` in a row-major grid of gi cells (x fastest, then y, then
    z): a DenseGrid's bucket, or a fused flocking replica's cell."""
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
    """The number of cell (0, ry, rz) in a row-major grid of gi cells (a DenseGrid's
    bucket): rows of x-cells are contiguous."""
    return gi[0] * (ry + gi[1] * rz)


@ti.func
def grid_row(start: ti.template(), c0, c, b, e, lo, hi, shape: ti.template(),
             dim: ti.template()):
    """The agents k0 .. k1 - 1 (as a vector (k0, k1)) of the cells lo .. hi along x at
    y = c[1] + b (3D: z = c[2] + e) of a row-major grid of `shape` cells (x fastest, then
    y, then z) whose first cell is start's entry c0: contiguous, x being the fastest index;
    (0, 0) for a row off the grid. The DenseGrid (c0 = 0) and the fused flocking batch's
    per-replica agent and obstacle grids (c0: the replica's first cell) read their rows
    here."""
    k = ti.Vector([0, 0])
    ry = c[1] + b
    rz = 0
    inside = (lo <= hi) & (ry >= 0) & (ry < shape[1])
    if ti.static(dim == 3):
        rz = c[2] + e
        inside = inside & (rz >= 0) & (rz < shape[2])
    if inside:
        r0 = c0 + dense_row_start(ry, rz, shape)
        k = ti.Vector([start[r0 + lo], start[r0 + hi + 1]])
    return k


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


def make_cell_pass(visit_block, update, width: int, layout: str, dim: int):
    """Return `cell_pass(bucket, pos, G, S, F, v)`: the agents of cell `bucket` in blocks
    of BLOCK_LANES, each block's sums (BLOCK_LANES x width, from zero) from
    `visit_block(c, I, X, sums, pos, G, S)`, then `update(i, x_i, sums_i, F, v)` for each
    of the block's agents. F: the update's arrays (a static tuple); v: its runtime values
    (a small vector: Vicsek's noise keys)."""

    @ti.func
    def cell_pass(bucket, pos: ti.template(), G: ti.template(), S: ti.template(),
                  F: ti.template(), v):
        start = ti.static(G[0])
        c = cell_of(bucket, G, layout, dim)
        i0 = start[bucket]
        while i0 < start[bucket + 1]:
            m = ti.min(start[bucket + 1] - i0, BLOCK_LANES)
            Iv, X = load_block(pos, i0, m, dim)
            sums = ti.Matrix.zero(float, BLOCK_LANES, width)
            visit_block(c, Iv, X, sums, pos, G, S)
            for q in ti.static(range(BLOCK_LANES)):
                if q < m:
                    update(Iv[q], lane(X, q), lane(sums, q), F, v)
            i0 += BLOCK_LANES

    return cell_pass


def make_block_visitor(pair, dim: int):
    """Return `visit_block(c, I, X, acc, pos, G, S)` in the periodic box: `pair(k, p, I,
    X, acc, S)` (acc updated in place) for every candidate k of the block of agents in
    cell c, in the per-agent visit's order, p = r_k as that visit sees it from c (the
    periodic image)."""
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

    return visit_box


def make_sieved_visitor(sieve, pair, dim: int):
    """`visit_block(c, I, X, acc, pos, G, S)` on a DenseGrid for a per-agent pair
    `pair(i, k, d, acc, S) -> acc + term` whose term is zero for the agent itself and for
    the candidates that `sieve(i, k, d2, S)` (0 or 1) rejects: each lane's sum is the
    per-agent visit's, bit for bit (adding a zero changes no sum that starts at +0).

    Two passes over each stretch of at most SIEVE_CAP candidates: the sieve for every
    lane and candidate, branch-free (a distance test, four lanes to a vector register),
    listing the candidates it keeps per lane; then `pair` over each live lane's list, in
    the visit's order. A pair that costs a division and a branch then runs for the
    neighbours alone (M2 in 3D: about 16 of 98 candidates), not for every candidate."""

    rows = 3 ** (dim - 1)  # of the 3x3 (3x3x3) block: 3 (9)

    @ti.func
    def flush(Iv, X: ti.template(), acc: ti.template(), pos: ti.template(), S: ti.template(),
              listed: ti.template(), count: ti.template()):
        """pair over each live lane's list (a short block's spare lanes repeat its last
        agent: skipped), and the lists emptied. PAIRS_AT_ONCE listed agents at a time:
        their terms side by side (vector instructions: one division for two), then added
        in the list's order; the list is padded with the agent itself, whose term is
        zero."""
        for q in ti.static(range(BLOCK_LANES)):
            live = True
            if ti.static(q > 0):
                live = Iv[q] != Iv[q - 1]
            if live:
                i = Iv[q]
                a = lane(acc, q)
                xq = lane(X, q)
                for j in ti.static(range(PAIRS_AT_ONCE - 1)):
                    listed[q, count[q] + j] = i
                e0 = 0
                while e0 < count[q]:
                    T = ti.Matrix.zero(float, PAIRS_AT_ONCE, acc.m)
                    for j in ti.static(range(PAIRS_AT_ONCE)):
                        k = listed[q, e0 + j]
                        t = pair(i, k, row(pos, k, dim) - xq, ti.Vector.zero(float, acc.m), S)
                        for m in ti.static(range(acc.m)):
                            T[j, m] = t[m]
                    for j in ti.static(range(PAIRS_AT_ONCE)):
                        a = a + lane(T, j)
                    e0 += PAIRS_AT_ONCE
                for m in ti.static(range(acc.m)):
                    acc[q, m] = a[m]
            count[q] = 0

    @ti.func
    def visit_block(c, Iv, X: ti.template(), acc: ti.template(), pos: ti.template(),
                    G: ti.template(), S: ti.template()):
        """The rows of cell c's 3x3 (3x3x3) block in the per-agent visit's order (z layers
        outermost, then y; a row's three cells are contiguous), each sieved a list's room
        at a time; one row past the last runs the final pair pass (one call of flush in
        the code: it is compiled once)."""
        start, gi = ti.static(G[0], G[3])
        listed = ti.Matrix.zero(ti.i32, BLOCK_LANES, SIEVE_CAP + PAIRS_AT_ONCE - 1)
        count = ti.Vector.zero(ti.i32, BLOCK_LANES)
        lo = ti.max(c[0] - 1, 0)
        hi = ti.min(c[0] + 1, gi[0] - 1)
        for r in range(rows + 1):
            rk = ti.Vector([0, 0])
            if r < rows:
                rk = grid_row(start, 0, c, r % 3 - 1, r // 3 - 1, lo, hi, gi, dim)
            k0, k1 = rk[0], rk[1]
            more = True
            while more:
                k2 = ti.min(k1, k0 + SIEVE_CAP)
                if (r == rows) | (count.max() + (k2 - k0) > SIEVE_CAP):
                    flush(Iv, X, acc, pos, S, listed, count)
                for k in range(k0, k2):
                    p = row(pos, k, dim)
                    for q in ti.static(range(BLOCK_LANES)):
                        d = p - lane(X, q)
                        listed[q, count[q]] = k  # kept only if the count moves past it
                        count[q] += sieve(Iv[q], k, d.dot(d), S)
                k0 = k2
                more = k0 < k1

    return visit_block
