"""Per-agent derived arrays in the frames (recording.arrays "degree" and "radius"): equal
to a brute-force count at every frame, ties at r included, and to the observables' own
statistics; written to H5MD as (F, N) datasets; refused where a model has none."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import h5py
import numpy as np
import pytest
from pydantic import ValidationError

from flocklab import kernels
from flocklab.schemas import Scenario, field_errors, get_preset
from flocklab.service.h5md import H5MDWriter
from tests.kernels.flocking.test_flocking_reference import m2_scenario, m3_scenario
from tests.reference import degrees, degrees_per_agent_radius


class Frames:
    """A FrameSink keeping every frame (small runs only)."""

    def __init__(self):
        self.steps: list[int] = []
        self.frames: list[dict[str, np.ndarray]] = []

    def frame(self, step, time, arrays):
        self.steps.append(step)
        self.frames.append({k: np.array(v) for k, v in arrays.items()})


def recording(sc: Scenario, arrays: list[str], every: int = 1, **extra) -> Scenario:
    """`sc` recording `arrays` every `every` steps, observed at every step."""
    doc = sc.model_dump(mode="json")
    doc["recording"] = {**doc["recording"], "every": every, "arrays": arrays,
                        "observables_every": 1, **extra}
    return Scenario.model_validate(doc)


def run(sc: Scenario, path: str = "auto"):
    sink = Frames()
    result = kernels.run(sc, sink=sink, path=path)
    assert result.status == "completed", result.error
    return result, sink


def vicsek(N=60, L=6.0, r=1.0, eta=0.6, steps=12, dim=2, inclusive=None, v0=0.1,
           initial=None, rule="vicsek") -> Scenario:
    space = ({"kind": "periodic", "L": L} if L else {"kind": "plane"}) | {"dimension": dim}
    init = initial or {"kind": "random", "N": N}
    if not L and initial is None:
        init["region"] = {"kind": "box", "low": [0.0] * dim, "high": [4.0] * dim}
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": rule, "v0": v0, "eta": eta},
        "space": space, "neighbours": {"radius": r, "inclusive": inclusive},
        "initial": init, "time": {"steps": steps}, "seed": 3,
        "recording": {"every": 1, "arrays": ["position", "degree"], "observables_every": 1},
    })


def assert_stats(result, sink, prefix: str, name: str) -> None:
    """The recorded array's mean, min and max at every frame are the observables'."""
    steps = list(result.observables["step"])
    for step, f in zip(sink.steps, sink.frames, strict=True):
        row = steps.index(step)
        got = {s: result.observables[f"{prefix}_{s}"][row] for s in ("mean", "min", "max")}
        assert (got["min"], got["max"]) == (f[name].min(), f[name].max()), step
        # The observable sums in storage order and float64, the frame is in id order.
        want = f[name].astype(np.float64).mean()
        assert got["mean"] == pytest.approx(want, rel=1e-13, abs=0), step


def lattice_points(dim: int, side: int) -> list[list[float]]:
    """Integer lattice points: every neighbour distance is exactly 1, sqrt 2, ... so a
    radius of 1 puts each agent's axis neighbours exactly at r, in any arithmetic."""
    axes = np.meshgrid(*[np.arange(side, dtype=float)] * dim, indexing="ij")
    return np.stack(axes, -1).reshape(-1, dim).tolist()


@pytest.mark.parametrize("L", [5.0, None], ids=["periodic", "plane"])
@pytest.mark.parametrize("dim,rule", [(2, "vicsek"), (2, "average"), (3, "vicsek")])
def test_vicsek_degree_is_the_brute_force_count(taichi_cpu, dim, L, rule):
    sc = vicsek(N=70, L=L, dim=dim, rule=rule, eta=0.6 if rule == "vicsek" else 0.0)
    result, sink = run(sc)
    assert result.extra["engine_path"] == "per_step"  # derived arrays: the per-step path
    assert sink.steps == list(range(sc.time.steps + 1))
    for f in sink.frames:
        assert f["degree"].dtype == np.int32 and f["degree"].shape == (sc.n_agents,)
        np.testing.assert_array_equal(f["degree"], degrees(f["position"], 1.0, L, True))
    assert_stats(result, sink, "degree", "degree")
    assert result.observables["degree_max"].max() > 0  # something to count


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("inclusive", [True, False])
@pytest.mark.parametrize("L", [4.0, None], ids=["periodic", "plane"])
def test_vicsek_degree_ties_at_r(taichi_cpu, dim, inclusive, L):
    """Frozen agents (v0 = 0) on the integer lattice, r = 1: each has 2 dim neighbours
    exactly at r (the lattice wraps in the box of side 4), counted only by <=."""
    side = 4 if L else 3
    pts = lattice_points(dim, side)
    init = {"kind": "explicit", "positions": pts}
    if dim == 2:
        init["headings"] = [0.0] * len(pts)
    else:
        init["velocities"] = [[1.0, 0.0, 0.0]] * len(pts)
    sc = vicsek(L=L, dim=dim, inclusive=inclusive, v0=0.0, eta=0.0, steps=2, initial=init)
    result, sink = run(sc)
    want = degrees(np.array(pts), 1.0, L, inclusive)
    if L and inclusive:
        assert (want == 2 * dim).all()
    if not inclusive:
        assert (want == 0).all()
    for f in sink.frames:
        np.testing.assert_array_equal(f["degree"], want)
    assert_stats(result, sink, "degree", "degree")


