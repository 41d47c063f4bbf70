"""A dense grid for compact swarms in unbounded space: row-major cells over the bounding box.

The engine's unbounded grid (kernels/space/grid.py) hashes cells into buckets, so the 3x3
(3x3x3) cells around an agent lie at unrelated places in memory. When the swarm's
bounding box holds at most `CELLS_PER_AGENT` cells of side R per agent, this grid numbers
the cells row by row instead (x fastest, then y, then z): the three cells of a row are one
contiguous range of agents, as in the periodic box (a step of M2 at N = 10^6: 0.31 s
instead of 1.1 s here). A sprawling swarm (or a GPU, where the engine's parallel scatter
is needed) uses the engine's hashed grid instead. One source for 2D and 3D (`dim` at
compile time); the 2D arithmetic is the 2D-only grid's, operation for operation.

Build: bounding box -> cell c_a = floor((r_a - r_min,a) / cell) -> count -> exclusive
scan -> stable serial scatter (perm), so the order and every sum are reproducible.
Visit: `make_dense_visitor(pair, dim)` has the interface of grid.make_visitor and reads
the view (start, unused, gf, gi) with gf = (cell, x0, y0[, z0]), gi = (cells along x, y[, z]).
"""

import math

import numpy as np
import taichi as ti

from .. import runtime
from ..result import SimulationDiverged
from ..runtime import DevicePolicy
from .blocks import dense_row_start, grid_row
from .grid import (
    Grid,
    bbox_buffer,
    bounding_box,
    make_visitor,
    max_cells_across,
    row,
    space_cell,
    widen,
)
from .knn import make_knn_visitor

nd = ti.types.ndarray()
CELLS_PER_AGENT = 4


@ti.kernel
def _assign(pos: nd, key: nd, count: nd, gf: nd, gi: nd, dim: ti.template()):
    cells = gi[0] * gi[1]
    if ti.static(dim == 3):
        cells *= gi[2]
    for b in range(cells):
        count[b] = 0
    for i in range(pos.shape[0]):
        c = space_cell(row(pos, i, dim), gf, 1)
        k = c[0] + gi[0] * c[1]
        if ti.static(dim == 3):
            k = c[0] + dense_row_start(c[1], c[2], gi)
        key[i] = k
        ti.atomic_add(count[k], 1)


@ti.kernel
def _scan_scatter(key: nd, count: nd, start: nd, perm: nd, n_cells: ti.i32):
    # Serial: an exclusive scan, then a stable counting-sort scatter.
    ti.loop_config(serialize=True)
    acc = 0
    for b in range(n_cells):
        start[b] = acc
        acc += count[b]
    start[n_cells] = acc
    ti.loop_config(serialize=True)
    for b in range(n_cells):
        count[b] = start[b]  # count becomes the cursor
    ti.loop_config(serialize=True)
    for i in range(key.shape[0]):
        b = key[i]
        perm[i] = count[b]
        count[b] += 1


