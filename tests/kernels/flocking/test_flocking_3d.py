"""M2 (Tanner–Jadbabaie–Pappas) and M3 (Tanner's obstacles) in 3D: every step against the
brute-force reference (fixed and switching, all pairs and the hashed grid, Euler and RK4;
point and sphere obstacles, the adaptive radius), and M2's theorems: the mean velocity is
conserved, W (fixed) and Q (switching) do not increase."""

import numpy as np
import pytest

from flocklab import kernels
from flocklab.schemas import Scenario
from tests.kernels.flocking.test_flocking_reference import euler, m2_accel, rk4


class Frames:
    def __init__(self):
        self.pos, self.vel = [], []

    def frame(self, step, time, arrays):
        self.pos.append(arrays["position"])
        self.vel.append(arrays["velocity"])


def lattice_3d(n: int, spacing: float, seed: int, speed: float = 0.5) -> dict:
    """Explicit 3D state: a jittered cubic lattice, random velocities."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(n ** (1 / 3) - 1e-9))
    k = np.arange(n)
    g = np.stack([k % side, (k // side) % side, k // side**2], axis=1)
    pos = spacing * (g + rng.uniform(-0.2, 0.2, size=(n, 3)))
    vel = rng.uniform(-speed, speed, size=(n, 3))
    return {"kind": "explicit", "positions": pos.tolist(), "velocities": vel.tolist()}


def scenario(topology="switching", n=27, steps=30, dt=0.01, integrator="semi_implicit_euler",
             search="auto", R=1.8, seed=5, every=1, spacing=1.1) -> Scenario:
    model = {"kind": "flocking", "topology": topology, "integrator": integrator,
             "potential": {"kind": "log_barrier", "d": 1.0}}
    spec = {"model": model, "space": {"kind": "plane", "dimension": 3},
            "initial": lattice_3d(n, spacing, seed), "time": {"steps": steps, "dt": dt},
            "recording": {"every": every, "arrays": ["position", "velocity"]}, "seed": seed}
    if topology == "fixed":
        model["graph"] = {"kind": "ring"}
    else:
        model["neighbour_search"] = search
        spec["neighbours"] = {"radius": R}
    return Scenario.model_validate(spec)


def ring(n: int) -> np.ndarray:
    adj = np.zeros((n, n), dtype=bool)
    i = np.arange(n)
    adj[i, (i + 1) % n] = adj[(i + 1) % n, i] = True
    return adj


CASES = [
    dict(topology="switching", search="all_pairs"),
    dict(topology="switching", search="grid", n=64),
    dict(topology="switching", search="grid", integrator="rk4"),
    dict(topology="fixed"),
    dict(topology="fixed", integrator="rk4"),
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(f"{v}" for v in c.values()))
# RK4 and the grid stay fast in per_step-fixed-rk4 and the switching-grid-64 cases.
@pytest.mark.slow_cases("per_step-switching-grid-rk4")
@pytest.mark.fast_cases("fused-switching-grid-64", "fused-fixed", "per_step-switching-all_pairs",
                        "per_step-fixed-rk4")
def test_matches_brute_force_step_by_step(taichi_cpu, path, case):
    """On both engine paths, Euler and RK4."""
    sc = scenario(**case)
    sink = Frames()
    result = kernels.run(sc, sink=sink)
    assert result.status == "completed" and result.extra["engine_path"] == path
    a, _ = sc.model.potential.coefficients()
    R = None if sc.neighbours is None else sc.neighbours.radius
    adj = ring(sc.n_agents) if sc.model.topology == "fixed" else None

    def accel(x, v):
        return m2_accel(x, v, a=a, adj=adj, R=R, inclusive=sc.inclusive)

    x, v = sink.pos[0], sink.vel[0]
    assert x.shape == (sc.n_agents, 3)
    for step in range(sc.time.steps):
        if sc.model.integrator == "rk4":
            x, v = rk4(x, v, accel, sc.time.dt)
        else:
            x, v = euler(x, v, accel(x, v), sc.time.dt)
        assert np.abs(sink.pos[step + 1] - x).max() < 1e-10, step
        assert np.abs(sink.vel[step + 1] - v).max() < 1e-10, step


@pytest.mark.parametrize("topology,energy", [("fixed", "W"), ("switching", "Q")])
def test_mean_velocity_conserved_and_energy_non_increasing(taichi_cpu, topology, energy):
    sc = scenario(topology=topology, n=64, steps=300, dt=0.005, every=0, search="grid")
    result = kernels.run(sc)
    obs = result.observables
    for c in "xyz":
        mean = obs[f"mean_velocity_{c}"]
        assert np.ptp(mean) < 1e-12, c  # eq. 3 is antisymmetric in (i, j)
    e = obs[energy]
    assert (np.diff(e) <= 1e-9 * np.abs(e).max()).all()
    assert e[-1] < e[0]  # ... and it does fall: the velocities align
    assert obs["velocity_disagreement"][-1] < obs["velocity_disagreement"][0]


def test_3d_heading_frames_and_observables(taichi_cpu):
    sc = Scenario.model_validate({
        "model": {"kind": "flocking"}, "space": {"kind": "plane", "dimension": 3},
        "neighbours": {"radius": 1.5},
        "initial": {"kind": "random", "N": 100, "speed_range": [0.5, 1.0],
                    "region": {"kind": "lattice", "low": [0, 0, 0], "spacing": 1.0}},
        "time": {"steps": 5, "dt": 0.01},
        "recording": {"every": 5, "arrays": ["position", "velocity", "heading"]},
    })

    class Keep(Frames):
        def frame(self, step, time, arrays):
            super().frame(step, time, arrays)
            self.head = arrays["heading"]

    sink = Keep()
    result = kernels.run(sc, sink=sink)
    assert sink.head.shape == (100, 3)
    assert np.allclose(sink.head * np.linalg.norm(sink.vel[-1], axis=1)[:, None], sink.vel[-1])
    assert {"mean_velocity_z", "Q", "components", "lambda2"} <= set(result.final)
    assert 0 <= result.final["heading_spread"] <= 2 * np.pi


def m3_scenario(steps=150, search="auto", **model) -> Scenario:
    """Paper 002's law in 3D: point and sphere obstacles between the flock and r_d."""
    base = {"kind": "flocking_obstacles", "destination": [4.0, -1.0, 0.5],
            "obstacles": [[1.2, 0.4, 0.6], [2.0, 1.0, 1.2], [1.5, 0.2, 1.6]],
            "discs": [{"center": [3.0, 0.0, 0.0], "radius": 0.6}],
            "obstacle_range": 0.6, "radius_every": 5, "stuck_speed": 0.1,
            "radius_floor": 1.0, "V_min": 0.3, "c_d": 2.0, "neighbour_search": search}
    base.update(model)
    return Scenario.model_validate({
        "model": base, "space": {"kind": "plane", "dimension": 3},
        "neighbours": {"radius": 2.0}, "initial": lattice_3d(12, 1.05, 7, speed=0.4),
        "time": {"steps": steps, "dt": 0.01},
        "recording": {"every": 1, "arrays": ["position", "velocity"]}, "seed": 7,
    })


