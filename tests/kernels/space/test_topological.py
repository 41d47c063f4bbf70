"""Topological neighbours (Ballerini et al. 2008): the k-NN search on the grid
(kernels/space/knn.py) and the Vicsek family's step over it, against brute-force numpy
references that sort all N - 1 distances (tests/reference.py)."""

import numpy as np
import pytest
from pydantic import ValidationError

from flocklab import kernels
from flocklab.kernels.space import rng
from flocklab.schemas import Scenario, describe_models
from flocklab.schemas.presets import PRESETS
from flocklab.schemas.problems import field_errors
from tests.reference import (
    knn_adjacency,
    knn_lists,
    vicsek_step,
    vicsek_step_3d,
    vicsek_step_vectorial,
)

pytestmark = pytest.mark.usefixtures("taichi_cpu")


def search(pos, k, L=None, radius=None, inclusive=True, symmetric=False, backend="cpu"):
    """The engine's k nearest of every agent, as agent-id lists (nearest first)."""
    from flocklab.kernels.runtime import DevicePolicy
    from flocklab.kernels.space.knn import TopologicalNeighbours
    from flocklab.kernels.space.state import SortedState

    n, dim = pos.shape
    t = TopologicalNeighbours(n, k, radius, inclusive, symmetric, L,
                              DevicePolicy.for_backend(backend), dim)
    st = SortedState({"pos": pos}, vectors=("pos",))
    st.sort(t.grid, 0)
    t.search(st["pos"], st.ids)
    return t.lists(st.ids_numpy())


def check(pos, k, L=None, radius=None, inclusive=True):
    """Directed lists equal the reference's, order included; symmetric: the same sets as
    the reference's undirected graph."""
    assert search(pos, k, L, radius, inclusive) == knn_lists(pos, k, L, radius, inclusive)
    a = knn_adjacency(pos, k, L, radius, inclusive, symmetric=True)
    got = search(pos, k, L, radius, inclusive, symmetric=True)
    assert [sorted(js) for js in got] == [list(np.flatnonzero(row)) for row in a]


def lattice(m, dim, spacing=1.0):
    axes = np.meshgrid(*[np.arange(m) * spacing] * dim, indexing="ij")
    return np.stack(axes, -1).reshape(-1, dim)


R = np.random.default_rng(25)
LAYOUTS = {
    # agents within 0.3 of the box's faces: every neighbourhood crosses a seam
    "seams": lambda dim: np.mod(R.uniform(-0.3, 0.3, (300, dim)), 10.0),
    "uniform": lambda dim: R.uniform(0, 10.0, (500, dim)),
    # every agent in one cell
    "one-cell": lambda dim: 5.0 + R.uniform(0, 1e-3, (200, dim)),
    # a few tight clusters far apart: the k-th nearest many rings out
    "clusters": lambda dim: (R.integers(0, 4, (120, 1)) * 2.4
                             + R.uniform(0, 0.01, (120, dim))),
}


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("L", [10.0, None], ids=["box", "plane"])
@pytest.mark.parametrize("layout", sorted(LAYOUTS))
@pytest.mark.parametrize("k", [1, 7])
def test_search_matches_sorting_all_pairs(dim, L, layout, k):
    check(LAYOUTS[layout](dim), k, L)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("L", [6.0, None], ids=["box", "plane"])
@pytest.mark.parametrize("k", [1, 4, 5, 6, 7, 12, 26])
def test_exact_ties_go_to_the_smaller_id(dim, L, k):
    # The lattice puts 4 (2D) or 6 (3D) agents at distance 1 of each, then 4 or 12 at
    # sqrt 2, ...: k cuts through those shells, and the box's seams join its faces.
    check(lattice(6 if dim == 2 else 4, dim, 1.0), k, L if dim == 2 else L and 4.0)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("L", [10.0, None], ids=["box", "plane"])
