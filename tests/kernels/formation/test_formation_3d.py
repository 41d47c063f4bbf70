"""M4 (Xi–Abed) in 3D: F1 and F2 against the brute-force numpy reference step by step, the
paper's properties in 3D (the lag of eq. 8, the centroid law, V1/V2 non-increasing, an F2
formation with D1-D3), the 3D formations and paths, and validation."""

import copy
import json
import math

import h5py
import numpy as np
import pytest
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from flocklab import kernels
from flocklab.kernels.models.formation.path import make_path
from flocklab.kernels.models.formation.props import d3_holds_3d, surrounds_3d
from flocklab.kernels.models.formation.schedule import OffsetSchedule
from flocklab.kernels.models.formation.shapes import named_offsets
from flocklab.schemas import Scenario, field_errors
from flocklab.schemas.formation import FormationChange, NamedFormation, SplinePath
from tests.reference import formation_step
from tests.service.cli.test_cli import flocklab

D = 20.0
BOX = {"kind": "box", "low": [0.0, 0.0, 0.0], "high": [30.0, 30.0, 30.0]}
STRAIGHT = {"kind": "straight", "target": [-40.0, -30.0, 25.0], "speed": 6.0}


class Frames:
    """A FrameSink keeping every frame (small runs only)."""

    def __init__(self):
        self.time, self.pos, self.vel = [], [], []

    def frame(self, step, time, arrays):
        self.time.append(time)
        self.pos.append(arrays["position"])
        self.vel.append(arrays.get("velocity"))


def doc(model, *, N=12, steps=30, dt=0.01, every=1, obs_every=1, seed=5, region=BOX,
        positions=None) -> dict:
    init = ({"kind": "explicit", "positions": positions} if positions is not None else
            {"kind": "random", "N": N, "region": region})
    return {
        "model": {"kind": "formation", **model},
        "space": {"kind": "plane", "dimension": 3},
        "neighbours": {"radius": D},
        "initial": init,
        "time": {"steps": steps, "dt": dt},
        "recording": {"every": every, "arrays": ["position", "velocity"],
                      "observables_every": obs_every},
        "seed": seed,
    }


def run(spec: dict):
    sc = Scenario.model_validate(spec)
    sink = Frames()
    result = kernels.run(sc, sink=sink)
    return sc, result, sink


def explicit(shape, n, angle=0.0):
    return {"kind": "explicit", "offsets": named_offsets(shape, n, D, angle, 3).tolist()}


# --- the reference's leader and offsets (straight path, at most one change) ---------------


def ref_leader(t, m, p0):
    target = np.asarray(m["path"]["target"])
    T = m["path"].get("arrival_time") or np.linalg.norm(target - p0) / m["path"]["speed"]
    return p0 + min(t / T, 1.0) * (target - p0)


def ref_offsets(t, m):
    b0 = np.asarray(m["formation"]["offsets"], dtype=float)
    if not m.get("schedule"):
        return b0
    c = m["schedule"][0]
    u = min(max((t - c["start"]) / (c["end"] - c["start"]), 0.0), 1.0)
    s = u if c.get("relaxation") == "linear" else 3 * u * u - 2 * u**3
    if c.get("rotate") is not None:
        axis = np.asarray(c.get("axis") or [0.0, 0.0, 1.0], dtype=float)
        rot = Rotation.from_rotvec(s * c["rotate"] * axis / np.linalg.norm(axis))
        return rot.apply(b0)
    return (1 - s) * b0 + s * np.asarray(c["formation"]["offsets"], dtype=float)


def targets(m, p0):
    """l(t) of every agent: the leader (F2) or the leader plus the offsets (F1)."""
    if m.get("design", "F1") == "F2":
        return lambda t: ref_leader(t, m, p0)[None, :]
    return lambda t: ref_leader(t, m, p0) + ref_offsets(t, m)