class DenseGrid:
    """Row-major cells of side `radius` over the current bounding box (CPU). The per-cell
    arrays hold the cells the swarm spans, a quarter more, and grow when a build needs
    more (a swarm at the density of its interaction range spans a few cells per 10
    agents: sizing them for the cap, 4 per agent, took 32 B/agent)."""

    def __init__(self, n: int, radius: float, dim: int = 2):
        self.n = n
        self.dim = dim
        self.radius = float(radius)
        self.cell = self.radius * widen()
        self.max_cells = CELLS_PER_AGENT * n + 16
        self.key = ti.ndarray(ti.i32, shape=n)
        self.perm = ti.ndarray(ti.i32, shape=n)
        self.cells = 0  # the cells `count` and `start` have room for
        self.n_buckets = 0  # the cells of the last build (count and start may hold more)
        self.count: ti.Ndarray | None = None
        self.start: ti.Ndarray | None = None
        self.gf = ti.ndarray(float, shape=1 + dim)
        self.gi = ti.ndarray(ti.i32, shape=dim)
        self._bb_part = bbox_buffer(n, dim)
        self.bbox: np.ndarray | None = None  # of the last build, kept or not

    def build(self, pos: ti.Ndarray, step: int) -> bool:
        """Bucket the agents at `pos`; False (nothing built) if the box needs more than
        CELLS_PER_AGENT cells per agent."""
        d = self.dim
        self.bbox = bb = bounding_box(pos, self._bb_part)
        extent = max(bb[d + a] - bb[a] for a in range(d))
        if not math.isfinite(extent):
            raise SimulationDiverged(step, "position", "a position became non-finite")
        if extent / self.cell > max_cells_across(d):
            return False  # the engine's grid reports the runaway swarm
        # One spare cell along each axis: floor() in the kernel may round up where int()
        # here rounds down, and no cell index may reach past the grid.
        shape = [int((bb[d + a] - bb[a]) / self.cell) + 2 for a in range(d)]
        cells = math.prod(shape)
        if cells > self.max_cells:
            return False
        self._reserve(cells)
        self.n_buckets = cells
        self.gf.from_numpy(runtime.as_real([self.cell, *bb[:d]]))
        self.gi.from_numpy(np.array(shape, dtype=np.int32))
        _assign(pos, self.key, self.count, self.gf, self.gi, d)
        _scan_scatter(self.key, self.count, self.start, self.perm, cells)
        return True

    def _reserve(self, cells: int) -> None:
        """Room for `cells` cells (the old arrays freed before the new are made)."""
        if cells > self.cells:
            self.count = self.start = None
            self.cells = min(self.max_cells, cells + cells // 4 + 16)
            self.count = ti.ndarray(ti.i32, shape=self.cells)
            self.start = ti.ndarray(ti.i32, shape=self.cells + 1)

    def view(self) -> tuple:
        """Static tuple for kernels, shaped like grid.Grid.view(): (start, -, gf, gi)."""
        return (self.start, self.key, self.gf, self.gi)


def make_dense_visitor(pair, dim: int = 2):
    """grid.make_visitor's interface over a DenseGrid: three contiguous rows of three cells
    (3D: nine rows, z layers outermost), each row's agents from blocks.grid_row, as
    blocks.make_sieved_visitor reads them for a cell's agents together. The per-agent visit
    keeps its own loop: folded through that visitor's in-place interface it measured slower
    (M4 F1's step at 10^6, three alternating pairs of processes: 113-118 ms against 99-116
    ms)."""
    layers = range(-1, 2) if dim == 3 else range(1)

    @ti.func
    def visit(i, xi, acc, pos: ti.template(), G: ti.template(), S: ti.template(),
              periodic: ti.template()):
        start, gf, gi = ti.static(G[0], G[2], G[3])
        c = space_cell(xi, gf, 1)
        lo = ti.max(c[0] - 1, 0)
        hi = ti.min(c[0] + 1, gi[0] - 1)
        for e in ti.static(layers):
            for b in range(3):
                rk = grid_row(start, 0, c, b - 1, e, lo, hi, gi, dim)
                for k in range(rk[0], rk[1]):
                    acc = pair(i, k, row(pos, k, dim) - xi, acc, S)
        return acc

    return visit


class PlaneGrid:
    """The neighbour grid of the plane models: a DenseGrid while the swarm is compact (where
    the policy allows one: the CPU), else the engine's hashed grid. `layout` names the one
    built last."""

    def __init__(self, n: int, radius: float, policy: DevicePolicy, dim: int = 2):
        self.n, self.radius, self.policy, self.dim = n, radius, policy, dim
        self.dense = DenseGrid(n, radius, dim) if policy.dense_grid else None
        self.hashed: Grid | None = None  # allocated when first needed
        self.layout = "hash"

    def build(self, pos: ti.Ndarray, step: int) -> None:
        bb = None
        if self.dense is not None:
            if self.dense.build(pos, step):
                self.layout = "dense"
                return
            bb = self.dense.bbox  # the hashed grid needs the same box: no second reduction
        self.layout = "hash"
        self._current().build(pos, step, bb)

    def _current(self) -> DenseGrid | Grid:
        if self.layout == "dense":
            return self.dense
        if self.hashed is None:
            self.hashed = Grid(self.n, self.radius, None, self.policy, self.dim)
        return self.hashed

    @property
    def perm(self) -> ti.Ndarray:
        return self._current().perm

    @property
    def n_buckets(self) -> int:
        """The buckets of the last build (a dense grid's cells; its arrays may hold more)."""
        return self._current().n_buckets

    def view(self) -> tuple:
        return self._current().view()


def make_all_pairs_visitor(pair):
    """grid.make_visitor's interface, folding `pair` over every agent k (no grid: O(N^2),
    for small N, where rebuilding a grid costs more than the pairs)."""

    @ti.func
    def visit(i, xi, acc, pos: ti.template(), G: ti.template(), S: ti.template(),
              periodic: ti.template()):
        for k in range(pos.shape[0]):
            acc = pair(i, k, row(pos, k, xi.n) - xi, acc, S)
        return acc

    return visit


def visitor(pair, search: str, dim: int = 2):
    """The neighbour loop for a search: all pairs, the engine's hashed grid, a DenseGrid,
    or the k nearest ("knn", "knn_symmetric": knn.py's lists)."""
    if search in ("knn", "knn_symmetric"):
        return make_knn_visitor(pair, search == "knn_symmetric", dim)
    if search == "hash":
        return make_visitor(pair, dim=dim)
    if search == "dense":
        return make_dense_visitor(pair, dim)
    return make_all_pairs_visitor(pair)