@pytest.mark.parametrize("case", [dict(), dict(search="grid", radius_rule="min"),
                                  dict(integrator="rk4", kappa=2.0, damping_region="everywhere")],
                         ids=["own", "min-grid", "rk4-kappa2"])
# Minutes of Python reference in 3D; radius_rule "min" on the grid and RK4 stay fast in 2D
# (test_flocking_reference.py, test_obstacles.py).
@pytest.mark.slow_cases("per_step-min-grid", "per_step-rk4-kappa2", "fused-rk4-kappa2", "fused-own",
                        "per_step-own")
def test_obstacles_match_brute_force_step_by_step(taichi_cpu, path, case):
    """On both engine paths (radius_rule "min" has only the per-step one)."""
    from tests.kernels.flocking.test_flocking_reference import M3Ref

    sc = m3_scenario(**case)
    p = sc.model
    sink = Frames()
    result = kernels.run(sc, sink=sink)
    fused = p.radius_rule == "own"
    want = path if fused else "per_step"
    assert result.status == "completed" and result.extra["engine_path"] == want
    ref = M3Ref(p, sc.neighbours.radius, sc.inclusive)
    x, v = sink.pos[0], sink.vel[0]
    R = np.full(sc.n_agents, sc.neighbours.radius)
    halved = grown = 0
    for step in range(sc.time.steps):
        if step > 0 and step % p.radius_every == 0:
            R_new = ref.radius(x, v, R)
            halved += int((R_new < R).sum())
            grown += int((R_new > R).sum())
            R = R_new
        if p.integrator == "rk4":
            x, v = rk4(x, v, lambda x, v: ref.accel(x, v, R), sc.time.dt)  # noqa: B023
        else:
            x, v = euler(x, v, ref.accel(x, v, R), sc.time.dt)
        err = max(np.abs(sink.pos[step + 1] - x).max(), np.abs(sink.vel[step + 1] - v).max())
        assert err < 1e-10, f"step {step}: {err:.3g}"
    counts = result.extra["adaptive_radius"]
    assert (counts["halvings"], counts["increases"]) == (halved, grown)
    assert halved > 0 and grown > 0  # both branches of eq. 4 were exercised
    assert result.final["obstacle_distance_min"] < 0.6  # the obstacles were felt


