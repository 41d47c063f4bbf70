"""M4 (Xi–Abed): the kernel against an independent brute-force numpy reference, the paper's
properties at small N, the helpers (formations, paths, schedule, D1-D3) and validation."""

import itertools
import math

import numpy as np
import pytest
from pydantic import ValidationError

from flocklab import kernels
from flocklab.kernels.models.formation.path import make_path
from flocklab.kernels.models.formation.props import Isolated, d3_holds
from flocklab.kernels.models.formation.schedule import OffsetSchedule
from flocklab.kernels.models.formation.shapes import named_offsets
from flocklab.schemas import Scenario
from flocklab.schemas.formation import FormationChange, NamedFormation, SplinePath

D = 20.0


class Frames:
    """A FrameSink keeping every frame (small runs only)."""

    def __init__(self):
        self.time, self.pos, self.vel = [], [], []

    def frame(self, step, time, arrays):
        self.time.append(time)
        self.pos.append(arrays["position"])
        self.vel.append(arrays.get("velocity"))


def scenario(model, *, N=10, box=30.0, steps=40, dt=0.01, every=1, arrays=("position",),
             obs_every=1, seed=5, inclusive=None, positions=None):
    init = ({"kind": "explicit", "positions": positions} if positions is not None else
            {"kind": "random", "N": N,
             "region": {"kind": "box", "low": [0.0, 0.0], "high": [box, box]}})
    return Scenario.model_validate({
        "model": {"kind": "formation", **model},
        "space": {"kind": "plane"},
        "neighbours": {"radius": D, "inclusive": inclusive},
        "initial": init,
        "time": {"steps": steps, "dt": dt},
        "recording": {"every": every, "arrays": list(arrays), "observables_every": obs_every},
        "seed": seed,
    })


def run(sc):
    sink = Frames()
    result = kernels.run(sc, sink=sink)
    return result, sink


# --- the independent reference -----------------------------------------------------------


def ref_f_unit(z, f):
    """f(|z|) z/|z| row by row."""
    s = np.hypot(z[:, 0], z[:, 1])[:, None]
    if f["kind"] == "linear":
        return f["k"] * z
    if f["kind"] == "quadratic":
        return f["c"] * (s * s + s) * z / np.where(s > 0, s, 1.0)
    mag = f["v_max"] * np.tanh(f["k"] * s / f["v_max"])
    return mag * z / np.where(s > 0, s, 1.0)


def ref_g(s, g):
    if g["kind"] == "inverse":
        return -g["k_g"] * (1.0 / s - 1.0 / D)
    return -g["k_g"] * (1.0 / s**2 - 1.0 / D**2)


def ref_leader(t, m, p0):
    path = m["path"]
    target = np.asarray(path["target"])
    T = path.get("arrival_time") or np.hypot(*(target - p0)) / path["speed"]
    return p0 + min(t / T, 1.0) * (target - p0)


def ref_offsets(t, m):
    """b_i(t) for an explicit formation and at most one change (rotate or morph)."""
    b0 = np.asarray(m["formation"]["offsets"], dtype=float)
    if not m.get("schedule"):
        return b0
    c = m["schedule"][0]
    u = min(max((t - c["start"]) / (c["end"] - c["start"]), 0.0), 1.0)
    s = u if c.get("relaxation") == "linear" else 3 * u * u - 2 * u**3
    if c.get("rotate") is not None:
        a = s * c["rotate"]
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        return b0 @ rot.T
    return (1 - s) * b0 + s * np.asarray(c["formation"]["offsets"], dtype=float)


def ref_rates(x, t, m, p0):
    lead = ref_leader(t, m, p0)
    target = lead + ref_offsets(t, m) if m.get("design", "F1") == "F1" else lead
    v = ref_f_unit(target - x, m["attraction"])
    diff = x[None, :, :] - x[:, None, :]  # [i, j] = r_j - r_i
    dist = np.hypot(diff[..., 0], diff[..., 1])
    near = (dist < D) & ~np.eye(len(x), dtype=bool)
    w = np.where(near, ref_g(np.where(near, dist, 1.0), m["repulsion"]) / np.where(
        near, dist, 1.0), 0.0)
    return v + (w[..., None] * diff).sum(axis=1)