CASES = {
    "F1-linear-rotate-axis": dict(
        attraction={"kind": "linear", "k": 1.5}, repulsion={"kind": "inverse", "k_g": 50.0},
        path=STRAIGHT, formation=explicit("shell", 12),
        schedule=[{"start": 0.05, "end": 0.25, "rotate": 2.0, "axis": [1.0, 2.0, 3.0]}]),
    "F1-quadratic-morph-cube-to-shell": dict(
        attraction={"kind": "quadratic", "c": 0.05},
        repulsion={"kind": "inverse_square", "k_g": 400.0},
        path={"kind": "straight", "target": [60.0, 10.0, -20.0], "arrival_time": 3.0},
        formation=explicit("cube", 12),
        schedule=[{"start": 0.0, "end": 0.2, "formation": explicit("shell", 12, 0.4),
                   "relaxation": "linear"}]),
    "F1-saturating-rotate-z": dict(
        attraction={"kind": "saturating", "k": 2.0, "v_max": 9.0}, path=STRAIGHT,
        formation=explicit("hex", 12), schedule=[{"start": 0.1, "end": 0.2, "rotate": -1.0}]),
    "F2-linear-stops": dict(
        design="F2", attraction={"kind": "linear", "k": 1.0},
        path={"kind": "straight", "target": [10.0, 12.0, 14.0], "arrival_time": 0.2}),
    "F2-quadratic-rk4": dict(
        design="F2", attraction={"kind": "quadratic", "c": 0.02}, integrator="rk4",
        path=STRAIGHT),
    "F1-linear-rk4-rotate": dict(
        attraction={"kind": "linear", "k": 1.0}, integrator="rk4", path=STRAIGHT,
        formation=explicit("cube", 12),
        schedule=[{"start": 0.05, "end": 0.25, "rotate": 1.0, "axis": [0.0, 1.0, 0.0]}]),
}


@pytest.mark.parametrize("name", list(CASES))
# F2-quadratic-rk4 takes minutes in 3D (it stays fast in 2D, test_formation.py); each other
# case stays fast once, on one schedule (3D kernels compile for seconds); --all runs both.
@pytest.mark.fast_cases("fused-F1-quadratic-morph-cube-to-shell", "fused-F1-saturating-rotate-z",
                        "per_step-F2-linear-stops", "per_step-F1-linear-rk4-rotate")
def test_matches_brute_force_step_by_step(path, name):
    sc, result, sink = run(doc(CASES[name]))
    assert result.status == "completed", result.error
    assert result.extra["engine_path"] == path
    m = sc.model.model_dump(mode="json")
    x = sink.pos[0].copy()
    assert x.shape == (12, 3)
    at = targets(m, x.mean(axis=0))
    iu = np.triu_indices(len(x), 1)
    kw = dict(f=m["attraction"], g=m["repulsion"], d=D, integrator=m["integrator"])
    for step in range(sc.time.steps):
        dist = np.linalg.norm(x[:, None] - x[None], axis=2)[iu]
        assert (dist < D).sum() >= 5  # the repulsion is exercised at every step
        x = formation_step(x, step * sc.time.dt, sc.time.dt, at, **kw)
        scale = 1.0 + np.abs(x).max()
        assert np.abs(sink.pos[step + 1] - x).max() <= 1e-10 * scale, (name, step)


def test_observables_match_the_reference(path):
    """V1, the formation error with the lag of eq. 8, the speeds, the minimum distance and
    the z components, recomputed from the final frame."""
    m = dict(CASES["F1-linear-rotate-axis"], schedule=[])
    sc, result, sink = run(doc(m, steps=30))
    assert result.extra["engine_path"] == path
    x, v = sink.pos[-1], sink.vel[-1]
    full = sc.model.model_dump(mode="json")
    p0 = sink.pos[0].mean(axis=0)
    t = sink.time[-1]
    from tests.reference import formation_rates

    lead = ref_leader(t, full, p0)
    np.testing.assert_allclose(
        v, formation_rates(x, lead + ref_offsets(t, full), f=full["attraction"],
                           g=full["repulsion"], d=D), rtol=1e-10, atol=1e-10)
    q = np.asarray(STRAIGHT["target"]) - p0
    q = 6.0 * q / np.linalg.norm(q)
    e = x - (lead + ref_offsets(t, full) - q / 1.5)  # eq. 8's lag, linear f
    dist = np.linalg.norm(x[:, None] - x[None], axis=2)
    iu = np.triu_indices(len(x), 1)
    s = dist[iu][dist[iu] < D]
    V1 = (0.75 * (e**2).sum(axis=1)).sum() + (50.0 * (np.log(D / s) + s / D - 1.0)).sum()
    f = result.final
    assert f["V1"] == pytest.approx(V1, rel=1e-9) and len(s) > 0
    assert f["formation_error"] == pytest.approx(np.linalg.norm(e, axis=1).mean(), rel=1e-9)
    assert f["min_distance"] == pytest.approx(dist[iu].min(), rel=1e-12)
    speeds = np.linalg.norm(v, axis=1)
    assert f["speed_max"] == pytest.approx(speeds.max(), rel=1e-12)
    assert f["velocity_mismatch_max"] == pytest.approx(
        np.linalg.norm(v - q, axis=1).max(), rel=1e-12)
    c = x.mean(axis=0)
    assert (f["leader_z"], f["centroid_z"]) == pytest.approx((lead[2], c[2]), rel=1e-12)
    assert f["centroid_distance"] == pytest.approx(np.linalg.norm(c - lead), rel=1e-9)


