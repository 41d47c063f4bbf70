"""Tanner–Jadbabaie–Pappas flocking (paper 000, switching) with topological neighbours:
N_i = the k nearest within R (Ballerini et al. 2008), against an independent numpy
reference (the k nearest by sorting every distance, ties by agent id; u_i of eq. 3 over
them), step by step in 2D and 3D, directed and symmetric; ties on an exact lattice, N <= k
with every agent in one cell; the degree array and the components; and the refusals."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pydantic
import pytest
from scipy.sparse.csgraph import connected_components

from flocklab import kernels
from flocklab.kernels.model import all_kernels
from flocklab.kernels.runtime import DevicePolicy
from flocklab.schemas import Scenario

from ...reference import knn_adjacency
from .test_flocking_reference import euler, m2_accel, rk4, state

pytestmark = pytest.mark.usefixtures("taichi_cpu")

TOL = 1e-10


def jittered(n: int, dim: int, spacing: float, jitter: float, seed: int) -> dict:
    """Explicit initial state: a (jittered) square or cubic lattice, random velocities."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(n ** (1.0 / dim)))
    axes = np.meshgrid(*[np.arange(side)] * dim)
    g = np.stack(axes, -1).reshape(-1, dim)[:n]
    pos = spacing * (g + rng.uniform(-jitter, jitter, size=(n, dim)))
    vel = rng.uniform(-0.5, 0.5, size=(n, dim))
    return {"kind": "explicit", "positions": pos.tolist(), "velocities": vel.tolist()}


def spec(n=20, dim=2, k=4, R=2.0, symmetric=False, spacing=1.1, jitter=0.2, seed=3,
         steps=60, **model) -> dict:
    return {
        "model": {"kind": "flocking", "topology": "switching",
                  "potential": {"kind": "log_barrier", "d": 1.0}, **model},
        "space": {"kind": "plane", "dimension": dim},
        "neighbours": {"kind": "topological", "k": k, "radius": R, "symmetric": symmetric},
        "initial": jittered(n, dim, spacing, jitter, seed),
        "time": {"steps": steps, "dt": 0.01}, "seed": seed,
    }


def kernel(sc: Scenario):
    return all_kernels()["flocking"](sc, DevicePolicy(serial_scatter=True, dense_grid=True))


def reference_adjacency(sc: Scenario, x: np.ndarray) -> np.ndarray:
    nb = sc.neighbours
    return knn_adjacency(x, nb.k, None, nb.radius, sc.inclusive, nb.symmetric)