def ref_step(x, t, dt, m, p0, integrator):
    if integrator == "euler":
        return x + dt * ref_rates(x, t, m, p0)
    k1 = ref_rates(x, t, m, p0)
    k2 = ref_rates(x + 0.5 * dt * k1, t + 0.5 * dt, m, p0)
    k3 = ref_rates(x + 0.5 * dt * k2, t + 0.5 * dt, m, p0)
    k4 = ref_rates(x + dt * k3, t + dt, m, p0)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def explicit(shape, n, angle=0.0):
    return {"kind": "explicit", "offsets": named_offsets(shape, n, D, angle).tolist()}


STRAIGHT = {"kind": "straight", "target": [-40.0, -30.0], "speed": 6.0}
CASES = {
    "F1-linear-rotate": dict(
        attraction={"kind": "linear", "k": 1.5}, repulsion={"kind": "inverse", "k_g": 50.0},
        path=STRAIGHT, formation=explicit("wedge", 10),
        schedule=[{"start": 0.1, "end": 0.3, "rotate": 2.0}]),
    "F1-quadratic-morph": dict(
        attraction={"kind": "quadratic", "c": 0.05},
        repulsion={"kind": "inverse_square", "k_g": 400.0},
        path={"kind": "straight", "target": [60.0, 10.0], "arrival_time": 3.0},
        formation=explicit("circle", 10),
        schedule=[{"start": 0.0, "end": 0.25, "formation": explicit("hex", 10, 0.4),
                   "relaxation": "linear"}]),
    "F1-saturating": dict(
        attraction={"kind": "saturating", "k": 2.0, "v_max": 9.0},
        path={"kind": "straight", "target": [-40.0, -30.0], "speed": 4.0},
        formation=explicit("diamond", 10)),
    "F2-linear-stops": dict(
        design="F2", attraction={"kind": "linear", "k": 1.0},
        path={"kind": "straight", "target": [10.0, 12.0], "arrival_time": 0.2}),
    "F2-quadratic-rk4": dict(
        design="F2", attraction={"kind": "quadratic", "c": 0.02}, integrator="rk4",
        path=STRAIGHT),
    "F1-linear-rk4-rotate": dict(
        attraction={"kind": "linear", "k": 1.0}, integrator="rk4", path=STRAIGHT,
        formation=explicit("line", 10), schedule=[{"start": 0.05, "end": 0.25, "rotate": -1.0}]),
}


@pytest.mark.parametrize("name", list(CASES))
# Each case compiles kernels of its own (seconds): the fast lane keeps every case once, on
# one schedule (per_step: F2-linear-stops and F1-linear-rk4-rotate); --all runs both.
@pytest.mark.fast_cases("fused-F1-linear-rotate", "fused-F1-quadratic-morph", "fused-F1-saturating",
                        "per_step-F2-linear-stops", "per_step-F1-linear-rk4-rotate")
def test_matches_brute_force_step_by_step(path, name):
    m = CASES[name]
    sc = scenario(m, obs_every=40)
    result, sink = run(sc)
    assert result.status == "completed", result.error
    assert result.extra["engine_path"] == path
    full = sc.model.model_dump(mode="json")
    x = sink.pos[0].copy()
    p0 = x.mean(axis=0)
    iu = np.triu_indices(len(x), 1)
    for step in range(sc.time.steps):
        dist = np.hypot(*(x[:, None] - x[None]).transpose(2, 0, 1))[iu]
        assert (dist < D).sum() >= 5  # the repulsion is exercised at every step
        x = ref_step(x, step * sc.time.dt, sc.time.dt, full, p0, full["integrator"])
        scale = 1.0 + np.abs(x).max()
        assert np.abs(sink.pos[step + 1] - x).max() <= 1e-10 * scale, (name, step)