# --- the paper's properties in 3D ---------------------------------------------------------


def test_linear_f_settles_at_the_lag_of_eq8_in_formation(taichi_cpu):
    """A cube formation behind a leader of constant 3D velocity q: r_i - r_id -> a = -q/k."""
    q = np.array([2.0, -1.0, 2.0])  # |q| = 3
    start = np.array([25.0, 25.0, 25.0])
    m = dict(attraction={"kind": "linear", "k": 2.0},
             path={"kind": "straight", "start": start.tolist(),
                   "target": (start + 100 * q).tolist(), "speed": 3.0},
             formation={"kind": "named", "shape": "cube"})
    _, result, sink = run(doc(m, N=8, steps=1200, every=1200, obs_every=100,
                               region={"kind": "ball", "center": [25.0, 25.0, 25.0],
                                       "radius": 30.0}))
    t = sink.time[-1]
    b = named_offsets("cube", 8, D, dim=3)
    lag = sink.pos[-1] - (start + q * t + b)
    np.testing.assert_allclose(lag, np.tile(-q / 2.0, (8, 1)), atol=1e-8)
    assert result.final["lag"] == pytest.approx(1.5)
    assert result.final["formation_error"] == pytest.approx(0.0, abs=1e-8)
    assert result.final["velocity_mismatch_max"] < 1e-8


@pytest.mark.parametrize("design", ["F1", "F2"])
def test_linear_f_centroid_obeys_dc_dt(taichi_cpu, design):
    """Pairwise repulsion cancels and the offsets have mean zero: with linear f, Euler's
    centroid is c' = c + dt k (p(t) - c), in every component."""
    m = dict(design=design, attraction={"kind": "linear", "k": 0.8},
             repulsion={"kind": "inverse", "k_g": 200.0},
             path={"kind": "straight", "target": [-30.0, 20.0, 10.0], "arrival_time": 0.3})
    if design == "F1":
        m["formation"] = {"kind": "named", "shape": "shell"}
    _, result, _ = run(doc(m, N=40, steps=60, every=0))
    o = result.observables
    c = np.stack([o["centroid_x"], o["centroid_y"], o["centroid_z"]], axis=1)
    p = np.stack([o["leader_x"], o["leader_y"], o["leader_z"]], axis=1)
    assert o["degree_mean"].min() > 5  # the repulsion is busy
    np.testing.assert_allclose(c[1:], c[:-1] + 0.01 * 0.8 * (p[:-1] - c[:-1]), atol=1e-11)


@pytest.mark.parametrize("design", ["F1", "F2"])
def test_lyapunov_never_increases_once_the_leader_is_still(taichi_cpu, design):
    m = dict(design=design, attraction={"kind": "quadratic", "c": 0.05},
             path={"kind": "straight", "target": [5.0, 5.0, 5.0], "arrival_time": 0.5})
    if design == "F1":
        m["formation"] = {"kind": "named", "shape": "cube"}
    _, result, _ = run(doc(m, N=27, steps=400, every=0, region={
        "kind": "box", "low": [0.0, 0.0, 0.0], "high": [40.0, 40.0, 40.0]}))
    o = result.observables
    V = o["V1" if design == "F1" else "V2"]
    still = o["time"] >= 0.5
    assert np.all(np.diff(V[still]) <= 1e-12 * np.abs(V[still][:-1]))
    assert V[still][-1] < 0.9 * V[still][0]  # and it does decrease