@pytest.mark.parametrize("n", [1, 2, 3, 7, 8])
def test_n_at_most_k_gives_every_other_agent(dim, L, n):
    pos = R.uniform(0, 10, (n, dim))
    got = search(pos, 7, L)
    assert [sorted(js) for js in got] == [[j for j in range(n) if j != i] for i in range(n)]
    check(pos, 7, L)


@pytest.mark.parametrize("dim", [2, 3])
def test_huge_spread(dim):
    # Sparse: 60 agents over 10^6 in the plane (rings far out) and in a box of side 10^5.
    pos = R.uniform(0, 1e6, (60, dim))
    pos[:10] = 3.0 + R.uniform(0, 1e-6, (10, dim))  # and a cluster inside it
    check(pos, 7, None)
    check(np.mod(pos, 1e5), 7, 1e5)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("L", [10.0, None], ids=["box", "plane"])
@pytest.mark.parametrize("inclusive", [True, False])
def test_radius_caps_the_search(dim, L, inclusive):
    pos = R.uniform(0, 10, (400, dim))
    check(pos, 7, L, radius=0.8, inclusive=inclusive)
    # On the lattice, the cap at exactly the spacing: <= keeps the shell at 1, < drops it.
    g = lattice(5, dim, 1.0)
    check(g, 7, L and 5.0, radius=1.0, inclusive=inclusive)
    assert all(len(js) == (2 * dim if inclusive else 0) for js in search(g, 7, 5.0, 1.0,
                                                                          inclusive))


def test_gpu_style_build_gives_the_same_lists():
    """The grid's parallel scatter and blocked scan (a GPU's) give the same neighbours."""
    pos = R.uniform(0, 10, (500, 2))
    assert search(pos, 7, 10.0, symmetric=True, backend="cuda") == search(
        pos, 7, 10.0, symmetric=True)


# --- the Vicsek family's step -----------------------------------------------------------


def scenario(rule="vicsek", N=150, L=8.0, k=7, dim=2, eta=0.0, steps=6, radius=None,
             symmetric=False, every=1, seed=5, density_region=None, **model):
    space = {"kind": "periodic", "L": L, "dimension": dim} if L else {
        "kind": "plane", "dimension": dim}
    init = {"kind": "random", "N": N}
    if density_region is not None or not L:
        init["region"] = density_region or {"kind": "box", "low": [0] * dim,
                                            "high": [4] * dim}
    nb = {"kind": "topological", "k": k, "symmetric": symmetric}
    if radius is not None:
        nb["radius"] = radius
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": rule, "v0": 0.1, "eta": eta, **model},
        "space": space, "neighbours": nb, "initial": init,
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"every": every, "arrays": ["position", "heading", "degree"]},
        "seed": seed,
    })


class Frames:
    def __init__(self):
        self.pos, self.heading, self.degree = [], [], []

    def frame(self, step, time, arrays):
        self.pos.append(arrays["position"])
        self.heading.append(arrays["heading"])
        self.degree.append(arrays["degree"])


def run(sc, **kw):
    sink = Frames()
    result = kernels.run(sc, sink=sink, **kw)
    assert result.status == "completed", result.error
    return result, sink


def wrapped(d, period):
    return d - period * np.round(d / period) if period else d


STEP_CASES = [
    dict(eta=0.8),
    dict(eta=0.8, L=None),
    dict(eta=0.5, symmetric=True),
    dict(eta=0.5, radius=0.7, k=5),
    dict(eta=0.3, N=6, k=7),  # N <= k: all-to-all
    dict(rule="average", eta=0.2),
    dict(rule="laplacian", g=200.0, symmetric=True),
    dict(rule="leader", leader_heading=0.4, L=None),
    dict(dim=3, eta=0.9),
    dict(dim=3, eta=0.9, L=None, symmetric=True, radius=1.5),
    dict(eta=0.8, noise="vectorial"),
    dict(eta=0.6, noise="vectorial", symmetric=True, L=None),
    dict(dim=3, eta=0.9, noise="vectorial", radius=1.5),
]