def test_observables_match_the_reference(path):
    """V1 (eq. 10), the formation error with the lag of eq. 8, speeds and the minimum
    distance, recomputed independently from the final frame."""
    m = dict(CASES["F1-linear-rotate"], schedule=[])
    sc = scenario(m, steps=30, arrays=("position", "velocity"))
    result, sink = run(sc)
    x, v = sink.pos[-1], sink.vel[-1]
    full = sc.model.model_dump(mode="json")
    p0 = sink.pos[0].mean(axis=0)
    t = sink.time[-1]
    np.testing.assert_allclose(v, ref_rates(x, t, full, p0), rtol=1e-10, atol=1e-10)
    q = np.array([-40.0, -30.0]) - p0
    q = 6.0 * q / np.hypot(*q)
    a = -q / 1.5  # eq. 8, linear f
    e = x - (ref_leader(t, full, p0) + ref_offsets(t, full) + a)
    dist = np.hypot(*(x[:, None] - x[None]).transpose(2, 0, 1))
    iu = np.triu_indices(len(x), 1)
    s = dist[iu][dist[iu] < D]
    pair = (50.0 * (np.log(D / s) + s / D - 1.0)).sum()
    V1 = (0.5 * 1.5 * (e**2).sum(axis=1)).sum() + pair
    f = result.final
    assert f["V1"] == pytest.approx(V1, rel=1e-9)
    assert pair > 0
    assert f["formation_error"] == pytest.approx(np.hypot(*e.T).mean(), rel=1e-9)
    assert f["lag"] == pytest.approx(6.0 / 1.5, rel=1e-12)
    assert f["min_distance"] == pytest.approx(dist[iu].min(), rel=1e-12)
    speeds = np.hypot(*v.T)
    assert f["speed_max"] == pytest.approx(speeds.max(), rel=1e-12)
    assert f["speed_error_max"] == pytest.approx(np.abs(speeds - 6.0).max(), rel=1e-12)
    assert f["centroid_distance"] == pytest.approx(
        np.hypot(*(x.mean(axis=0) - ref_leader(t, full, p0))), rel=1e-9)


# --- the paper's properties at small N ---------------------------------------------------


@pytest.mark.parametrize("sign, expected", [("eq8", 0.0), ("prop3.2", 2 * 3.0 / 2.0)])
@pytest.mark.slow_cases("per_step-eq8-0.0", "per_step-prop3.2-3.0")  # long runs; fused stays
def test_linear_f_settles_at_the_lag_of_eq8(path, sign, expected):
    """Constant-velocity leader, linear f: r_i - r_id -> a = -q/k (eq. 8); the lag_sign
    choice moves only the reference point of the formation error (to +q/k)."""
    q = np.array([3.0, 0.0])
    m = dict(attraction={"kind": "linear", "k": 2.0},
             path={"kind": "straight", "start": [25.0, 25.0], "target": [25.0 + 3.0 * 100, 25.0],
                   "speed": 3.0},
             formation=explicit("column", 4), lag_sign=sign)
    sc = scenario(m, N=4, steps=1200, every=1200, obs_every=100)
    result, sink = run(sc)
    t = sink.time[-1]
    b = named_offsets("column", 4, D)
    lag = sink.pos[-1] - (np.array([25.0, 25.0]) + q * t + b)
    np.testing.assert_allclose(lag, np.tile(-q / 2.0, (4, 1)), atol=1e-8)
    assert result.final["lag"] == pytest.approx(1.5)
    assert result.final["formation_error"] == pytest.approx(expected, abs=1e-8)
    assert result.final["velocity_mismatch_max"] < 1e-8


