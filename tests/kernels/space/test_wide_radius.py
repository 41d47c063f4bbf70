"""A periodic radius beyond L/3 and L/2, up to the half-diagonal and past it: every pair
interacts once, through its minimum image. The grid, the Vicsek family on both engine
paths (2D) and in 3D, against brute-force minimum-image references."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from flocklab import kernels
from flocklab.kernels.space import rng
from flocklab.kernels.space.graph import MetricGraph, count_roots, reset_parent
from flocklab.kernels.space.grid import Grid
from flocklab.kernels.space.state import SortedState
from flocklab.schemas import Scenario
from tests.kernels.space import test_grid, test_grid_3d
from tests.kernels.vicsek.test_vicsek import Frames, wrapped_diff
from tests.reference import adjacency, vicsek_step, vicsek_step_3d

L = 4.0
# Radii as fractions of L: just past L/3 (fewer than 3 cells across), L/2, beyond it, and
# just below the half-diagonal L sqrt(dim) / 2.
FRACTIONS = {2: [1 / 3 * 1.001, 0.5, 0.6, 0.7, math.sqrt(2) / 2 * (1 - 1e-6)],
             3: [1 / 3 * 1.001, 0.5, 0.6, 0.7, 0.8, math.sqrt(3) / 2 * (1 - 1e-6)]}
CASES = [(dim, f) for dim in (2, 3) for f in FRACTIONS[dim]]


def case_id(case) -> str:
    return f"{case[0]}d-r={case[1]:.4f}L"


def vicsek(dim: int, r: float, N=60, eta=0.8, steps=6, rule="vicsek", **model) -> Scenario:
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": rule, "v0": 0.15, "eta": eta, **model},
        "space": {"kind": "periodic", "L": L, "dimension": dim},
        "neighbours": {"radius": r},
        "initial": {"kind": "random", "N": N},
        "time": {"steps": steps},
        "recording": {"every": 1, "arrays": ["position", "heading"], "observables_every": 1},
        "seed": 21,
    })


def test_the_schema_takes_any_periodic_radius():
    for dim, half_diagonal in ((2, L * math.sqrt(2) / 2), (3, L * math.sqrt(3) / 2)):
        for r in (0.51 * L, half_diagonal, 5 * L):
            assert vicsek(dim, r).neighbours.radius == r


@pytest.mark.parametrize("inclusive", [True, False])
@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_grid_visits_each_pair_once_at_its_minimum_image(taichi_cpu, case, inclusive):
    dim, frac = case
    pos = np.random.default_rng(5).uniform(0, L, size=(200, dim))
    helper = test_grid if dim == 2 else test_grid_3d
    want = helper.assert_same(pos, frac * L, L, inclusive)  # exactly the brute-force sets
    assert want.sum() > 0
    if frac <= 0.6:
        assert want.sum() < 200 * 199  # and some out (near the half-diagonal: none left)


@pytest.mark.parametrize("dim", [2, 3])
def test_grid_beyond_the_half_diagonal_has_every_pair(taichi_cpu, dim):
    pos = np.random.default_rng(6).uniform(0, L, size=(150, dim))
    helper = test_grid if dim == 2 else test_grid_3d
    want = helper.assert_same(pos, L * math.sqrt(dim) / 2 * 1.001, L, False)
    assert want.sum() == 150 * 149


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_the_half_visit_graph_counts_each_edge_once(taichi_cpu, case):
    """MetricGraph's symmetric half visit (degrees, components, and the by-id forest of
    Theorem 2's tracking) at the same radii: every unordered pair once."""
    dim, frac = case
    r = frac * L
    pos = np.random.default_rng(7).uniform(0, L, size=(40, dim))
    want = adjacency(pos, r, L, True)
    grid = Grid(len(pos), r, L, test_grid.policy(), dim=dim)
    st = SortedState({"pos": pos})
    grid.build(st["pos"])
    st.resort(grid)
    graph = MetricGraph(len(pos), r, True, True, dim=dim)
    obs = graph.observe(grid, st["pos"], st.ids)
    deg = np.empty(len(pos), dtype=np.int64)
    deg[st.ids_numpy()] = graph.deg.to_numpy()
    np.testing.assert_array_equal(deg, want.sum(axis=1))
    assert obs["components"] == connected_components(want, directed=False)[0]
    by_id = graph.parent  # a forest indexed by agent id, as the linked-interval tracking's
    reset_parent(by_id)
    graph.union_edges(grid, st["pos"], st.ids, parent=by_id)
    assert count_roots(by_id) == obs["components"]


