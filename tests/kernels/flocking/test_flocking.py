"""M2 (paper 000): the paper's properties, the presets, observables against brute force,
fixed-graph generators, and the scenarios the schema must refuse."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import scipy.sparse as sp
from pydantic import ValidationError
from scipy.sparse.csgraph import connected_components

from flocklab import kernels
from flocklab.kernels.models.flocking.topology import build_edges, to_csr
from flocklab.schemas import PRESETS, Scenario
from flocklab.schemas.flocking import GraphSpec
from tests.kernels.flocking.test_flocking_reference import (
    fused_or_skip,
    lattice,
    m2_scenario,
    make_kernel,
    pair_geometry,
)

# Taichi on the CPU for every test (the two-path `path` fixture does not start it).
pytestmark = pytest.mark.usefixtures("taichi_cpu")


def run_states(sc: Scenario, every: int = 1, path: str = "per_step"):
    """Step the kernel, yielding (step, kernel) every `every` steps (and at step 0)."""
    k = make_kernel(sc, path=path)
    yield 0, k
    for step in range(sc.time.steps):
        k.step(step)
        if (step + 1) % every == 0:
            yield step + 1, k


def preset(name: str, **recording) -> Scenario:
    spec = PRESETS[name].build()
    spec["recording"] = {**spec["recording"], **recording}
    return Scenario.model_validate(spec)


# --- paper 000's properties -----------------------------------------------------------------

@pytest.mark.slow_cases("fused-switching-all_pairs-rk4", "fused-switching-grid",
                        "per_step-switching-grid")
@pytest.mark.parametrize("case", [
    dict(topology="fixed"),
    dict(topology="fixed", integrator="rk4", graph={"kind": "path"}),
    dict(topology="switching", search="grid"),
    dict(topology="switching", search="all_pairs", integrator="rk4"),
], ids=lambda c: "-".join(str(v) for v in c.values()))
def test_mean_velocity_is_conserved(path, case):
    """Without obstacles every pair term of eq. 3 is antisymmetric, so sum_i u_i = 0:
    the mean velocity stays put up to rounding (1e-13 over 500 steps)."""
    sc = m2_scenario(n=30, steps=500, speed=1.0, **case)
    fused_or_skip(path, sc)
    means = [k.frame(["velocity"])["velocity"].mean(axis=0)
             for _, k in run_states(sc, 50, path)]
    drift = np.abs(np.array(means) - means[0]).max()
    assert drift < 1e-13, drift
    assert np.abs(means[0]).max() > 1e-3


def energy_series(sc: Scenario, key: str) -> np.ndarray:
    return np.array([k.observe(step)[key] for step, k in run_states(sc)])


@pytest.mark.slow
def test_fixed_energy_never_increases(taichi_cpu):
    """dW/dt = -v^T (L x I) v <= 0 (eq. 8). RK4 at dt = 0.005 has a per-step error of order
    dt^5 ~ 1e-12 times the force scale, so W may not rise by more than 1e-9 in any step
    (measured here: it falls in every step, by at least 6e-5)."""
    sc = m2_scenario("fixed", n=10, steps=2000, dt=0.005, integrator="rk4", speed=1.0)
    w = energy_series(sc, "W")
    assert np.diff(w).max() < 1e-9, np.diff(w).max()
    assert w[0] - w[-1] > 10.0  # it does dissipate (35.6 -> 21.1 here)


@pytest.mark.slow
def test_switching_q_never_increases(taichi_cpu):
    """dQ/dt <= 0 for the saturated potential (eq. 10-12). Q is continuous across a switch
    while u jumps, so a step straddling a switch has a larger error; the bound is the same
    1e-9 (measured here with RK4 at dt = 0.005, 20 switching steps: Q falls in every step,
    by at least 2e-4)."""
    sc = m2_scenario("switching", n=16, steps=1000, dt=0.005, integrator="rk4", R=1.6,
                     speed=1.0, spacing=1.2)
    k = make_kernel(sc)
    q, valency = [], []
    for step in range(sc.time.steps + 1):
        obs = k.observe(step)
        q.append(obs["Q"])
        valency.append([obs[f"valency_{i}"] for i in range(16)])
        if step < sc.time.steps:
            k.step(step)
    q = np.array(q)
    assert np.diff(q).max() < 1e-9, np.diff(q).max()
    assert q[0] - q[-1] > 5.0
    assert np.any(np.diff(np.array(valency), axis=0) != 0)  # the topology did switch


@pytest.mark.slow_cases("fused")
def test_tree_settles_at_potential_minimiser(path):
    """Corollary 1: on a tree every edge length converges to the minimiser d of V."""
    d = 1.3
    sc = m2_scenario("fixed", n=9, steps=6000, dt=0.01, d=d, speed=0.5,
                     graph={"kind": "tree", "seed": 4})
    *_, (_, k) = run_states(sc, sc.time.steps, path)
    u, v = build_edges(sc.model.graph, sc.n_agents, sc.seed)
    x = k.frame(["position"])["position"]
    lengths = np.hypot(*(x[u] - x[v]).T)
    np.testing.assert_allclose(lengths, d, atol=1e-6)


@pytest.mark.slow_cases("fused")
def test_complete_graph_synchronises_faster_than_path(path):
    """Corollary 2: more algebraic connectivity, faster velocity synchronisation. The
    potential terms act as disturbances (the complete graph's distances are frustrated, so
    it keeps a small residue), so the claim is tested on the transient: the complete graph
    (lambda_2 = 10) gets below 1e-2 first and is 10x closer to synchrony at t = 5 s and
    t = 10 s than the path (lambda_2 = 0.098) from the same state."""
    out = {}
    for kind in ("complete", "path"):
        sc = m2_scenario("fixed", n=10, steps=1500, graph={"kind": kind}, speed=1.0)
        series = [(k.observe(s)["velocity_disagreement"], k.observe(s)["lambda2"])
                  for s, k in run_states(sc, 10, path)]
        out[kind] = np.array(series)
    complete, chain = out["complete"], out["path"]
    np.testing.assert_allclose(complete[0, 0], chain[0, 0])  # the same initial state
    assert complete[0, 1] == pytest.approx(10.0)  # lambda_2(K_N) = N
    assert chain[0, 1] == pytest.approx(2 * (1 - np.cos(np.pi / 10)))
    first = {kind: np.argmax(s[:, 0] < 1e-2) for kind, s in out.items()}
    assert 0 < first["complete"] < first["path"]
    for t in (50, 100):  # observations every 0.1 s
        assert complete[t, 0] < 0.1 * chain[t, 0]


@pytest.mark.slow_cases("per_step")  # 10^4 steps; the fused twin stays fast
def test_switching_preset_flocks_without_collisions(path):
    """Paper 000, section 6: velocities synchronised by t = 100 s; no collisions."""
    result = kernels.run(preset("tjp-switching", observables_every=10))
    assert result.status == "completed", result.error
    assert result.extra["engine_path"] == path
    obs = result.observables
    assert obs["time"][-1] == pytest.approx(100.0)
    assert obs["velocity_disagreement"][-1] < 1e-10
    assert obs["heading_spread"][-1] < 1e-5
    assert obs["components"][-1] == 1 and obs["lambda2"][-1] > 0
    assert obs["min_distance"].min() > 0.5  # closest approach between observations: ~0.65
    assert result.extra["closest_approach"]["distance"] == pytest.approx(obs["min_distance"].min())
    assert np.diff(obs["Q"]).max() < 1e-3  # semi-implicit Euler, dt = 0.01
    json.dumps(result.summary(), allow_nan=False)


@pytest.mark.slow_cases("per_step")  # the fused twin stays fast
def test_fixed_preset_flocks(path):
    """Paper 000, Fig. 4/7: a connected random graph synchronises the velocities; W falls."""
    result = kernels.run(preset("tjp-fixed", observables_every=50))
    assert result.status == "completed", result.error
    assert result.extra["engine_path"] == path
    obs = result.observables
    assert result.extra["graph"]["components"] == 1
    assert obs["velocity_disagreement"][-1] < 1e-10
    assert obs["W"][-1] < obs["W"][0]
    assert obs["lambda2"][-1] == pytest.approx(result.extra["graph"]["lambda2"])
    assert obs["lambda2"][-1] > 0
    json.dumps(result.summary(), allow_nan=False)


# --- observables against brute force ----------------------------------------------------------

@pytest.mark.parametrize("search", ["grid", "all_pairs"])
def test_switching_observables_match_brute_force(path, search):
    sc = m2_scenario("switching", n=30, steps=30, R=1.8, spacing=1.0, speed=1.0, search=search)
    *_, (step, k) = run_states(sc, sc.time.steps, path)
    obs = k.observe(step)
    f = k.frame(["position", "velocity"])
    x, v = f["position"], f["velocity"]
    R, n = 1.8, sc.n_agents
    _, s2 = pair_geometry(x)
    adj = (s2 < R * R) & ~np.eye(n, dtype=bool)
    deg = adj.sum(axis=1)
    assert [obs[f"valency_{i}"] for i in range(n)] == deg.tolist()
    assert obs["components"] == connected_components(sp.csr_matrix(adj))[0]
    pot = sc.model.potential
    s = np.sqrt(s2[np.triu_indices(n, 1)])
    u_sat = np.where(s < R, [pot.value(t) for t in s], pot.value(R))
    q = u_sat.sum() + 0.5 * (v * v).sum()  # eq. 10: 1/2 sum_i sum_j U_ij + 1/2 sum |v|^2
    assert obs["Q"] == pytest.approx(q, rel=1e-12)
    np.fill_diagonal(s2, np.inf)
    i, j = np.unravel_index(np.argmin(s2), s2.shape)
    assert obs["min_distance"] == pytest.approx(np.sqrt(s2[i, j]), rel=1e-12)
    assert {obs["min_pair_i"], obs["min_pair_j"]} == {i, j}
    lap = np.diag(deg) - adj
    assert obs["lambda2"] == pytest.approx(max(np.linalg.eigvalsh(lap)[1], 0.0), abs=1e-9)
    dev = v - v.mean(axis=0)
    assert obs["velocity_disagreement"] == pytest.approx((dev**2).sum(), rel=1e-12)
    assert obs["speed_max"] == pytest.approx(np.hypot(*v.T).max(), rel=1e-12)


def test_large_n_reports_histograms_and_skips_lambda2(path):
    sc = Scenario.model_validate({
        "model": {"kind": "flocking", "valency_per_agent_max": 10, "lambda2_max_agents": 20},
        "space": {"kind": "plane"}, "neighbours": {"radius": 2.0},
        "initial": lattice(100, 1.0, 3), "time": {"steps": 2, "dt": 0.01},
    })
    obs = make_kernel(sc, path=path).observe(0)
    assert obs["lambda2"] == -1.0
    assert "valency_0" not in obs
    hist = [obs[f"valency_hist_{b}"] for b in range(16)] + [obs["valency_hist_16plus"]]
    assert sum(hist) == 100


def test_overlapping_agents_diverge_with_a_clear_error(path):
    sc = Scenario.model_validate({
        "model": {"kind": "flocking"}, "space": {"kind": "plane"},
        "neighbours": {"radius": 2.0},
        "initial": {"kind": "explicit", "positions": [[0, 0], [0, 0], [1, 0]]},
        "time": {"steps": 5, "dt": 0.01},
    })
    result = kernels.run(sc)
    assert result.status == "diverged" and result.extra["engine_path"] == path
    assert result.error["step"] == 0
    assert "same point" in result.error["cause"]


# --- fixed graphs -----------------------------------------------------------------------------

@pytest.mark.parametrize("spec,n,edges,max_deg", [
    ({"kind": "complete"}, 7, 21, 6),
    ({"kind": "ring"}, 9, 9, 2),
    ({"kind": "path"}, 9, 8, 2),
    ({"kind": "tree", "branching": 3}, 13, 12, 4),
    ({"kind": "tree"}, 50, 49, None),
    ({"kind": "random_connected", "mean_degree": 3.0}, 40, 60, None),
    ({"kind": "random_connected", "mean_degree": 8.0}, 10, 40, None),  # dense branch
    ({"kind": "edges", "edges": [[0, 1], [2, 1], [3, 0]]}, 4, 3, 2),
])
def test_generated_graphs(spec, n, edges, max_deg):
    g = GraphSpec.model_validate(spec)
    u, v = build_edges(g, n, seed=1)
    assert len(u) == edges and np.all(u < v)
    assert len(np.unique(u * n + v)) == edges
    indptr, idx = to_csr(n, u, v)
    adj = sp.csr_matrix((np.ones(len(idx)), idx, indptr), shape=(n, n))
    assert (adj != adj.T).nnz == 0
    assert connected_components(adj)[0] == 1
    if max_deg is not None:
        assert np.diff(indptr).max() == max_deg == g.max_valency(n)
    u2, v2 = build_edges(g, n, seed=1)
    assert np.array_equal(u, u2) and np.array_equal(v, v2)  # seeded: reproducible


@pytest.mark.parametrize("kind,n,expected", [
    ("complete", 12, 12.0),
    ("path", 12, 2 * (1 - np.cos(np.pi / 12))),
    ("path", 300, 2 * (1 - np.cos(np.pi / 300))),  # sparse shift-invert
    ("ring", 300, 2 * (1 - np.cos(2 * np.pi / 300))),
])
def test_lambda2_of_fixed_graphs(taichi_cpu, kind, n, expected):
    sc = m2_scenario("fixed", n=n, steps=1, graph={"kind": kind}, spacing=1.5)
    k = make_kernel(sc)
    assert k.extra()["graph"]["lambda2"] == pytest.approx(expected, rel=1e-8)
    assert k.observe(0)["lambda2"] == pytest.approx(expected, rel=1e-8)


def test_random_graph_depends_on_its_seed():
    g = GraphSpec(kind="random_connected", mean_degree=4.0)
    a, b = build_edges(g, 200, seed=1), build_edges(g, 200, seed=2)
    assert not np.array_equal(a[0] * 200 + a[1], b[0] * 200 + b[1])
    pinned = GraphSpec(kind="random_connected", mean_degree=4.0, seed=9)
    assert np.array_equal(build_edges(pinned, 200, 1)[0], build_edges(pinned, 200, 2)[0])


@pytest.mark.slow  # the small random graphs above stay fast
def test_random_connected_graph_at_a_million_agents():
    """N = 10^6 with mean degree 10: connected, no repeats, built without an N^2 step."""
    n = 1_000_000
    t0 = time.perf_counter()
    u, v = build_edges(GraphSpec(kind="random_connected", mean_degree=10.0), n, seed=3)
    indptr, idx = to_csr(n, u, v)
    elapsed = time.perf_counter() - t0
    assert len(u) == 5 * n
    keys = u * n + v
    keys.sort()
    assert np.all(keys[1:] != keys[:-1]) and np.all(u != v)
    adj = sp.csr_matrix((np.ones(len(idx), dtype=np.int8), idx, indptr), shape=(n, n))
    assert connected_components(adj)[0] == 1
    assert elapsed < 60  # ~3 s here; an N^2 step would take hours


# --- the schema refuses what cannot run ---------------------------------------------------------

def m2_spec(model=None, **top) -> dict:
    spec = {"model": {"kind": "flocking", **(model or {})}, "space": {"kind": "plane"},
            "neighbours": {"radius": 2.0},
            "initial": {"kind": "random", "N": 10,
                        "region": {"kind": "box", "low": [0, 0], "high": [3, 3]}},
            "time": {"steps": 10, "dt": 0.01}}
    spec.update(top)
    return {k: v for k, v in spec.items() if v is not None}


BAD = [
    (m2_spec({"topology": "fixed"}, neighbours=None), "needs model.graph"),
    (m2_spec({"topology": "fixed", "graph": {"kind": "ring"}}), "remove the neighbours block"),
    (m2_spec(neighbours=None), "needs a neighbours block with the radius R"),
    (m2_spec(neighbours={"radius": 0.9}), "must exceed the potential's desired distance"),
    (m2_spec(space={"kind": "periodic", "L": 10.0}, initial={"kind": "random", "N": 10}),
     "runs on the unbounded plane"),
    (m2_spec({"graph": {"kind": "ring"}}), "applies only to topology 'fixed'"),
    (m2_spec({"topology": "fixed", "graph": {"kind": "edges", "edges": [[0, 10]]}},
             neighbours=None), r"names an agent >= N = 10"),
    (m2_spec({"topology": "fixed", "graph": {"kind": "edges", "edges": [[3, 3]]}},
             neighbours=None), "self-loop"),
    (m2_spec({"topology": "fixed", "graph": {"kind": "edges", "edges": [[1, 2], [2, 1]]}},
             neighbours=None), "repeats an earlier edge"),
    (m2_spec({"topology": "fixed", "graph": {"kind": "random_connected", "mean_degree": 1.0}},
             neighbours=None), "mean_degree = 1 must lie in"),
    (m2_spec({"topology": "fixed", "graph": {"kind": "ring", "branching": 2}},
             neighbours=None), "branching applies only to kind tree"),
    (m2_spec({"topology": "fixed", "graph": {"kind": "complete"}}, neighbours=None,
             initial={"kind": "random", "N": 20000,
                      "region": {"kind": "box", "low": [0, 0], "high": [300, 300]}}),
     "over the limit of"),
    (m2_spec(time={"steps": 10, "dt": 0.8}), "too large for the pair potential"),
    (m2_spec({"topology": "fixed", "graph": {"kind": "complete"}}, neighbours=None,
             time={"steps": 10, "dt": 0.2}), "too large for the alignment term"),
    (m2_spec({"potential": {"kind": "paper002", "d": 2.0}}), "d applies only to kind"),
    (m2_spec({"neighbour_search": "all_pairs"},
             initial={"kind": "random", "N": 5000,
                      "region": {"kind": "box", "low": [0, 0], "high": [70, 70]}}),
     "costs N\\^2 per step"),
    (m2_spec({"topology": "fixed", "graph": {"kind": "ring"}, "neighbour_search": "grid"},
             neighbours=None), "applies to topology 'switching' only"),
    (m2_spec({"integrator": "leapfrog"}), "semi_implicit_euler"),
]


@pytest.mark.parametrize("spec,message", BAD, ids=[m for _, m in BAD])
def test_bad_scenarios_are_rejected(spec, message):
    with pytest.raises(ValidationError, match=message):
        Scenario.model_validate(spec)


def test_presets_validate():
    for name in ("tjp-fixed", "tjp-switching", "tanner-obstacles"):
        sc = Scenario.model_validate(PRESETS[name].build())
        assert sc.name == name