@pytest.mark.parametrize("design", ["F1", "F2"])
def test_linear_f_centroid_obeys_dc_dt(path, design):
    """Repulsion comes in opposite pairs and the offsets have mean zero, so with linear f the
    centroid follows dc/dt = k (r_0 - c) exactly; Euler: c' = c + dt k (p(t) - c)."""
    m = dict(design=design, attraction={"kind": "linear", "k": 0.8},
             repulsion={"kind": "inverse", "k_g": 200.0},
             path={"kind": "straight", "target": [-30.0, 20.0], "arrival_time": 0.3})
    if design == "F1":
        m["formation"] = explicit("hex", 40)
    sc = scenario(m, N=40, box=25.0, steps=60, every=0)
    result, _ = run(sc)
    o = result.observables
    c = np.stack([o["centroid_x"], o["centroid_y"]], axis=1)
    p = np.stack([o["leader_x"], o["leader_y"]], axis=1)
    assert o["degree_mean"].min() > 5  # the repulsion is busy
    predicted = c[:-1] + 0.01 * 0.8 * (p[:-1] - c[:-1])
    np.testing.assert_allclose(c[1:], predicted, rtol=0, atol=1e-11)


@pytest.mark.slow_cases("per_step-F1", "per_step-F2")
@pytest.mark.parametrize("design", ["F1", "F2"])
def test_lyapunov_never_increases_once_the_leader_is_still(path, design):
    m = dict(design=design, attraction={"kind": "quadratic", "c": 0.05},
             repulsion={"kind": "inverse", "k_g": 100.0},
             path={"kind": "straight", "target": [5.0, 5.0], "arrival_time": 0.5})
    if design == "F1":
        m["formation"] = {"kind": "named", "shape": "diamond"}
    sc = scenario(m, N=25, box=40.0, steps=400, every=0)
    o = run(sc)[0].observables
    V = o["V1" if design == "F1" else "V2"]
    still = o["time"] >= 0.5
    assert np.all(np.diff(V[still]) <= 1e-12 * np.abs(V[still][:-1]))
    assert V[still][-1] < 0.9 * V[still][0]  # and it does decrease


@pytest.mark.slow_cases("per_step")  # a long run; the fused twin stays fast
def test_rk4_is_far_more_accurate_than_euler(path):
    m = dict(design="F2", attraction={"kind": "linear", "k": 1.0},
             repulsion={"kind": "inverse", "k_g": 20.0}, path=STRAIGHT)
    finals = {}
    for integ, dt, steps in (("rk4", 0.0025, 400), ("rk4", 0.02, 50), ("euler", 0.02, 50)):
        sc = scenario(dict(m, integrator=integ), N=8, box=60.0, steps=steps, dt=dt,
                      every=steps, seed=9)
        finals[(integ, dt)] = run(sc)[1].pos[-1]
    truth = finals[("rk4", 0.0025)]
    err_rk4 = np.abs(finals[("rk4", 0.02)] - truth).max()
    err_euler = np.abs(finals[("euler", 0.02)] - truth).max()
    assert err_rk4 < 1e-3 * err_euler


def test_coincident_agents_stop_the_run_with_a_cause(path):
    sc = scenario({"design": "F2", "path": STRAIGHT},
                  positions=[[0.0, 0.0], [0.0, 0.0], [5.0, 1.0]], every=0)
    result, _ = run(sc)
    assert result.status == "diverged"
    assert result.error["step"] == 0 and "same position" in result.error["cause"]


def test_huge_dt_is_reported_as_divergence(path):
    sc = scenario({"design": "F2", "path": STRAIGHT, "attraction": {"kind": "quadratic"}},
                  N=30, dt=1e6, steps=50, every=0)
    result, _ = run(sc)
    assert result.status == "diverged"
    assert result.error["step"] < 50


# --- F2 formation properties D1-D3 -------------------------------------------------------


def ring(n, radius, center=(0.0, 0.0), start=0.0):
    a = start + 2 * np.pi * np.arange(n) / n
    return np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1) + center