CASES = {
    "2d": dict(),
    "2d-symmetric": dict(symmetric=True),
    "3d": dict(dim=3, n=27, k=6, R=2.2),
    "3d-symmetric": dict(dim=3, n=27, k=6, R=2.2, symmetric=True),
    # Exact lattice: four neighbours at one distance, k = 3 keeps the lowest ids.
    "2d-ties": dict(jitter=0.0, spacing=1.0, k=3, steps=1),
    # N - 1 < k: every other agent within R; they all fit in one of the k-NN grid's cells.
    "2d-n-below-k": dict(n=5, k=12, R=10.0),
    "3d-n-below-k": dict(dim=3, n=6, k=12, R=10.0),
    # RK4: each stage's k nearest at the stage's positions.
    "2d-rk4": dict(integrator="rk4"),
    "3d-rk4-symmetric": dict(dim=3, n=27, k=6, R=2.2, symmetric=True, integrator="rk4"),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.fast_cases("2d", "3d-symmetric", "2d-ties", "2d-n-below-k", "2d-rk4")
def test_matches_the_brute_force_reference_step_by_step(case):
    sc = Scenario.model_validate(spec(**CASES[case]))
    k = kernel(sc)
    x, v = state(k)
    a, _ = sc.model.potential.coefficients()
    worst = 0.0
    def accel(x, v):
        return m2_accel(x, v, a=a, adj=reference_adjacency(sc, x))

    for step in range(sc.time.steps):
        k.step(step)
        if sc.model.integrator == "rk4":
            x, v = rk4(x, v, accel, sc.time.dt)
        else:
            x, v = euler(x, v, accel(x, v), sc.time.dt)
        kx, kv = state(k)
        worst = max(worst, np.abs(kx - x).max(), np.abs(kv - v).max())
        assert worst < TOL, f"step {step}: engine and reference differ by {worst:.3g}"
    assert np.abs(v).max() > 1e-3  # the run did something


def test_ties_are_broken_by_agent_id():
    """On an exact integer lattice (5 x 5) most agents have four others at distance 1:
    the k-NN lists are the reference's, the lowest ids among equals."""
    sc = Scenario.model_validate(spec(jitter=0.0, spacing=1.0, k=3, n=25, steps=1))
    k = kernel(sc)
    k.step(0)  # the lists are searched at the step's sort
    ids = k.state.ids_numpy()
    got = k.knn.lists(ids)
    x0 = np.array(sc.initial.positions)
    want = [list(np.nonzero(row)[0]) for row in reference_adjacency(sc, x0)]
    assert [sorted(g) for g in got] == want
    # The centre agent 12, at (2, 2), has 7, 11, 13 and 17 at distance 1: 17 is left out.
    assert sorted(got[12]) == [7, 11, 13]


@pytest.mark.parametrize("symmetric", [False, True])
def test_degree_and_components_are_the_knn_graphs(symmetric):
    """degree: |N_i| (k for every agent with k others within R when directed); the
    components of the (weakly connected) graph, from the engine's union of every edge."""
    # Two lattices far apart: two components whatever k.
    one = jittered(16, 2, 1.1, 0.2, 4)
    two = jittered(16, 2, 1.1, 0.2, 5)
    pos = one["positions"] + [[p[0] + 40.0, p[1]] for p in two["positions"]]
    s = spec(n=32, k=5, R=3.0, symmetric=symmetric, steps=3)
    s["initial"] = {"kind": "explicit", "positions": pos,
                    "velocities": one["velocities"] + two["velocities"]}
    s["recording"] = {"arrays": ["position", "velocity", "degree"], "every": 1}
    sc = Scenario.model_validate(s)
    k = kernel(sc)
    adj = reference_adjacency(sc, np.array(pos))
    deg = k.derived_arrays(0, ["degree"])["degree"]
    np.testing.assert_array_equal(deg, adj.sum(axis=1))
    if not symmetric:
        assert (deg == 5).all()
    obs = k.observe(0)
    want, _ = connected_components(adj | adj.T, directed=False)
    assert want == 2
    assert obs["components"] == want
    assert obs["valency_mean"] == pytest.approx(adj.sum(axis=1).mean(), abs=0)


def test_a_run_takes_the_per_step_schedule_and_records_it():
    sc = Scenario.model_validate(spec(steps=30))
    result = kernels.run(sc)
    assert result.status == "completed"
    assert result.extra["engine_path"] == "per_step"
    # Links switch at any distance: eq. 10-11's Q is not claimed (a metric run's is).
    assert "Q_non_increasing" not in result.extra.get("checks", {})
    metric = spec(steps=30)
    metric["neighbours"] = {"radius": 2.0}
    assert "Q_non_increasing" in kernels.run(Scenario.model_validate(metric)).extra["checks"]
    with pytest.raises(kernels.engine.PathUnavailable, match="per-step schedule only"):
        kernels.run(sc, path="fused")


@pytest.mark.parametrize(("change", "words"), [
    (lambda s: s["model"].update(integrator="leapfrog"), "integrator"),
    (lambda s: s["neighbours"].pop("radius"), "neighbours block with the radius R"),
    (lambda s: s["neighbours"].update(radius=0.5), "neighbours.radius R"),
    (lambda s: s["model"].update(neighbour_search="all_pairs"), "neighbour_search"),
    (lambda s: s["neighbours"].pop("k"), "neighbours.k"),
    (lambda s: (s["model"].update(topology="fixed", graph={"kind": "ring"})),
     "remove the neighbours block"),
], ids=["integrator", "no-radius", "radius-below-d", "all-pairs", "no-k", "fixed"])
def test_bad_parameters_name_the_field(change, words):
    s = spec()
    change(s)
    with pytest.raises(pydantic.ValidationError, match=words):
        Scenario.model_validate(s)


def test_flocklab_validate_refuses_with_exit_2(tmp_path):
    s = spec()
    s["neighbours"]["radius"] = 0.5  # R <= d
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(s))
    out = subprocess.run([sys.executable, "-m", "flocklab", "validate", str(f)],
                         capture_output=True, text=True)
    assert out.returncode == 2
    assert "neighbours.radius" in out.stderr + out.stdout
    assert "Traceback" not in out.stderr
