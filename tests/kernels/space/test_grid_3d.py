"""In 3D the uniform grid finds exactly the brute-force neighbour sets, with the edge cases
of 2D: ties at r, the seams and corners of the cube, every agent in one cell, a swarm
spread over 10^6 radii, tiny boxes; the build is deterministic in both scatters."""

from functools import cache

import numpy as np
import pytest
import taichi as ti
from scipy.sparse.csgraph import connected_components

from flocklab.kernels.space.graph import MetricGraph
from flocklab.kernels.space.grid import Grid, make_visitor, permute_rows, row, within
from flocklab.kernels.space.state import SortedState
from tests.kernels.space.test_grid import MAX_DEG, policy
from tests.reference import adjacency

nd = ti.types.ndarray()


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

    visit = make_visitor(pair, dim=3)

    @ti.kernel
    def lister(pos: nd, out: nd, deg: nd, r2: nd, start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            deg[i] = visit(i, row(pos, i, 3), 0, pos, ti.static((start, cid, gf, gi)),
                           ti.static((out, r2)), periodic)

    return lister


def grid_adjacency(pos, r, L, inclusive, serial=True) -> np.ndarray:
    """Adjacency found through the 3D grid, in the original agent order."""
    n = len(pos)
    grid = Grid(n, r, L, policy(serial), dim=3)
    p = ti.ndarray(ti.f64, shape=(n, 3))
    p.from_numpy(pos)
    grid.build(p)
    ps = ti.ndarray(ti.f64, shape=(n, 3))
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
        a[slot_to_agent[slot], slot_to_agent[out[slot, : deg[slot]]]] = True
    return a


def assert_same(pos, r, L, inclusive, serial=True):
    want = adjacency(pos, r, L, inclusive)
    got = grid_adjacency(pos, r, L, inclusive, serial)
    missing = np.argwhere(want & ~got)
    extra = np.argwhere(got & ~want)
    assert not len(missing) and not len(extra), f"missing {missing[:5]}, extra {extra[:5]}"
    return want


@pytest.mark.parametrize("inclusive", [True, False])
@pytest.mark.parametrize("L", [None, 6.0, 4.3])
# The box (4.3, both inclusives) and the plane stay fast.
@pytest.mark.slow_cases("None-True", "6.0-True", "6.0-False")
def test_random_configurations(taichi_cpu, inclusive, L):
    rng = np.random.default_rng(3)
    pos = rng.uniform(0, L or 6.0, size=(500, 3))
    a = assert_same(pos, 1.0, L, inclusive)
    assert a.sum() > 500


@pytest.mark.parametrize("L", [None, 8.0])
def test_pairs_exactly_at_the_radius(taichi_cpu, L):
    # Dyadic coordinates: every distance below is exact in binary floating point.
    pos = np.array([[2.0, 2.0, 2.0], [3.0, 2.0, 2.0], [2.0, 2.0, 3.0], [2.0, 2.5, 2.0],
                    [2.0, 2.0, 1.0], [5.0, 5.0, 5.0]])
    inc = assert_same(pos, 1.0, L, True)
    exc = assert_same(pos, 1.0, L, False)
    assert inc[0, 1] and inc[0, 2] and inc[0, 4]  # at exactly r: in with <=
    assert not exc[0, 1] and not exc[0, 2] and not exc[0, 4]  # ... and out with <
    assert exc[0, 3]


def test_cube_seams_and_corners(taichi_cpu):
    L = 8.0
    pos = np.array([
        [0.25, 4.0, 4.0], [7.25, 4.0, 4.0],  # exactly r apart across the x seam
        [4.0, 4.0, 0.0], [4.0, 4.0, 7.5],  # 0.5 apart across the z seam
        [0.0, 0.0, 0.0], [7.75, 7.75, 7.75],  # across the corner of the cube
        [0.5, 0.5, 0.5], [7.5, 7.5, 7.5],  # sqrt(3) apart through the corner: not
        [4.0, 0.125, 7.875], [4.0, 7.875, 0.125],  # across the y-z edge
    ])
    a = assert_same(pos, 1.0, L, True)
    assert a[0, 1] and a[2, 3] and a[4, 5] and not a[6, 7] and a[8, 9]
    assert not assert_same(pos, 1.0, L, False)[0, 1]
    assert_same(pos, 1.0, L, True, serial=False)


@pytest.mark.parametrize("L", [None, 20.0])
def test_every_agent_in_one_cell(taichi_cpu, L):
    rng = np.random.default_rng(4)
    pos = rng.uniform(5.0, 5.4, size=(200, 3))
    a = assert_same(pos, 1.0, L, True)
    assert a.sum() == 200 * 199  # complete graph


def test_swarm_spread_over_a_huge_volume(taichi_cpu):
    # Clusters 10^6 radii apart: a bounding-box grid would need 10^18 cells.
    rng = np.random.default_rng(5)
    centres = rng.uniform(-5e5, 5e5, size=(20, 3))
    pos = (centres[:, None, :] + rng.normal(0, 0.6, size=(20, 15, 3))).reshape(-1, 3)
    a = assert_same(pos, 1.0, None, False)
    assert a.sum() > 0
    assert Grid(len(pos), 1.0, None, policy(), dim=3).n_buckets <= 4 * len(pos) + 16


@pytest.mark.parametrize("L,r", [(2.0, 1.0), (2.5, 1.0), (3.0, 1.0), (3.5, 1.2)])
def test_tiny_periodic_boxes(taichi_cpu, L, r):
    # One, two or three cells across: no cell may be visited twice.
    rng = np.random.default_rng(6)
    pos = rng.uniform(0, L, size=(60, 3))
    assert_same(pos, r, L, True)
    assert_same(pos, r, L, False)


def test_sparse_box_caps_cells(taichi_cpu):
    rng = np.random.default_rng(7)
    pos = rng.uniform(0, 1e3, size=(50, 3))
    pos[1] = pos[0] + [0.0, 0.0, 0.6]
    assert assert_same(pos, 1.0, 1e3, True)[0, 1]
    assert Grid(50, 1.0, 1e3, policy(), dim=3).n_buckets <= 4 * 50 + 16


def test_build_is_deterministic(taichi_cpu):
    rng = np.random.default_rng(8)
    pos = rng.uniform(0, 12, size=(5000, 3))
    for L in (12.0, None):
        perms = []
        for serial in (True, True, False):
            grid = Grid(len(pos), 1.0, L, policy(serial), dim=3)
            p = ti.ndarray(ti.f64, shape=pos.shape)
            p.from_numpy(pos)
            grid.build(p)
            perms.append(grid.perm.to_numpy())
        assert (perms[0] == perms[1]).all() and (perms[1] == perms[2]).all()
        assert sorted(perms[0]) == list(range(len(pos)))


@pytest.mark.parametrize("inclusive", [True, False])
@pytest.mark.parametrize("L", [None, 6.0, 2.5])
# A small box and the plane (both inclusives) stay fast.
@pytest.mark.slow_cases("6.0-True", "6.0-False")
def test_half_stencil_graph_matches_brute_force(taichi_cpu, inclusive, L):
    """Degrees and component count from the half-stencil union-find pass, in 3D."""
    rng = np.random.default_rng(10)
    r = 0.7
    pos = rng.uniform(0, L or 6.0, size=(200, 3))
    pos[:3] = [[1.0, 1.0, 1.0], [1.0, 1.0, 1.5], [1.5, 1.0, 1.0]]  # pairs exactly at 0.5
    want = adjacency(pos, r, L, inclusive)
    grid = Grid(len(pos), r, L, policy(), dim=3)
    st = SortedState({"pos": pos})
    grid.build(st["pos"])
    st.resort(grid)
    graph = MetricGraph(len(pos), r, inclusive, L is not None, dim=3)
    obs = graph.observe(grid, st["pos"], st.ids)
    deg = np.empty(len(pos), dtype=np.int64)
    deg[st.ids_numpy()] = graph.deg.to_numpy()
    assert (deg == want.sum(axis=1)).all()
    n_comp = connected_components(want, directed=False)[0]
    assert obs["components"] == n_comp
    if L is None or L > 5:
        assert 1 < n_comp < len(pos)