def test_obstacle_coordinates_must_match_the_dimension():
    from pydantic import ValidationError

    from flocklab.schemas import field_errors

    with pytest.raises(ValidationError) as exc:
        m3_scenario(obstacles=[[1.0, 1.0]])
    (err,) = field_errors(exc.value)
    assert err.loc == "model" and "obstacles[0] has 2 coordinates" in err.msg


def two_clusters_3d(n: int, gap: float, seed: int) -> dict:
    """Two jittered cubic lattices `gap` apart along x: a bounding box of far more cells
    than agents, where the dense grid gives way to the hashed one."""
    half = lattice_3d(n // 2, 1.1, seed)
    other = lattice_3d(n - n // 2, 1.1, seed + 1)
    pos = half["positions"] + [[x + gap, y, z] for x, y, z in other["positions"]]
    return {"kind": "explicit", "positions": pos,
            "velocities": half["velocities"] + other["velocities"]}


@pytest.mark.parametrize("hashed,sprawl", [(False, False), (True, False), (False, True)],
                         ids=["dense", "hash", "sprawl-falls-back-to-hash"])
def test_3d_grids_match_brute_force(taichi_cpu, hashed, sprawl):
    """The dense 3D grid (nine contiguous rows of three cells), the hashed grid of a device
    without it, and a sprawling swarm's fallback: each step equals the brute-force law."""
    from tests.kernels.flocking.test_flocking_reference import make_kernel

    sc = scenario(n=216, steps=8, search="grid", R=1.8)
    if sprawl:
        spec = sc.model_dump(mode="json")
        spec["initial"] = two_clusters_3d(216, 1e4, 7)
        sc = Scenario.model_validate(spec)
    k = make_kernel(sc, hashed=hashed)
    f = k.frame(["position", "velocity"])
    x, v = f["position"], f["velocity"]
    a, _ = sc.model.potential.coefficients()
    for step in range(sc.time.steps):
        k.step(step)
        x, v = euler(x, v, m2_accel(x, v, a=a, R=1.8, inclusive=sc.inclusive), sc.time.dt)
        f = k.frame(["position", "velocity"])
        assert np.abs(f["position"] - x).max() < 1e-10, step
        assert np.abs(f["velocity"] - v).max() < 1e-10, step
    assert k.grid.layout == ("hash" if hashed or sprawl else "dense")