def test_d3_connected_formation_around_the_leader():
    around = ring(6, 5.0)
    assert d3_holds(around, np.zeros(6, int), 1e-6)
    half = ring(6, 5.0)[[0, 1, 2]]  # angles 0, 60, 120 deg: all above a line through r^
    assert not d3_holds(half, np.zeros(3, int), 1e-6)
    # quasi-connected: two components, each around r^ (Definition 3.2)
    two = np.vstack([ring(4, 3.0), ring(5, 30.0, start=0.3)])
    assert d3_holds(two, np.r_[np.zeros(4, int), np.ones(5, int)], 1e-6)
    # one component around r^, one off to the side
    side = np.vstack([ring(4, 3.0), ring(5, 2.0, center=(40.0, 0.0))])
    assert not d3_holds(side, np.r_[np.zeros(4, int), np.ones(5, int)], 1e-6)
    # on one line through r^: both sides is a connected formation, one side is not
    line = np.array([[-5.0, 0.0], [5.0, 0.0], [10.0, 0.0]])
    assert d3_holds(line, np.zeros(3, int), 1e-6)
    assert not d3_holds(line[1:], np.zeros(2, int), 1e-6)
    # the agent at r^ alone is fine; an agent elsewhere alone is not
    assert d3_holds(np.array([[1e-9, 0.0]]), np.zeros(1, int), 1e-6)
    assert not d3_holds(np.array([[1.0, 0.0]]), np.zeros(1, int), 1e-6)


def test_d2_exempts_only_the_agent_at_the_leader():
    """The agent nearest r^, if within the tolerance, may lack a neighbour; the count
    follows it across blocks."""
    dist = np.array([5.0, 1e-4, 5.0, 70.0])

    def isolated(degree, blocks=((0, 4),), tol=0.2):
        d2 = Isolated(tol)
        for lo, hi in blocks:
            d2.add(dist[lo:hi], np.asarray(degree)[lo:hi])
        return d2.count()

    assert isolated([1, 0, 1, 0]) == 1
    assert isolated([1, 0, 1, 0], blocks=((0, 1), (1, 3), (3, 4))) == 1
    assert isolated([0, 1, 1, 1]) == 1
    assert isolated([1, 0, 1, 0], tol=1e-5) == 2  # nobody at r^: no exemption


def test_flatten_gives_every_node_its_root(taichi_cpu):
    import taichi as ti

    from flocklab.kernels.space.graph import flatten

    parent = ti.ndarray(ti.i32, shape=7)
    parent.from_numpy(np.array([0, 0, 1, 2, 4, 4, 5], dtype=np.int32))
    flatten(parent)
    assert parent.to_numpy().tolist() == [0, 0, 0, 0, 4, 4, 4]


# --- formations, schedule, paths --------------------------------------------------------


@pytest.mark.parametrize("shape", ["line", "column", "wedge", "diamond", "circle", "hex"])
def test_named_formations_meet_the_paper_conditions(shape):
    for n in [*range(1, 41), 64, 100, 257]:
        b = named_offsets(shape, n, D, 0.7)
        assert b.shape == (n, 2)
        assert np.abs(b.mean(axis=0)).max() < 1e-9 * D  # condition (1)
        if n == 1:
            continue
        dist = np.hypot(*(b[:, None] - b[None]).transpose(2, 0, 1))
        np.fill_diagonal(dist, np.inf)
        assert dist.min() >= D * (1 - 1e-12)  # no repulsion in the formation
        np.testing.assert_allclose(dist.min(axis=1), D, rtol=1e-12)  # condition (2)


def test_wedge_of_six_is_a_triangle_and_hex_of_seven_a_hexagon():
    w = named_offsets("wedge", 6, 1.0)
    assert sorted(np.round(w[:, 0] - w[:, 0].max(), 9).tolist()).count(0.0) == 1  # apex
    h = named_offsets("hex", 7, 1.0)
    assert np.allclose(np.sort(np.hypot(*h.T))[1:], 1.0)