def test_f2_ends_in_an_f2_formation_in_3d(taichi_cpu):
    """Xi–Abed's Simulation 3 in a cube: 60 agents, one leader stopping at the target; the
    group ends in an F2 formation around it (D1-D3), one component, V2 settled."""
    m = dict(design="F2", attraction={"kind": "linear", "k": 1.0},
             path={"kind": "straight", "target": [-40.0, -40.0, -40.0], "arrival_time": 20.0})
    _, result, _ = run(doc(m, N=60, steps=3000, dt=0.01, every=0, obs_every=50, seed=3,
                           region={"kind": "box", "low": [0.0, 0.0, 0.0],
                                   "high": [50.0, 50.0, 50.0]}))
    assert result.status == "completed", result.error
    f = result.final
    assert (f["D1"], f["D2"], f["D3"], f["components"]) == (1.0, 1.0, 1.0, 1.0)
    assert f["centroid_distance"] < 0.5 and f["min_distance"] > 1.0
    V = result.observables["V2"][result.observables["time"] >= 20.0]
    assert np.all(np.diff(V) <= 1e-12 * V[:-1])


def test_d3_in_3d_is_the_plane_condition():
    tetra = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    assert surrounds_3d(tetra / np.sqrt(3))
    assert not surrounds_3d(np.abs(tetra) / np.sqrt(3))  # one octant: a plane cuts off all
    assert surrounds_3d(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]))  # a line, both sides
    square = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], dtype=float)
    assert surrounds_3d(square)  # in a plane through r^, around it
    assert not surrounds_3d(square[:3])  # a half-plane: the plane y = 0 has one side only
    rel = np.concatenate([2 * tetra, 3 * tetra + 10.0, [[0.0, 0.0, 0.0]]])
    labels = np.array([0] * 4 + [1] * 4 + [2])
    assert not d3_holds_3d(rel, labels, 0.1)  # the second group is off to one side
    assert d3_holds_3d(rel, np.array([0] * 8 + [2]), 0.1)  # joined: around r^; r^ exempt


# --- formations, schedule and paths in 3D --------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 7, 8, 12, 27, 50, 64, 100])
def test_cube_and_shell_meet_the_paper_conditions(n):
    cube, shell = (named_offsets(s, n, D, 0.3, 3) for s in ("cube", "shell"))
    for b in (cube, shell):
        assert b.shape == (n, 3)
        assert np.abs(b.mean(axis=0)).max() < 1e-9 * D  # condition (1)
    if n == 1:
        return
    for b in (cube, shell):
        dist = np.linalg.norm(b[:, None] - b[None], axis=2)
        np.fill_diagonal(dist, np.inf)
        assert dist.min() == pytest.approx(D, rel=1e-12)  # no repulsion in formation
    dist = np.linalg.norm(cube[:, None] - cube[None], axis=2)
    np.fill_diagonal(dist, np.inf)
    np.testing.assert_allclose(dist.min(axis=1), D, rtol=1e-12)  # condition (2)
    r = np.linalg.norm(shell, axis=1)
    if n >= 7:  # a shell: every point at nearly the same radius from the centre
        assert r.std() < 0.05 * r.mean()


def test_plane_shapes_lie_in_the_xy_plane_in_3d():
    b2, b3 = named_offsets("wedge", 6, D, 0.5), named_offsets("wedge", 6, D, 0.5, 3)
    np.testing.assert_array_equal(b3[:, :2], b2)
    assert np.all(b3[:, 2] == 0.0)


def test_schedule_rotates_about_an_axis_and_morphs():
    changes = [FormationChange(start=1.0, end=2.0, rotate=math.pi / 2, axis=(1.0, 0.0, 0.0)),
               FormationChange(start=3.0, end=4.0, formation=NamedFormation(shape="cube"),
                               relaxation="linear")]
    sch = OffsetSchedule(NamedFormation(shape="shell"), changes, 8, D, 3)
    shell, cube = named_offsets("shell", 8, D, dim=3), named_offsets("cube", 8, D, dim=3)
    turned = shell[:, [0, 2, 1]] * np.array([1.0, -1.0, 1.0])  # (x, -z, y): 90 deg about x
    np.testing.assert_allclose(sch.at(0.5), shell)
    np.testing.assert_allclose(sch.at(2.5), turned, atol=1e-12)
    np.testing.assert_allclose(sch.at(3.5), 0.5 * turned + 0.5 * cube, atol=1e-12)
    np.testing.assert_allclose(sch.at(9.0), cube, atol=1e-12)
    half = Rotation.from_rotvec([math.pi / 4, 0.0, 0.0]).apply(shell)
    np.testing.assert_allclose(sch.at(1.5), half, atol=1e-12)  # smoothstep at u = 1/2


