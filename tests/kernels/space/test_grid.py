"""The uniform grid finds exactly the brute-force neighbour sets, edge cases included."""

from functools import cache

import numpy as np
import pytest
import taichi as ti

from flocklab.kernels.runtime import DevicePolicy
from flocklab.kernels.space.grid import Grid, make_visitor, permute_rows, within
from tests.reference import adjacency

nd = ti.types.ndarray()
MAX_DEG = 320


@cache
def _lister(inclusive: bool, periodic: bool):
    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        out, r2 = ti.static(S[0], S[1])
        if k != i and within(d.dot(d), r2[0], inclusive):
            if acc < MAX_DEG:
                out[i, acc] = k
            acc += 1
        return acc

    visit = make_visitor(pair)

    @ti.kernel
    def lister(pos: nd, out: nd, deg: nd, r2: nd, start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi = ti.math.vec2(pos[i, 0], pos[i, 1])
            deg[i] = visit(i, xi, 0, pos, ti.static((start, cid, gf, gi)),
                           ti.static((out, r2)), periodic)

    return lister


def policy(serial: bool = True) -> DevicePolicy:
    """The CPU's grid policy, or (serial=False) a GPU's parallel scatter, built on the CPU."""
    return DevicePolicy(serial_scatter=serial, dense_grid=True)


def grid_adjacency(pos: np.ndarray, r: float, L: float | None, inclusive: bool,
                   serial: bool = True) -> np.ndarray:
    """Adjacency found through the grid, in the original agent order."""
    n = len(pos)
    grid = Grid(n, r, L, policy(serial))
    p = ti.ndarray(ti.f64, shape=(n, 2))
    p.from_numpy(pos)
    grid.build(p)
    ps = ti.ndarray(ti.f64, shape=(n, 2))
    permute_rows(p, ps, grid.perm)
    out = ti.ndarray(ti.i32, shape=(n, MAX_DEG))
    deg = ti.ndarray(ti.i32, shape=n)
    r2 = ti.ndarray(ti.f64, shape=1)
    r2.from_numpy(np.array([r * r]))
    _lister(inclusive, L is not None)(ps, out, deg, r2, *grid.view())
    perm, out, deg = grid.perm.to_numpy(), out.to_numpy(), deg.to_numpy()
    assert deg.max() <= MAX_DEG
    slot_to_agent = np.empty(n, dtype=np.int64)
    slot_to_agent[perm] = np.arange(n)
    a = np.zeros((n, n), dtype=bool)
    for slot in range(n):
        i = slot_to_agent[slot]
        a[i, slot_to_agent[out[slot, : deg[slot]]]] = True
    return a


def assert_same(pos, r, L, inclusive):
    want = adjacency(pos, r, L, inclusive)
    got = grid_adjacency(pos, r, L, inclusive)
    missing = np.argwhere(want & ~got)
    extra = np.argwhere(got & ~want)
    assert not len(missing) and not len(extra), f"missing {missing[:5]}, extra {extra[:5]}"
    return want


@pytest.mark.parametrize("inclusive", [True, False])
@pytest.mark.parametrize("L", [None, 10.0, 7.3])
# The box (7.3, both inclusives) and the plane stay fast.
@pytest.mark.slow_cases("None-True", "10.0-True", "10.0-False")
def test_random_configurations(taichi_cpu, inclusive, L):
    rng = np.random.default_rng(3)
    pos = rng.uniform(0, L or 10.0, size=(400, 2))
    a = assert_same(pos, 1.0, L, inclusive)
    assert a.sum() > 400  # the configuration has plenty of pairs to get wrong


@pytest.mark.parametrize("L", [None, 8.0])
def test_pairs_exactly_at_the_radius(taichi_cpu, L):
    # Dyadic coordinates: every distance below is exact in binary floating point.
    pos = np.array([[2.0, 2.0], [3.0, 2.0], [2.0, 3.0], [2.5, 2.0], [4.0, 2.0], [5.0, 5.0]])
    inc = assert_same(pos, 1.0, L, True)
    exc = assert_same(pos, 1.0, L, False)
    assert inc[0, 1] and inc[0, 2] and inc[1, 4]  # at exactly r: in with <=
    assert not exc[0, 1] and not exc[0, 2] and not exc[1, 4]  # ... and out with <
    assert exc[0, 3]


def test_periodic_seam_and_corners(taichi_cpu):
    L = 8.0
    pos = np.array([
        [0.25, 4.0], [7.25, 4.0],  # exactly r apart across the x seam
        [4.0, 0.0], [4.0, 7.5],  # 0.5 apart across the y seam
        [0.0, 0.0], [7.75, 7.75],  # across the corner
        [0.5, 0.5], [7.0, 7.0],  # 2.12 apart through the corner: not neighbours
    ])
    a = assert_same(pos, 1.0, L, True)
    assert a[0, 1] and a[2, 3] and a[4, 5] and not a[6, 7]
    assert not assert_same(pos, 1.0, L, False)[0, 1]


@pytest.mark.parametrize("L", [None, 20.0])
def test_every_agent_in_one_cell(taichi_cpu, L):
    rng = np.random.default_rng(4)
    pos = rng.uniform(5.0, 5.4, size=(300, 2))
    a = assert_same(pos, 1.0, L, True)
    assert a.sum() == 300 * 299  # complete graph


def test_swarm_spread_over_a_huge_area(taichi_cpu):
    # Clusters 10^6 radii apart on the plane: a bounding-box grid would need 10^12 cells.
    rng = np.random.default_rng(5)
    centres = rng.uniform(-5e5, 5e5, size=(20, 2))
    pos = (centres[:, None, :] + rng.normal(0, 0.7, size=(20, 15, 2))).reshape(-1, 2)
    a = assert_same(pos, 1.0, None, False)
    assert a.sum() > 0
    grid = Grid(len(pos), 1.0, None, policy())
    assert grid.n_buckets <= 4 * len(pos) + 16  # memory follows N, not the area


@pytest.mark.parametrize("L,r", [(2.0, 1.0), (2.5, 1.0), (3.0, 1.0), (3.5, 1.2)])
def test_tiny_periodic_boxes(taichi_cpu, L, r):
    # One, two or three cells across: no cell may be visited twice.
    rng = np.random.default_rng(6)
    pos = rng.uniform(0, L, size=(60, 2))
    assert_same(pos, r, L, True)
    assert_same(pos, r, L, False)


def test_sparse_box_caps_cells(taichi_cpu):
    rng = np.random.default_rng(7)
    pos = rng.uniform(0, 1e4, size=(50, 2))
    pos[1] = pos[0] + [0.6, 0.0]
    a = assert_same(pos, 1.0, 1e4, True)
    assert a[0, 1]
    assert Grid(50, 1.0, 1e4, policy()).n_buckets <= 4 * 50 + 16


@pytest.mark.parametrize("L", [None, 12.0])
def test_parallel_scatter_finds_the_same_neighbours(taichi_cpu, L):
    # The GPU path (atomic slots + per-bucket sort), exercised on the CPU.
    rng = np.random.default_rng(9)
    pos = rng.uniform(0, 12, size=(500, 2))
    want = adjacency(pos, 1.0, L, True)
    assert (grid_adjacency(pos, 1.0, L, True, serial=False) == want).all()


def test_build_is_deterministic(taichi_cpu):
    rng = np.random.default_rng(8)
    pos = rng.uniform(0, 30, size=(5000, 2))
    perms = []
    for serial in (True, True, False):
        grid = Grid(len(pos), 1.0, 30.0, policy(serial))
        p = ti.ndarray(ti.f64, shape=pos.shape)
        p.from_numpy(pos)
        grid.build(p)
        perms.append(grid.perm.to_numpy())
    # Stable in both variants: the same permutation every time, serial or parallel.
    assert (perms[0] == perms[1]).all() and (perms[1] == perms[2]).all()
    assert sorted(perms[0]) == list(range(len(pos)))


@pytest.mark.parametrize("inclusive", [True, False])
@pytest.mark.parametrize("L", [None, 8.0, 2.5, 3.0])
# Small boxes (both inclusives) and the plane stay fast.
@pytest.mark.slow_cases("None-True", "8.0-True", "8.0-False")
def test_half_stencil_graph_matches_brute_force(taichi_cpu, inclusive, L):
    """Degrees and component count from the half-stencil union-find pass."""
    from scipy.sparse.csgraph import connected_components

    from flocklab.kernels.space.graph import MetricGraph
    from flocklab.kernels.space.state import SortedState

    rng = np.random.default_rng(10)
    r = 0.5
    pos = rng.uniform(0, L or 8.0, size=(150, 2))
    pos[:4] = [[1.0, 1.0], [1.5, 1.0], [1.0, 1.5], [1.0, 1.25]]  # pairs exactly at r
    want = adjacency(pos, r, L, inclusive)
    grid = Grid(len(pos), r, L, policy())
    st = SortedState({"pos": pos})
    grid.build(st["pos"])
    st.resort(grid)
    graph = MetricGraph(len(pos), r, inclusive, L is not None)
    obs = graph.observe(grid, st["pos"], st.ids)
    deg = np.empty(len(pos), dtype=np.int64)
    deg[st.ids_numpy()] = graph.deg.to_numpy()
    assert (deg == want.sum(axis=1)).all()
    n_comp = connected_components(want, directed=False)[0]
    assert obs["components"] == n_comp
    if L is None or L > 5:
        assert 1 < n_comp < len(pos)  # a graph with something to get wrong