def test_schedule_rotates_and_morphs_smoothly():
    a = NamedFormation(shape="wedge")
    changes = [FormationChange(start=8.0, end=12.0, rotate=math.pi / 2),
               FormationChange(start=15.0, end=15.0, formation=NamedFormation(shape="line")),
               FormationChange(start=20.0, end=22.0, rotate=math.pi, relaxation="linear")]
    sch = OffsetSchedule(a, changes, 6, D)
    b0 = named_offsets("wedge", 6, D)
    rot = np.array([[0.0, -1.0], [1.0, 0.0]])
    np.testing.assert_allclose(sch.at(7.0), b0)
    np.testing.assert_allclose(sch.at(10.0), b0 @ np.array(
        [[math.cos(math.pi / 4), -math.sin(math.pi / 4)],
         [math.sin(math.pi / 4), math.cos(math.pi / 4)]]).T, atol=1e-12)
    np.testing.assert_allclose(sch.at(12.0), b0 @ rot.T, atol=1e-12)
    np.testing.assert_allclose(sch.at(14.9), b0 @ rot.T, atol=1e-12)
    line = named_offsets("line", 6, D)
    np.testing.assert_allclose(sch.at(15.0), line)
    np.testing.assert_allclose(sch.at(21.0), line @ rot.T, atol=1e-12)  # half of 180 deg
    np.testing.assert_allclose(sch.at(30.0), -line, atol=1e-12)
    # smoothstep: the offsets start and end the rotation with zero velocity
    eps = 1e-6
    assert np.abs(sch.at(8.0 + eps) - sch.at(8.0)).max() < 1e-9
    assert np.abs(sch.at(12.0) - sch.at(12.0 - eps)).max() < 1e-9
    for t in np.linspace(0, 30, 61):
        assert np.abs(sch.at(t).mean(axis=0)).max() < 1e-9


def test_spline_path_passes_waypoints_at_constant_speed():
    spec = SplinePath(waypoints=[(0.0, -40.0), (-40.0, -20.0), (-60.0, -60.0)], speed=2.5)
    path = make_path(spec, np.array([25.0, 25.0]))
    pts = [(25.0, 25.0), *spec.waypoints]
    for s, pt in zip(path.cum, pts, strict=True):
        np.testing.assert_allclose(path.position(s / path.speed), pt, atol=1e-9)
    ts = np.linspace(0.0, path.arrival_time - 1e-9, 400)
    speeds = [np.hypot(*path.velocity(t)) for t in ts]
    np.testing.assert_allclose(speeds, 2.5, rtol=1e-12)
    h = 1e-5
    for t in ts[1:-1:17]:
        fd = (path.position(t + h) - path.position(t - h)) / (2 * h)
        np.testing.assert_allclose(fd, path.velocity(t), atol=1e-6)
    # arc length, not chord length: the curve is longer than the polyline
    assert path.length > sum(math.dist(a, b) for a, b in itertools.pairwise(pts))
    np.testing.assert_allclose(path.position(1e9), pts[-1])
    assert np.all(path.velocity(path.arrival_time) == 0.0)
    timed = make_path(SplinePath(waypoints=spec.waypoints, arrival_time=40.0),
                      np.array([25.0, 25.0]))
    assert timed.speed == pytest.approx(path.length / 40.0)


def test_straight_path_by_speed_or_arrival_time():
    from flocklab.schemas.formation import StraightPath

    a = make_path(StraightPath(target=(3.0, 4.0), speed=2.5), np.zeros(2))
    b = make_path(StraightPath(target=(3.0, 4.0), arrival_time=2.0), np.zeros(2))
    assert a.arrival_time == pytest.approx(2.0)
    np.testing.assert_allclose(a.position(1.0), b.position(1.0))
    np.testing.assert_allclose(a.velocity(1.0), [1.5, 2.0])
    np.testing.assert_allclose(a.position(5.0), [3.0, 4.0])
    assert np.all(a.velocity(2.0) == 0.0)


# --- validation ---------------------------------------------------------------------------