def test_spline_through_3d_waypoints_is_arc_length_timed():
    """A curved 3D path: a spline through points of a helix, at constant speed."""
    ang = np.linspace(0.0, 3 * np.pi, 10)[1:]
    pts = [(20 * math.cos(a), 20 * math.sin(a), 5.0 * a) for a in ang]
    path = make_path(SplinePath(waypoints=pts, speed=4.0), np.array([20.0, 0.0, 0.0]))
    for s, pt in zip(path.cum, [(20.0, 0.0, 0.0), *pts], strict=True):
        np.testing.assert_allclose(path.position(s / path.speed), pt, atol=1e-9)
    ts = np.linspace(0.0, path.arrival_time - 1e-9, 200)
    np.testing.assert_allclose([np.linalg.norm(path.velocity(t)) for t in ts], 4.0,
                               rtol=1e-12)
    h = 1e-5
    for t in ts[1:-1:13]:
        fd = (path.position(t + h) - path.position(t - h)) / (2 * h)
        np.testing.assert_allclose(fd, path.velocity(t), atol=1e-6)
    assert np.all(path.velocity(path.arrival_time + 1.0) == np.zeros(3))
    assert path.position(1e9).shape == (3,)


# --- validation -----------------------------------------------------------------------------


def field_errors_of(spec: dict) -> list[tuple[str, str]]:
    with pytest.raises(ValidationError) as exc:
        Scenario.model_validate(spec)
    return [(f.loc, f.msg) for f in field_errors(exc.value)]


@pytest.mark.parametrize("formation", [
    {"kind": "named", "shape": "cube"},
    {"kind": "named", "shape": "shell", "orientation": 1.0},
    {"kind": "named", "shape": "hex"},
    {"kind": "explicit", "offsets": [[1.0, 0.0, 2.0], [-1.0, 0.0, -2.0]]},
])
def test_3d_formations_validate(formation):
    m = {"formation": formation, "path": STRAIGHT}
    sc = Scenario.model_validate(doc(m, N=2))
    assert sc.dimension == 3 and sc.model.formation.kind == formation["kind"]


def test_two_column_offsets_in_3d_are_refused_clearly():
    m = {"formation": {"kind": "explicit", "offsets": [[1.0, 0.0], [-1.0, 0.0]]},
         "path": STRAIGHT}
    (loc, msg), = field_errors_of(doc(m, N=2))
    assert loc == "model"
    assert "formation.offsets have 2 columns" in msg and "space.dimension = 3" in msg


