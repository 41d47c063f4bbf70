"""M3 (paper 002): the navigation function and its obstacle grid, the preset's mission,
the adaptive radius in a constructed stuck case, observables, and refused scenarios."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp
import taichi as ti
from pydantic import ValidationError
from scipy.optimize import brentq
from scipy.sparse.csgraph import connected_components

from flocklab import kernels
from flocklab.kernels.models.flocking.navigation import nav_eval_kernel
from flocklab.schemas import PRESETS, Scenario
from tests.kernels.flocking.test_flocking_reference import (
    fused_or_skip,
    lattice,
    m3_scenario,
    make_kernel,
    navigation_ref,
    pair_geometry,
)

# Taichi on the CPU for every test (the two-path `path` fixture does not start it).
pytestmark = pytest.mark.usefixtures("taichi_cpu")


def nav_at(k, points: np.ndarray) -> np.ndarray:
    """The engine's (V, dV/dx, dV/dy, min boundary distance) at points."""
    pts = ti.ndarray(ti.f64, shape=points.shape)
    pts.from_numpy(np.ascontiguousarray(points))
    out = ti.ndarray(ti.f64, shape=(len(points), 4))
    nav_eval_kernel(k.flags["has_obstacles"], k.flags["unit_kappa"], k.dim)(
        pts, out, k.mission.nav, *k.mission.obstacles.view())
    return out.to_numpy()


def obstacle_world(kappa: float, n_points: int, n_discs: int, seed: int = 0, spread=3.0):
    rng = np.random.default_rng(seed)
    return m3_scenario(
        kappa=kappa,
        destination=[0.2, -0.3],
        obstacles=rng.uniform(-spread, spread, size=(n_points, 2)).tolist(),
        discs=[{"center": c, "radius": r} for c, r in
               zip(rng.uniform(-spread, spread, size=(n_discs, 2)).tolist(),
                   rng.uniform(0.05, 0.3, size=n_discs).tolist(), strict=True)],
        obstacle_range=0.7,
    )


def probe_points(sc: Scenario, n: int, seed: int = 1) -> np.ndarray:
    """Points near the obstacles (within their range) but off their boundaries."""
    p = sc.model
    rng = np.random.default_rng(seed)
    centers = np.array([*p.obstacles, *(d.center for d in p.discs)])
    radii = np.array([0.0] * len(p.obstacles) + [d.radius for d in p.discs])
    pick = rng.integers(0, len(centers), size=n)
    ang = rng.uniform(0, 2 * np.pi, size=n)
    r = radii[pick] + rng.uniform(0.05, 0.65, size=n)
    return centers[pick] + r[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)


@pytest.mark.parametrize("kappa", [1.0, 2.5])
def test_navigation_gradient_matches_finite_differences(taichi_cpu, kappa):
    sc = obstacle_world(kappa, n_points=30, n_discs=6)
    k = make_kernel(sc)
    x = np.concatenate([probe_points(sc, 300), np.random.default_rng(2).uniform(-5, 5, (50, 2))])
    g = nav_at(k, x)[:, 1:3]
    h = 1e-6
    for c in range(2):
        e = np.zeros(2)
        e[c] = h
        fd = (nav_at(k, x + e)[:, 0] - nav_at(k, x - e)[:, 0]) / (2 * h)
        np.testing.assert_allclose(g[:, c], fd, rtol=1e-5, atol=1e-7)
    assert np.abs(g).max() > 0.1  # obstacles within reach do bend the field