@pytest.mark.parametrize("case", [
    dict(search="all_pairs"), dict(search="grid"),
    dict(search="grid", inclusive=True), dict(search="grid", integrator="rk4"),
], ids=lambda c: "-".join(str(v) for v in c.values()))
def test_switching_degree_is_the_brute_force_count(taichi_cpu, case):
    inclusive = case.get("inclusive") or False
    sc = recording(m2_scenario(n=30, steps=40, R=2.0, **case), ["position", "degree"], 4)
    result, sink = run(sc)
    assert result.extra["engine_path"] == "per_step"
    assert sink.steps == [*range(0, 41, 4)]
    for f in sink.frames:
        np.testing.assert_array_equal(f["degree"], degrees(f["position"], 2.0, None,
                                                           inclusive))
    assert_stats(result, sink, "valency", "degree")


def test_switching_degree_ties_at_R(taichi_cpu):
    """The first frame of agents on the integer lattice with R = 1 (< by default, paper 000):
    no agent has a neighbour; with inclusive <= the axis neighbours count."""
    pts = lattice_points(2, 4)
    for inclusive, want in ((None, 0), (True, degrees(np.array(pts), 1.0, None, True))):
        sc = Scenario.model_validate({
            "model": {"kind": "flocking", "topology": "switching",
                      "potential": {"kind": "log_barrier", "d": 0.5}},
            "space": {"kind": "plane"}, "neighbours": {"radius": 1.0, "inclusive": inclusive},
            "initial": {"kind": "explicit", "positions": pts,
                        "velocities": [[0.0, 0.0]] * len(pts)},
            "time": {"steps": 1, "dt": 0.01},
            "recording": {"every": 1, "arrays": ["degree"], "observables_every": 1},
        })
        result, sink = run(sc)
        np.testing.assert_array_equal(sink.frames[0]["degree"], want)
        assert result.observables["valency_max"][0] == np.max(want)


@pytest.mark.parametrize("graph,want", [
    ({"kind": "ring"}, [2] * 12),
    ({"kind": "edges", "edges": [[0, 1], [0, 2], [0, 3], [4, 5]]},
     [3, 1, 1, 1, 1, 1] + [0] * 6),
])
def test_fixed_degree_is_the_graphs(taichi_cpu, graph, want):
    sc = recording(m2_scenario(topology="fixed", n=12, steps=6, graph=graph),
                   ["velocity", "degree"], 3)
    result, sink = run(sc)
    assert sink.steps == [0, 3, 6]
    for f in sink.frames:
        np.testing.assert_array_equal(f["degree"], want)
        assert set(f) == {"velocity", "degree"}
    assert_stats(result, sink, "valency", "degree")


@pytest.mark.parametrize("rule", ["own", "min"])
def test_obstacles_radius_and_degree(taichi_cpu, rule):
    """M3's adaptive radii differ by the end of this run (as in test_obstacles); each frame's
    degree is the brute-force count with the frame's own radii, R_i (own) or min(R_i, R_j)."""
    sc = recording(m3_scenario(n=14, steps=60, radius_rule=rule, neighbour_search="grid"),
                   ["position", "degree", "radius"], 5)
    result, sink = run(sc)
    assert result.extra["engine_path"] == "per_step"
    radii = [f["radius"] for f in sink.frames]
    assert (radii[0] == 2.0).all() and len(set(radii[-1])) > 1
    for f in sink.frames:
        np.testing.assert_array_equal(
            f["degree"], degrees_per_agent_radius(f["position"], f["radius"], rule, True))
    assert_stats(result, sink, "radius", "radius")
    assert_stats(result, sink, "valency", "degree")


def test_flocking_3d_degree(taichi_cpu):
    init = {"kind": "explicit", "positions": (np.array(lattice_points(3, 3)) * 1.1).tolist(),
            "velocities": np.random.default_rng(2).uniform(-0.5, 0.5, (27, 3)).tolist()}
    sc = Scenario.model_validate({
        "model": {"kind": "flocking", "potential": {"kind": "log_barrier", "d": 1.0},
                  "neighbour_search": "grid"},
        "space": {"kind": "plane", "dimension": 3}, "neighbours": {"radius": 1.8},
        "initial": init, "time": {"steps": 20, "dt": 0.01},
        "recording": {"every": 5, "arrays": ["position", "degree"], "observables_every": 1},
    })
    result, sink = run(sc)
    for f in sink.frames:
        np.testing.assert_array_equal(f["degree"], degrees(f["position"], 1.8, None, False))
    assert_stats(result, sink, "valency", "degree")