def check_graph_observables(result, frames, r: float, inclusive: bool) -> None:
    """degree_* and components of every observed state against the brute-force graph."""
    for row, pos in enumerate(frames):
        a = adjacency(pos, r, L, inclusive)
        deg = a.sum(axis=1)
        obs = {k: v[row] for k, v in result.observables.items()}
        assert (obs["degree_min"], obs["degree_max"]) == (deg.min(), deg.max()), row
        assert obs["degree_mean"] == pytest.approx(deg.mean(), rel=1e-13)
        assert obs["components"] == connected_components(a, directed=False)[0], row


@pytest.mark.parametrize("rule", ["vicsek", "average"])
@pytest.mark.parametrize("frac", FRACTIONS[2], ids=lambda f: f"r={f:.4f}L")
# Every radius once in the fast lane, each rule on each schedule; --all runs the grid.
@pytest.mark.fast_cases("fused-r=0.3337L-vicsek", "per_step-r=0.5000L-average",
                        "fused-r=0.6000L-average", "per_step-r=0.7000L-vicsek",
                        "fused-r=0.7071L-vicsek")
def test_vicsek_2d_matches_the_minimum_image_reference(path, frac, rule):
    r = frac * L
    sc = vicsek(2, r, rule=rule, eta=0.8 if rule == "vicsek" else 0.3)
    sink = Frames()
    result = kernels.run(sc, sink=sink)
    assert result.status == "completed" and result.extra["engine_path"] == path
    pos, theta = sink.pos[0].copy(), sink.theta[0].copy()
    ids = np.arange(sc.n_agents)
    period = 2 * np.pi if rule == "vicsek" else None
    for step in range(sc.time.steps):
        noise = rng.uniform_np(rng.step_key(sc.seed, 0, step), ids)
        pos, theta = vicsek_step(pos, theta, rule=rule, r=r, L=L, inclusive=True,
                                 v0dt=0.15, eta=sc.model.eta, noise=noise)
        assert np.abs(wrapped_diff(sink.pos[step + 1], pos, L)).max() < 1e-9, step
        assert np.abs(wrapped_diff(sink.theta[step + 1], theta, period)).max() < 1e-9, step
    check_graph_observables(result, sink.pos, r, True)


@pytest.mark.parametrize("frac", FRACTIONS[3], ids=lambda f: f"r={f:.4f}L")
def test_vicsek_3d_matches_the_minimum_image_reference(taichi_cpu, frac):
    r = frac * L
    sc = vicsek(3, r)
    sink = Frames()
    result = kernels.run(sc, sink=sink)
    assert result.status == "completed"
    pos, e = sink.pos[0].copy(), sink.theta[0].copy()
    ids = np.arange(sc.n_agents)
    for step in range(sc.time.steps):
        u1 = rng.uniform_np(rng.step_key(sc.seed, 0, step), ids)
        u2 = rng.uniform_np(rng.step_key(sc.seed, 1, step), ids)
        pos, e = vicsek_step_3d(pos, e, r=r, L=L, inclusive=True, v0dt=0.15,
                                eta=sc.model.eta, u1=u1, u2=u2)
        assert np.abs(wrapped_diff(sink.pos[step + 1], pos, L)).max() < 1e-9, step
        assert np.abs(sink.theta[step + 1] - e).max() < 1e-9, step
    check_graph_observables(result, sink.pos, r, True)


@pytest.mark.parametrize("dim,engine_path", [(2, "fused"), (2, "per_step"), (3, "per_step")])
def test_beyond_the_half_diagonal_is_the_mean_field(taichi_cpu, dim, engine_path):
    """r = L: every pair is within r, so without noise all agents align in one step."""
    result = kernels.run(vicsek(dim, L, eta=0.0, steps=3), path=engine_path)
    assert result.extra["engine_path"] == engine_path
    obs = result.observables
    assert (obs["degree_min"] == 59).all() and (obs["components"] == 1).all()
    assert obs["polarization"][0] < 0.5
    assert obs["polarization"][1:] == pytest.approx(1.0, abs=1e-12)