def test_obstacle_grid_matches_brute_force(taichi_cpu):
    """The obstacle grid finds every obstacle within reach: V, grad V and the nearest
    boundary agree with the O(N M) reference (which sees every obstacle)."""
    sc = obstacle_world(1.0, n_points=300, n_discs=40, seed=5, spread=6.0)
    p = sc.model
    k = make_kernel(sc)
    far = np.random.default_rng(4).uniform(-9, 9, (50, 2))
    x = np.concatenate([probe_points(sc, 250, seed=3), far])
    got = nav_at(k, x)
    centers = np.array([*p.obstacles, *(d.center for d in p.discs)])
    radii = np.array([0.0] * len(p.obstacles) + [d.radius for d in p.discs])
    V, G = navigation_ref(x, np.array(p.destination), centers, radii, p.obstacle_range, p.kappa)
    np.testing.assert_allclose(got[:, 0], V, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(got[:, 1:3], G, rtol=1e-10, atol=1e-12)
    delta = np.hypot(*(x[:, None, :] - centers[None]).transpose(2, 0, 1)) - radii
    near = delta.min(axis=1) < k.mission.obstacles.cell  # exact below the cell; capped above
    np.testing.assert_allclose(got[near, 3], delta.min(axis=1)[near], rtol=1e-12)
    assert near.sum() > 200


@pytest.mark.slow_cases("per_step")
def test_obstacle_preset_reaches_the_destination(path):
    """Paper 002, section V: every vehicle ends inside the V_min level set around (0, 0),
    with no vehicle-vehicle or vehicle-obstacle collision on the way."""
    spec = PRESETS["tanner-obstacles"].build()
    spec["recording"] = {**spec["recording"], "observables_every": 25}
    result = kernels.run(Scenario.model_validate(spec))
    assert result.status == "completed", result.error
    assert result.extra["engine_path"] == path
    obs = result.observables
    assert obs["time"][-1] == pytest.approx(300.0)
    assert obs["inside_vmin_fraction"][-1] == 1.0
    assert obs["mission_potential_max"][-40:].max() < spec["model"]["V_min"]  # the last 20 s
    assert obs["destination_distance_max"][-1] < 1.3
    assert obs["min_distance"].min() > 0.6  # ~0.78 here
    assert obs["obstacle_distance_min"].min() > 0.15  # ~0.25 here, at the leg's end
    assert obs["destination_distance_mean"][0] > 5.0  # it did travel
    json.dumps(result.summary(), allow_nan=False)


def test_every_count_at_the_step_cap_runs(path):
    """radius_every, observables_every and every may be as large as time.steps may
    (10^9, an int32 in the kernels; one more is refused: tests/schemas/test_schemas.py): eq. 4
    then never runs, the observables are taken at the start and the end, one frame at the
    end."""
    spec = PRESETS["tanner-obstacles"].build()
    spec["time"]["steps"] = 20
    spec["model"]["radius_every"] = 10**9
    spec["recording"] = {**spec["recording"], "every": 10**9, "observables_every": 10**9}
    result = kernels.run(Scenario.model_validate(spec))
    assert result.status == "completed", result.error
    assert result.extra["engine_path"] == path
    dt = spec["time"]["dt"]
    assert result.observables["time"].tolist() == [0.0, pytest.approx(20 * dt)]
    R = spec["neighbours"]["radius"]
    assert result.observables["radius_min"].tolist() == [R, R]  # eq. 4 never ran


@pytest.mark.slow_cases("fused")
def test_stuck_pair_halves_then_recovers_its_radius(path):
    """A constructed stuck case for eq. 4. Agent 0 sits at the destination, agent 1 at rest
    where the mission pull balances the pair repulsion (2 s / (1 + s^2)^2 = 2/s^3 - 2/s,
    s = 0.8955). Agent 0 is pushed off the destination, the pair drifts, and whichever
    vehicle comes to rest (|v| < 0.01) outside the V_min = 0.3 level set halves its radius
    2 -> 1; at the next evaluation it moves again with its neighbour (R = 2) within R_i = 1,
    so R_i <- max(R_i, R_j) = 2."""
    s0 = brentq(lambda s: 2 / s**3 - 2 / s - 2 * s / (1 + s * s) ** 2, 0.5, 0.99)
    every, dt = 20, 0.01
    sc = Scenario.model_validate({
        "model": {"kind": "flocking_obstacles", "V_min": 0.3, "stuck_speed": 0.01,
                  "radius_every": every, "radius_floor": 0.25, "c_d": 0.5},
        "space": {"kind": "plane"}, "neighbours": {"radius": 2.0},
        "initial": {"kind": "explicit", "positions": [[0, 0], [0, s0]],
                    "velocities": [[0, 0], [0, 0]]},
        "time": {"steps": 1000, "dt": dt},
    })
    k = make_kernel(sc, path=path)
    history = []  # (time, R_0, R_1, speeds, V) at every evaluation of eq. 4
    for step in range(sc.time.steps):
        if step > 0 and step % every == 0:
            f = k.frame(["velocity"])
            obs = k.observe(step)
            speeds = np.hypot(*f["velocity"].T)
            k.step(step)  # eq. 4 runs first in this step
            r = k.state.in_id_order("rad")
            history.append((step * dt, *r, speeds, obs))
        else:
            k.step(step)
    changes = [(t, r0, r1, v) for t, r0, r1, v, _ in history if (r0, r1) != (2.0, 2.0)]
    assert changes, "no radius ever changed"
    t_half, r0, r1, speeds = changes[0]
    halved = 0 if r0 == 1.0 else 1
    assert sorted((r0, r1)) == [1.0, 2.0]  # one vehicle halved, the other kept R
    assert speeds[halved] < 0.01  # it was immobilised
    after = [h for h in history if h[0] == pytest.approx(t_half + every * dt)]
    assert after and after[0][1:3] == (2.0, 2.0)  # and recovered at the next evaluation
    assert after[0][3][halved] >= 0.01  # moving again
    assert k.extra()["adaptive_radius"] == {"halvings": 2, "increases": 2}  # two cycles in 10 s


@pytest.mark.slow_cases("per_step-min", "per_step-own")
@pytest.mark.parametrize("rule", ["own", "min"])
def test_m3_observables_match_brute_force(path, rule):
    sc = m3_scenario(n=14, steps=60, radius_rule=rule, neighbour_search="grid")
    fused_or_skip(path, sc)
    k = make_kernel(sc, path=path)
    for step in range(sc.time.steps):
        k.step(step)
    obs = k.observe(sc.time.steps)
    p, n = sc.model, sc.n_agents
    f = k.frame(["position", "velocity"])
    x, v = f["position"], f["velocity"]
    R = k.state.in_id_order("rad")
    assert len(set(R)) > 1  # the radii differ by now
    _, s2 = pair_geometry(x)
    r = np.repeat(R[:, None], n, axis=1) if rule == "own" else np.minimum(R[:, None], R[None, :])
    off = ~np.eye(n, dtype=bool)
    near = (s2 <= r * r) & off
    assert [obs[f"valency_{i}"] for i in range(n)] == near.sum(axis=1).tolist()
    n_comp, labels = connected_components(sp.csr_matrix(near | near.T))
    assert obs["components"] == n_comp
    pot = p.potential
    u = np.where((s2 < r * r) & off, [[pot.value(np.sqrt(t)) if t > 0 else 0 for t in row]
                                      for row in s2], 0.0)
    u_sat = np.where((s2 < r * r) & off, u, np.vectorize(pot.value)(r)) * off
    centers = np.array([*p.obstacles, *(d.center for d in p.discs)])
    radii = np.array([0.0] * len(p.obstacles) + [d.radius for d in p.discs])
    V, _ = navigation_ref(x, np.array(p.destination), centers, radii, p.obstacle_range, p.kappa)
    q = 0.5 * (u_sat.sum() + (v * v).sum()) + V.sum()  # eq. 5
    assert obs["Q"] == pytest.approx(q, rel=1e-12)
    assert obs["inside_vmin_fraction"] == np.mean(V <= p.V_min)
    assert (obs["radius_min"], obs["radius_max"]) == (R.min(), R.max())
    dist = np.hypot(*(x - p.destination).T)
    assert obs["destination_distance_max"] == pytest.approx(dist.max(), rel=1e-12)
    within = 0.0
    for c in range(n_comp):
        m = labels == c
        within += ((v[m] - v[m].mean(axis=0)) ** 2).sum()
    assert obs["velocity_disagreement_components"] == pytest.approx(within, rel=1e-9)


def m3_spec(**model) -> dict:
    return {"model": {"kind": "flocking_obstacles", **model}, "space": {"kind": "plane"},
            "neighbours": {"radius": 2.0}, "initial": lattice(4, 1.0, 0),
            "time": {"steps": 10, "dt": 0.01}}


BAD = [
    (m3_spec(radius_floor=3.0), "radius_floor = 3 exceeds the initial radius"),
    (m3_spec(obstacles=[[1, 1], [0, 0]]), r"obstacles\[1\] lies on the destination"),
    (m3_spec(discs=[{"center": [0.5, 0], "radius": 1.0}]), r"discs\[0\] covers the destination"),
    (m3_spec(V_min=1.0), "less than 1"),
    (m3_spec(kappa=0.5), "greater than or equal to 1"),
    (m3_spec(damping_region="inside"), "above_vmin"),
    (m3_spec(potential={"kind": "log_barrier", "d": 2.5}), "must exceed the potential's"),
    ({**m3_spec(), "neighbours": None}, "its radius is the initial R_i"),
]


@pytest.mark.parametrize("spec,message", BAD, ids=[m for _, m in BAD])
def test_bad_m3_scenarios_are_rejected(spec, message):
    spec = {k: v for k, v in spec.items() if v is not None}
    with pytest.raises(ValidationError, match=message):
        Scenario.model_validate(spec)