GOOD = {"design": "F1", "path": STRAIGHT, "formation": {"kind": "named", "shape": "hex"}}
BAD = [
    ({"design": "F2"}, "design F2 has no formation"),
    ({"formation": None}, "design F1 needs a formation"),
    ({"formation": {"kind": "explicit", "offsets": [[1.0, 0.0], [-1.0, 0.0]]}},
     "2 offsets, N = 10"),
    ({"formation": {"kind": "explicit", "offsets": [[1.0, 0.0], [0.0, 0.0]]}},
     "mean zero"),
    ({"path": {"kind": "straight", "target": [0, 0]}}, "exactly one of speed and arrival"),
    ({"path": {"kind": "straight", "target": [0, 0], "speed": 1, "arrival_time": 2}},
     "exactly one of speed and arrival"),
    ({"path": {"kind": "spline", "start": [0, 0], "waypoints": [[0, 0]], "speed": 1}},
     "coincide"),
    ({"schedule": [{"start": 5, "end": 4, "rotate": 1}]}, "before it starts"),
    ({"schedule": [{"start": 1, "end": 4}]}, "exactly one of rotate and formation"),
    ({"schedule": [{"start": 1, "end": 4, "rotate": 1}, {"start": 3, "end": 5, "rotate": 1}]},
     "before schedule[0] ends"),
    ({"attraction": {"kind": "saturating", "v_max": 5.0}}, "could never keep up"),
    ({"attraction": {"kind": "linear", "k": 0}}, "greater than 0"),
    ({"repulsion": {"kind": "inverse", "k_g": -1}}, "greater than 0"),
    ({"formation": {"kind": "named", "shape": "star"}}, "line"),
]


@pytest.mark.parametrize("change, fragment", BAD, ids=[b[1] for b in BAD])
def test_bad_models_are_rejected_clearly(change, fragment):
    with pytest.raises(ValidationError) as exc:
        scenario({**GOOD, **change})
    assert fragment in str(exc.value)


def test_bad_scenario_blocks_are_rejected_clearly():
    good = scenario(GOOD).model_dump(mode="json")
    periodic = dict(good, space={"kind": "periodic", "L": 100.0})
    periodic["initial"] = {"kind": "random", "N": 10}
    with pytest.raises(ValidationError, match="unbounded plane"):
        Scenario.model_validate(periodic)
    with pytest.raises(ValidationError, match="neighbours block"):
        Scenario.model_validate(dict(good, neighbours=None))


def test_saturating_leader_too_fast_at_run_time(path):
    m = {"design": "F2", "attraction": {"kind": "saturating", "v_max": 3.0},
         "path": {"kind": "straight", "target": [400.0, 0.0], "arrival_time": 10.0}}
    with pytest.raises(ValueError, match="could never keep up"):
        kernels.run(scenario(m))


# --- the dense regime ---------------------------------------------------------------------


def test_dense_regime_caps_work_and_stays_close_to_exact(taichi_cpu):
    """5000 agents in a disc of radius 60 (about 480 neighbours each): above the cap the
    step coarse-grains far sub-cells; the repulsion stays within a few % of the exact sum."""
    rates = {}
    for cap in (None, 256):
        sc = Scenario.model_validate({
            "model": {"kind": "formation", "design": "F2", "max_exact_candidates": cap,
                      "path": {"kind": "straight", "start": [0.0, 0.0], "target": [0.0, 0.0],
                               "speed": 1.0}},
            "space": {"kind": "plane"}, "neighbours": {"radius": D},
            "initial": {"kind": "random", "N": 5000, "region": {"kind": "disc", "radius": 60.0}},
            "time": {"steps": 1, "dt": 1e-6}, "recording": {"every": 1}, "seed": 3})
        result, sink = run(sc)
        regime = result.extra["dense_regime"]
        assert (regime["steps"] > 0) == (cap is not None)
        x = sink.pos[0]
        rates[cap] = (sink.pos[1] - x) / 1e-6 + x  # minus the attraction -k (x - 0), k = 1
    exact, coarse = rates[None], rates[256]
    assert regime["max_reach"] >= 2
    scale = np.sqrt((np.hypot(*exact.T) ** 2).mean())
    assert scale > 100.0
    err = np.sqrt((np.hypot(*(coarse - exact).T) ** 2).mean())
    assert 1e-6 * scale < err < 0.03 * scale