def test_recording_degree_leaves_the_trajectory_alone(taichi_cpu):
    """On the per-step path, computing the degrees at frame steps changes no bit."""
    for sc in (vicsek(N=80, steps=15), m3_scenario(n=14, steps=30, neighbour_search="grid")):
        plain, with_degree = (run(recording(sc, ["position", *extra], 3), "per_step")[1]
                              for extra in ([], ["degree"]))
        for a, b in zip(plain.frames, with_degree.frames, strict=True):
            assert np.array_equal(a["position"], b["position"])


@pytest.mark.slow
@pytest.mark.resets_taichi  # float32
def test_h5md_holds_degree_and_radius(taichi_cpu, tmp_path):
    sc = recording(m3_scenario(n=14, steps=20, neighbour_search="grid"),
                   ["position", "degree", "radius"], 10, precision="float32")
    path = tmp_path / "trajectory.h5"
    writer = H5MDWriter(path, sc)
    sink = Frames()

    class Both:
        def frame(self, step, time, arrays):
            writer.frame(step, time, arrays)
            sink.frame(step, time, arrays)

    kernels.run(sc, sink=Both())
    writer.close()
    with h5py.File(path) as f:
        swarm = f["particles/swarm"]
        deg, rad = swarm["degree/value"], swarm["radius/value"]
        assert deg.shape == rad.shape == (3, 14)
        assert deg.dtype == np.int32 and rad.dtype == np.float32  # counts stay integers
        assert list(swarm["degree/step"][:]) == list(swarm["position/step"][:]) == [0, 10, 20]
        assert rad.attrs["unit"] == "m" and "unit" not in deg.attrs
        np.testing.assert_array_equal(deg[:], np.stack([s["degree"] for s in sink.frames]))


@pytest.mark.parametrize("spec,message", [
    (dict(kind="vicsek", arrays=["position", "radius"]),
     "model vicsek cannot record radius (its agents share one radius"),
    (dict(kind="flocking", arrays=["radius"]), "model flocking cannot record radius"),
    (dict(kind="formation", arrays=["position", "degree"]),
     "model formation cannot record degree"),
])
def test_missing_derived_arrays_are_refused(spec, message):
    base = {
        "vicsek": vicsek().model_dump(mode="json"),
        "flocking": m2_scenario().model_dump(mode="json"),
        "formation": get_preset("xi-abed-sim3").model_dump(mode="json"),
    }[spec["kind"]]
    base["recording"] = {"every": 1, "arrays": spec["arrays"]}
    with pytest.raises(ValidationError, match=re.escape("recording.arrays: " + message)) as info:
        Scenario.model_validate(base)
    assert [e.loc for e in field_errors(info.value)] == ["recording.arrays"]


@pytest.mark.slow
def test_the_command_records_degree_at_a_wide_radius(tmp_path):
    """`flocklab run` end to end: a periodic Vicsek run with r = 0.6 L (beyond L/2) writes
    the degrees into trajectory.h5; `flocklab validate` names a refused array and exits 2."""
    doc = vicsek(N=120, L=4.0, r=2.4, steps=10).model_dump(mode="json")
    doc["recording"] = {"every": 5, "arrays": ["position", "degree"], "observables_every": 5}
    spec = tmp_path / "s.json"
    spec.write_text(json.dumps(doc))
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "flocklab", "run", str(spec), "--out",
                           str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    with h5py.File(out / "trajectory.h5") as f:
        deg = f["particles/swarm/degree/value"][:]
        pos = f["particles/swarm/position/value"][:]
        mean = f["observables/degree_mean/value"][:]
    assert deg.shape == (3, 120) and deg.dtype == np.int32
    for k in range(3):
        np.testing.assert_array_equal(deg[k], degrees(pos[k], 2.4, 4.0, True))
    assert mean == pytest.approx(deg.mean(axis=1), rel=1e-13)
    doc["recording"]["arrays"] = ["radius"]
    spec.write_text(json.dumps(doc))
    bad = subprocess.run([sys.executable, "-m", "flocklab", "validate", str(spec)],
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2
    assert "recording.arrays" in bad.stderr + bad.stdout
    assert "cannot record radius" in bad.stderr + bad.stdout


@pytest.mark.slow
@pytest.mark.resets_taichi
def test_float32_runs_record_their_own_counts(taichi_cpu):
    """precision float32: the degree is the float32 engine's count (the observables'), and
    the radius comes in the engine's float type."""
    for sc, prefix in ((vicsek(N=80, steps=6), "degree"),
                       (m3_scenario(n=14, steps=30, neighbour_search="grid"), "valency")):
        doc = recording(sc, ["position", *sc.model.derived_arrays], 3).model_dump(mode="json")
        sc32 = Scenario.model_validate({**doc, "precision": "float32"})
        result, sink = run(sc32)
        assert sink.frames[0]["position"].dtype == np.float32
        assert_stats(result, sink, prefix, "degree")
        if "radius" in sc.model.derived_arrays:
            assert sink.frames[-1]["radius"].dtype == np.float32
            assert_stats(result, sink, "radius", "radius")