@pytest.mark.parametrize("case", STEP_CASES,
                         ids=lambda c: "-".join(f"{k}={v}" for k, v in c.items()))
def test_step_matches_the_reference_step(case):
    """Each step from the engine's state at t against numpy's step on the same state over
    the brute-force k-NN graph, and the recorded degrees against that graph's."""
    sc = scenario(**case)
    result, sink = run(sc)
    assert result.extra["engine_path"] == "per_step"
    p, nb = sc.model, sc.neighbours
    L = sc.space.L if sc.space.kind == "periodic" else None
    ids = np.arange(sc.n_agents)
    for step in range(sc.time.steps):
        pos, head = sink.pos[step], sink.heading[step]
        a = knn_adjacency(pos, nb.k, L, nb.radius, sc.inclusive, nb.symmetric)
        assert (sink.degree[step] == a.sum(axis=1)).all(), step
        u1 = rng.uniform_np(rng.step_key(sc.seed, 0, step), ids)
        if p.noise == "vectorial":
            u2 = rng.uniform_np(rng.step_key(sc.seed, 1, step), ids)
            e = (head if sc.dimension == 3
                 else np.stack([np.cos(head), np.sin(head)], axis=1))
            x, e = vicsek_step_vectorial(pos, e, r=1.0, L=L, inclusive=True, v0dt=p.v0,
                                         eta=p.eta, u1=u1, u2=u2, graph=a,
                                         move_new=p.position_update == "new_heading")
            h = e if sc.dimension == 3 else np.arctan2(e[:, 1], e[:, 0])
        elif sc.dimension == 3:
            u2 = rng.uniform_np(rng.step_key(sc.seed, 1, step), ids)
            x, h = vicsek_step_3d(pos, head, r=1.0, L=L, inclusive=True, v0dt=p.v0,
                                  eta=p.eta, u1=u1, u2=u2, graph=a)
        else:
            x, h = vicsek_step(pos, head, rule=p.rule, r=1.0, L=L, inclusive=True,
                               v0dt=p.v0, eta=p.eta, g=p.g, theta0=p.leader_heading,
                               noise=u1, graph=a)
        assert np.abs(wrapped(sink.pos[step + 1] - x, L)).max() < 1e-9, step
        period = 2 * np.pi if p.rule == "vicsek" and sc.dimension == 2 else None
        assert np.abs(wrapped(sink.heading[step + 1] - h, period)).max() < 1e-9, step


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("side", [0.5, 8.0, 400.0])  # 1200 agents: densities 10^4 to 10^-2
def test_degree_is_exactly_k_at_every_density(dim, side):
    sc = scenario(N=1200, L=None, dim=dim, eta=0.5, steps=3, every=3,
                  density_region={"kind": "box", "low": [0] * dim, "high": [side] * dim})
    result, sink = run(sc)
    for name in ("degree_min", "degree_max", "degree_mean"):
        assert (result.observables[name] == 7).all(), name
    assert all((d == 7).all() for d in sink.degree)
    assert result.final["isolated"] == 0


def test_no_noise_and_k_at_least_n_aligns_in_one_step():
    sc = scenario(N=40, k=39, eta=0.0, steps=1, every=0)
    result = kernels.run(sc)
    assert result.observables["polarization"][0] < 0.5
    assert result.final["polarization"] == pytest.approx(1.0, abs=1e-12)


@pytest.mark.slow
@pytest.mark.resets_taichi  # Taichi restarts per thread count
def test_same_seed_same_bits_whatever_the_threads():
    base = scenario(N=3000, L=30.0, eta=1.0, steps=8, symmetric=True)
    one = run(base.model_copy(update={"threads": 1}))[1]
    two = run(base.model_copy(update={"threads": 2}))[1]
    assert all((x == y).all() for x, y in zip(one.pos, two.pos, strict=True))
    assert all((x == y).all() for x, y in zip(one.heading, two.heading, strict=True))