@pytest.mark.parametrize("change, loc, words", [
    (lambda d: d["model"]["path"].update(target=[1.0, 2.0]), "model",
     "path.target has 2 coordinates; space.dimension is 3"),
    (lambda d: d["model"]["path"].update(start=[0.0, 0.0]), "model", "path.start has 2"),
    (lambda d: d["model"]["formation"].update(offsets=[[1.0, 0.0, 0.0], [-1.0, 0.0]]),
     "model.formation", "offsets[1] has 2"),
    (lambda d: d["model"]["formation"].update(offsets=[[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
     "model.formation", "mean zero"),
    (lambda d: d["model"]["schedule"].append({"start": 1.0, "end": 2.0, "rotate": 1.0,
                                               "axis": [0.0, 0.0, 0.0]}),
     "model.schedule.0", "zero vector"),
    (lambda d: d["model"]["schedule"].append({"start": 1.0, "end": 2.0, "axis": [0, 0, 1],
                                               "formation": {"kind": "named",
                                                             "shape": "cube"}}),
     "model.schedule.0", "axis applies only to a rotation"),
])
def test_bad_3d_models_name_their_field(change, loc, words):
    spec = doc({"formation": {"kind": "explicit", "offsets": [[1.0, 0.0, 0.0],
                                                              [-1.0, 0.0, 0.0]]},
                "path": copy.deepcopy(STRAIGHT), "schedule": []}, N=2)
    change(spec)
    (got_loc, msg), = field_errors_of(spec)
    assert got_loc == loc and words in msg, (got_loc, msg)


@pytest.mark.parametrize("model, words", [
    ({"formation": {"kind": "named", "shape": "shell"}},
     "shape 'shell' is a 3D formation and runs in 3D only; space.dimension is 2"),
    ({"formation": {"kind": "named", "shape": "line"},
      "schedule": [{"start": 0.0, "end": 1.0, "rotate": 1.0, "axis": [1.0, 0.0, 0.0]}]},
     "schedule[0].axis is 3D only"),
])
def test_3d_only_parts_are_refused_in_2d(model, words):
    spec = doc({**model, "path": {"kind": "straight", "target": [1.0, 2.0], "speed": 1.0}})
    spec["space"] = {"kind": "plane"}
    spec["initial"]["region"] = {"kind": "box", "low": [0.0, 0.0], "high": [1.0, 1.0]}
    (loc, msg), = field_errors_of(spec)
    assert loc == "model" and words in msg, msg


# --- the command line, outputs, preset and example ----------------------------------------


@pytest.mark.slow
def test_run_writes_a_3d_formation_trajectory(tmp_path):
    spec = doc({"formation": {"kind": "named", "shape": "shell"}, "path": STRAIGHT},
               N=10, steps=20, every=10, obs_every=10)
    path = tmp_path / "s.json"
    path.write_text(json.dumps(spec))
    out = tmp_path / "out"
    proc = flocklab("run", str(path), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and "centroid_z" in summary["final"]
    with h5py.File(out / "trajectory.h5") as f:
        assert f["particles/swarm/box"].attrs["dimension"] == 3
        assert f["particles/swarm/position/value"].shape == (3, 10, 3)
        assert f["particles/swarm/velocity/value"].shape == (3, 10, 3)
    bad = copy.deepcopy(spec)
    bad["model"]["formation"] = {"kind": "explicit", "offsets": [[0.0, 0.0]] * 10}
    path.write_text(json.dumps(bad))
    proc = flocklab("validate", str(path))
    assert proc.returncode == 2 and "2 columns" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_models_command_lists_dimension_3_for_formation():
    proc = flocklab("models", "formation")
    assert proc.returncode == 0 and "dimensions: 2, 3" in proc.stdout
    js = json.loads(flocklab("models", "--json").stdout)
    assert {m["kind"]: m["dimensions"] for m in js if "dimensions" in m}["formation"] == [2, 3]


def test_the_3d_example_is_the_preset_and_keeps_its_shell(taichi_cpu):
    from pathlib import Path

    from flocklab.schemas import get_preset

    text = (Path(__file__).resolve().parents[3] / "examples" / "formation_3d.json").read_text()
    sc = Scenario.model_validate_json(text)
    assert sc == get_preset("xi-abed-f1-3d") and sc.dimension == 3
    short = sc.model_copy(update={"time": sc.time.model_copy(update={"steps": 700})})
    result = kernels.run(short)
    assert result.status == "completed"
    f = result.final
    # On the curve the lag behind each leader turns with q, but every agent is off its
    # leader by about the same vector: the shell is kept (before the turn at 8 s).
    assert f["formation_error_max"] - f["formation_error"] < 0.1
    assert f["min_distance"] > 0.99 * D


@pytest.mark.slow
def test_d3_in_3d_scales_to_large_components():
    # One component of 2 x 10^5 directions spread over the sphere surrounds r^; cut by the
    # plane z = 0 it does not; 10^5 lone agents do not. (The primal LP needed a K x K matrix.)
    rng = np.random.default_rng(5)
    u = rng.normal(size=(200_000, 3))
    one = np.zeros(len(u), dtype=np.int64)
    assert d3_holds_3d(u, one, 1e-6)
    assert not d3_holds_3d(np.abs(u), one, 1e-6)  # one octant
    half = u.copy()
    half[:, 2] = np.abs(half[:, 2])
    assert not d3_holds_3d(half, one, 1e-6)
    assert not d3_holds_3d(u[:100_000], np.arange(100_000), 1e-6)