def test_components_and_linked_intervals_of_the_knn_graph():
    from scipy.sparse.csgraph import connected_components

    # Two far clusters of 20 on the plane, k = 3: never joined.
    sc = scenario(rule="average", N=40, L=None, k=3, steps=4, every=1,
                  density_region={"kind": "box", "low": [0, 0], "high": [1, 1]})
    sc = Scenario.model_validate({**sc.model_dump(mode="json"), "initial": {
        "kind": "explicit",
        "positions": [[float(i % 5), float(i // 5 % 4) + 100.0 * (i >= 20)]
                      for i in range(40)],
        "headings": [0.1 * i for i in range(40)]}})
    result, sink = run(sc)
    a = knn_adjacency(sink.pos[0], 3, None)
    assert result.observables["components"][0] == connected_components(a, directed=True,
                                                                        connection="weak")[0]
    assert result.extra["linked_intervals"]["count"] == 0  # never connected


# --- the schema and the schedules ------------------------------------------------------


BASE = {"model": {"kind": "vicsek"}, "initial": {"kind": "random", "N": 10},
        "time": {"steps": 1}}


def errors(neighbours):
    with pytest.raises(ValidationError) as exc:
        Scenario.model_validate({**BASE, "neighbours": neighbours})
    return {e.loc: e.msg for e in field_errors(exc.value)}


def test_metric_is_the_default_kind():
    sc = Scenario.model_validate({**BASE, "neighbours": {"radius": 1.0}})
    assert sc.neighbours.kind == "metric" and not sc.neighbours.topological


@pytest.mark.parametrize("nb,loc,words", [
    ({"kind": "topological"}, "neighbours", "neighbours.k is required"),
    ({"kind": "topological", "k": 0}, "neighbours.k", "greater than or equal to 1"),
    ({"kind": "topological", "k": 2.0}, "neighbours.k", "valid integer"),
    ({"kind": "topological", "k": True}, "neighbours.k", "valid integer"),
    ({"kind": "metric"}, "neighbours", "neighbours.radius is required"),
    ({"radius": 1.0, "k": 3}, "neighbours", "neighbours.k and neighbours.symmetric"),
    ({"kind": "knn", "k": 3}, "neighbours.kind", "'metric' or 'topological'"),
    ({"kind": "topological", "k": 3, "radius": -1.0}, "neighbours.radius", "greater than"),
])
def test_bad_neighbours_name_the_field(nb, loc, words):
    errs = errors(nb)
    assert loc in errs and words in errs[loc], errs


@pytest.mark.parametrize("preset,kind", [("tanner-obstacles", "flocking_obstacles"),
                                         ("xi-abed-sim1", "formation")])
def test_other_models_refuse_topological(preset, kind):
    doc = PRESETS[preset].build()
    with pytest.raises(ValidationError) as exc:
        Scenario.model_validate({**doc, "neighbours": {"kind": "topological", "k": 7}})
    errs = {e.loc: e.msg for e in field_errors(exc.value)}
    assert "neighbours.kind" in errs, errs
    assert f"model {kind} takes metric neighbours only" in errs["neighbours.kind"]
    cards = {m["kind"]: m for m in describe_models()}
    assert cards[kind]["neighbour_kinds"] == ["metric"]
    for topological in ("vicsek", "flocking"):
        assert cards[topological]["neighbour_kinds"] == ["metric", "topological"]


def test_fused_and_batched_refuse_and_auto_takes_per_step():
    sc = scenario(N=50, steps=2, every=0)
    for path in ("fused", "batched"):
        with pytest.raises(kernels.PathUnavailable, match="topological neighbours"):
            kernels.run(sc, path=path)
    assert kernels.run(sc).extra["engine_path"] == "per_step"
