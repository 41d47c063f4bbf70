"""M4 on the fused small-N path: a replica gives the same bits alone, in a batch, cut into
any windows, and the same prefix when cancelled; the engine picks the path from the
scenario alone; in 2D and 3D. (The plane is M4's only space.)"""

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels import engine
from flocklab.kernels.models.formation import fused
from flocklab.kernels.models.formation.fused import MAX_N, FormationBatch
from flocklab.schemas import Scenario
from tests.kernels.formation.test_formation import STRAIGHT, explicit, scenario
from tests.kernels.formation.test_formation_3d import STRAIGHT as STRAIGHT_3D
from tests.kernels.formation.test_formation_3d import doc
from tests.kernels.formation.test_formation_3d import explicit as explicit_3d

SPLINE = {"kind": "spline", "waypoints": [[0.0, 60.0], [-50.0, 50.0]], "arrival_time": 2.0}
# A mix a sweep would batch together: designs, gains, paths, schedules, N, steps, seeds.
MIX = [
    (dict(attraction={"kind": "linear", "k": 1.5}, path=STRAIGHT,
          formation=explicit("wedge", 10),
          schedule=[{"start": 0.1, "end": 0.3, "rotate": 2.0}]), dict(N=10, steps=40)),
    (dict(attraction={"kind": "quadratic", "c": 0.05},
          repulsion={"kind": "inverse_square", "k_g": 400.0}, path=SPLINE,
          formation={"kind": "named", "shape": "circle"},
          schedule=[{"start": 0.0, "end": 0.2, "formation": explicit("hex", 12, 0.4),
                     "relaxation": "linear"}]), dict(N=12, steps=33, seed=2)),
    (dict(design="F2", attraction={"kind": "saturating", "k": 2.0, "v_max": 9.0},
          path={"kind": "straight", "target": [10.0, 12.0], "arrival_time": 4.0}),
     dict(N=30, steps=25, seed=3, obs_every=4, inclusive=True)),
    (dict(design="F2", path=SPLINE), dict(N=7, steps=40, seed=4, obs_every=3)),
]
SPLINE_3D = {"kind": "spline", "waypoints": [[0.0, 60.0, 20.0], [-50.0, 50.0, -10.0]],
             "arrival_time": 2.0}
# F2 in 3D: a leader too fast to keep up with (D3 fails, the LP's, once the group trails
# it), a box where the random start is several components (D3 fails on lone agents until
# they meet), a spline the group trails and then surrounds at its end.
FAST_3D = {"kind": "straight", "target": [-40.0, -30.0, 25.0], "speed": 40.0}
BIG_BOX = {"kind": "box", "low": [0.0, 0.0, 0.0], "high": [60.0, 60.0, 60.0]}
F2_3D = [
    (dict(design="F2", attraction={"kind": "linear", "k": 1.0}, path=FAST_3D),
     dict(N=12, steps=60, obs_every=3)),
    (dict(design="F2", attraction={"kind": "linear", "k": 1.0}, path=FAST_3D),
     dict(N=12, steps=60, obs_every=3, region=BIG_BOX)),
    (dict(design="F2", path=SPLINE_3D), dict(N=10, steps=80, seed=4, obs_every=2, dt=0.05)),
]
# 3D: named (cube, shell) and explicit 3-column formations, rotations about an axis and
# morphs, straight and spline paths; F2 with its D3 from the host's snapshots.
MIX_3D = [
    (dict(attraction={"kind": "linear", "k": 1.5}, path=STRAIGHT_3D,
          formation={"kind": "named", "shape": "cube", "orientation": 0.3},
          schedule=[{"start": 0.1, "end": 0.3, "rotate": 2.0, "axis": [1.0, 2.0, 3.0]}]),
     dict(N=10, steps=40)),
    (dict(attraction={"kind": "quadratic", "c": 0.05},
          repulsion={"kind": "inverse_square", "k_g": 400.0}, path=SPLINE_3D,
          formation={"kind": "named", "shape": "shell"},
          schedule=[{"start": 0.0, "end": 0.2, "formation": explicit_3d("cube", 12, 0.4),
                     "relaxation": "linear"}]), dict(N=12, steps=33, seed=2)),
    (dict(attraction={"kind": "saturating", "k": 2.0, "v_max": 9.0},
          path={"kind": "straight", "target": [10.0, 12.0, 14.0], "arrival_time": 4.0},
          formation=explicit_3d("wedge", 30),
          schedule=[{"start": 0.05, "end": 0.15, "rotate": -1.0}]),
     dict(N=30, steps=25, seed=3, obs_every=4, inclusive=True)),
    *F2_3D,
]
MIXES = {2: MIX, 3: MIX_3D}


def scenario_in(dim, model, *, every=1, arrays=("position",), inclusive=None, **kw):
    """test_formation's scenario in 2D; in 3D the same in a 3D box (test_formation_3d)."""
    if dim == 2:
        return scenario(model, every=every, arrays=arrays, inclusive=inclusive, **kw)
    spec = doc(model, every=every, **kw)
    spec["recording"]["arrays"] = list(arrays)
    spec["neighbours"]["inclusive"] = inclusive
    return Scenario.model_validate(spec)


def same_result(a, b):
    assert a.status == b.status and a.steps == b.steps
    assert a.observables.keys() == b.observables.keys()
    for k in a.observables:
        assert np.array_equal(a.observables[k], b.observables[k]), k
    assert a.extra["dense_regime"] == b.extra["dense_regime"]


class Frames:
    def __init__(self):
        self.steps, self.frames = [], []

    def frame(self, step, time, arrays):
        self.steps.append(step)
        self.frames.append(arrays)


@pytest.mark.slow_cases("rk4-3")
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("integrator", ["euler", "rk4"])
def test_a_batch_gives_each_replica_its_bits_alone(taichi_cpu, fixed_windows, integrator,
                                                   dim):
    scenarios = [scenario_in(dim, dict(m, integrator=integrator), every=0, **kw)
                 for m, kw in MIXES[dim]]
    together = kernels.run_batch(scenarios)
    assert len(engine._batches(scenarios)) == 1  # one launch for all of them
    alone = [kernels.run(sc) for sc in scenarios]
    # And in windows of 7 steps, some replicas ending before the others.
    fixed_windows(59 * 7)
    cut = kernels.run_batch(scenarios)
    for res, res_cut, ref in zip(together, cut, alone, strict=True):
        assert res.extra["engine_path"] == "fused"
        assert res.status == "completed", res.error
        same_result(res, ref)
        same_result(res_cut, ref)


@pytest.mark.parametrize("dim", [2, 3])
def test_windows_and_frames_do_not_change_a_bit(taichi_cpu, fixed_windows, dim):
    m, kw = MIXES[dim][1]
    arrays = ("position", "velocity")
    whole = kernels.run(scenario_in(dim, m, every=0, **kw))
    assert whole.extra["engine_path"] == "fused"
    sink = Frames()
    framed = kernels.run(scenario_in(dim, m, every=7, arrays=arrays, **kw), sink=sink)
    assert sink.steps == [*range(0, 33, 7), 33]
    fixed_windows(12 * 3)  # windows of 3 steps
    cut = kernels.run(scenario_in(dim, m, every=0, **kw))
    cut_sink = Frames()
    kernels.run(scenario_in(dim, m, every=7, arrays=arrays, **kw), sink=cut_sink)
    same_result(whole, framed)
    same_result(whole, cut)
    assert cut_sink.steps == sink.steps
    for a, b in zip(sink.frames, cut_sink.frames, strict=True):
        for k in arrays:
            assert np.array_equal(a[k], b[k]), k
    # The last frame's velocity is the rate of the last state (the observation's speeds).
    v = sink.frames[-1]["velocity"]
    assert v.shape == (12, dim)
    assert np.linalg.norm(v, axis=1).max() == pytest.approx(whole.final["speed_max"],
                                                            rel=1e-12)


def test_cancel_keeps_the_prefix_and_observes_the_stop(taichi_cpu, fixed_windows):
    m, kw = MIX[0]
    sc = scenario(m, every=0, **kw)
    whole = kernels.run(sc)
    fixed_windows(10 * 10)  # windows of 10 steps
    polls = iter([False, True])
    part = kernels.run(sc, should_stop=lambda: next(polls))
    assert part.status == "cancelled" and part.steps == 20
    assert np.array_equal(part.observables["step"], np.arange(21))
    for k in whole.observables:
        assert np.array_equal(part.observables[k], whole.observables[k][:21]), k


def test_divergence_stops_only_its_replica(taichi_cpu):
    good = scenario(*MIX[0][:1], every=0, **MIX[0][1])
    same = scenario({"design": "F2", "path": STRAIGHT}, every=0,
                    positions=[[0.0, 0.0], [0.0, 0.0], [5.0, 1.0]])
    huge = scenario({"design": "F2", "path": STRAIGHT, "attraction": {"kind": "quadratic"}},
                    N=30, dt=1e6, steps=50, every=0)
    res = kernels.run_batch([good, same, huge])
    assert [r.extra["engine_path"] for r in res] == ["fused"] * 3
    assert res[0].status == "completed" and res[0].steps == 40
    same_result(res[0], kernels.run(good))
    assert res[1].status == "diverged" and res[1].error["step"] == 0 == res[1].steps
    assert "same position" in res[1].error["cause"]
    assert res[2].status == "diverged" and 0 < res[2].steps < 50
    assert res[2].error["step"] == res[2].steps and "spans" in res[2].error["cause"]
    # The stopping state is not observed: the runaway check comes first, as on the
    # per-step path (its grid refuses to bucket the swarm).
    assert len(res[2].observables["step"]) == res[2].steps


@pytest.mark.slow_cases("runaway-rk4-3")
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("integrator", ["euler", "rk4"])
@pytest.mark.parametrize("case", ["runaway", "coincident"])
def test_divergence_has_the_per_step_step_and_cause(taichi_cpu, monkeypatch, integrator,
                                                    case, dim):
    m = {"design": "F2", "path": STRAIGHT if dim == 2 else STRAIGHT_3D}
    if case == "runaway":
        kw = dict(N=30, dt=1e3, steps=20)
    else:
        kw = dict(positions=[[0.0, 0.0, 0.0][:dim], [3.0, 0.0, 0.0][:dim],
                             [3.0, 0.0, 0.0][:dim]], steps=20)
    sc = scenario_in(dim, dict(m, integrator=integrator), every=0, **kw)
    fused = kernels.run(sc)
    per_step = kernels.run(sc, path="per_step")
    assert (fused.extra["engine_path"], per_step.extra["engine_path"]) == ("fused",
                                                                         "per_step")
    assert fused.status == per_step.status == "diverged"
    assert fused.error == per_step.error
    assert fused.steps == per_step.steps
    assert np.array_equal(fused.observables["step"], per_step.observables["step"])
    assert ("spans" if case == "runaway" else "same position") in fused.error["cause"]


def test_the_path_is_chosen_from_the_scenario_alone(taichi_cpu):
    m = {"design": "F2", "path": STRAIGHT}
    assert FormationBatch.batch_key(scenario(m, N=113)) is not None  # 9 N <= 1024: exact
    assert FormationBatch.batch_key(scenario(m, N=114)) is None  # the dense regime may act
    exact = dict(m, max_exact_candidates=None)
    assert FormationBatch.batch_key(scenario(exact, N=MAX_N)) is not None
    assert FormationBatch.batch_key(scenario(exact, N=MAX_N + 1)) is None
    assert FormationBatch.batch_key(scenario(m, N=1)) is None
    small = scenario(m, N=20, steps=2)
    assert engine.schedule(small, "cpu")[1] is FormationBatch
    assert engine.choose_path(small, "cuda") == "per_step"
    assert kernels.run(scenario(m, N=114, steps=2)).extra["engine_path"] == "per_step"
    # 3D: F1 and F2 are fused (in one launch, never with 2D; F2's D3 from snapshots).
    f1 = scenario_in(3, {"path": STRAIGHT_3D, "formation": {"kind": "named", "shape": "cube"}},
                     N=20, steps=2)
    assert engine.schedule(f1, "cpu")[1] is FormationBatch
    assert len(engine._batches([small, f1])) == 2
    f2 = scenario_in(3, {"design": "F2", "path": STRAIGHT_3D}, N=20, steps=2)
    assert engine.schedule(f2, "cpu")[1] is FormationBatch
    assert len(engine._batches([f1, f2])) == 1
    assert kernels.run(f2).extra["engine_path"] == "fused"


@pytest.mark.parametrize("dim", [2, 3])
def test_the_spline_table_is_the_scalar_path(dim):
    """The vectorised arc-length inversion the fused path tabulates p(t) and q(t) with
    gives the scalar solver's values (to its tolerance), before and after the arrival."""
    from flocklab.kernels.models.formation.path import SplineTable, make_path
    from flocklab.schemas.formation import SplinePath

    spec = SplinePath.model_validate(SPLINE if dim == 2 else SPLINE_3D)
    spline = make_path(spec, np.full(dim, 25.0))
    t = np.linspace(0.0, 2.5, 601)  # arrival at 2.0
    table = SplineTable(spline)
    want_q = np.arange(len(t)) % 3 == 0
    pq = table.at(t, want_q)
    assert pq.shape == (len(t), 2 * dim)
    p, q = pq[:, :dim], pq[want_q, dim:]
    np.testing.assert_allclose(p, [spline.position(x) for x in t], rtol=0, atol=1e-11)
    np.testing.assert_allclose(q, [spline.velocity(x) for x in t[want_q]], rtol=0,
                               atol=1e-11)
    assert np.all(pq[~want_q, dim:] == 0.0)
    moving = t[want_q] < 2.0
    assert np.all(q[~moving] == 0.0) and np.linalg.norm(q[moving], axis=1).min() > 1
    # Row by row the same bits however the times are cut (the windows of a run).
    cut = np.concatenate([table.at(t[:7], want_q[:7]), table.at(t[7:300], want_q[7:300]),
                          table.at(t[300:], want_q[300:])])
    assert np.array_equal(cut, pq)


SCHEDULE = [  # rotate, morph, an abrupt rotation, morph (linear), rotate (linear)
    {"start": 0.05, "end": 0.1, "rotate": 1.0},
    {"start": 0.12, "end": 0.2, "formation": {"kind": "named", "shape": "hex",
                                              "orientation": 0.3}},
    {"start": 0.2, "end": 0.2, "rotate": -0.5},
    {"start": 0.25, "end": 0.3, "formation": explicit("line", 9), "relaxation": "linear"},
    {"start": 0.31, "end": 0.35, "rotate": 2.0, "relaxation": "linear"},
]
SCHEDULE_3D = [  # the same chain in 3D: rotations about tilted axes and z, 3D formations
    {"start": 0.05, "end": 0.1, "rotate": 1.0, "axis": [1.0, 2.0, 3.0]},
    {"start": 0.12, "end": 0.2, "formation": {"kind": "named", "shape": "shell"}},
    {"start": 0.2, "end": 0.2, "rotate": -0.5},
    {"start": 0.25, "end": 0.3, "formation": explicit_3d("cube", 9, 0.2),
     "relaxation": "linear"},
    {"start": 0.31, "end": 0.35, "rotate": 2.0, "relaxation": "linear",
     "axis": [0.0, -1.0, 0.5]},
]
CHAIN = {2: ({"kind": "named", "shape": "wedge"}, SCHEDULE, STRAIGHT, SPLINE),
         3: ({"kind": "named", "shape": "cube", "orientation": 0.3}, SCHEDULE_3D,
             STRAIGHT_3D, SPLINE_3D)}


def on_both_paths(sc):
    """(result, frames) of the fused path, then of the per-step path; every observable of
    the one within 1e-12 of the other's."""
    runs = []
    for name in ("fused", "per_step"):
        sink = Frames()
        res = kernels.run(sc, sink=sink, path=name)
        assert res.extra["engine_path"] == name and res.status == "completed", res.error
        runs.append((res, sink))
    (a, _), (b, _) = runs
    assert a.observables.keys() == b.observables.keys()
    for k in a.observables:
        np.testing.assert_allclose(a.observables[k], b.observables[k], rtol=1e-12,
                                   atol=1e-12, err_msg=k)
    return runs


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("integrator", ["euler", "rk4"])
def test_both_paths_agree_through_a_chain_of_formation_changes(taichi_cpu, monkeypatch,
                                                              integrator, dim):
    """The in-kernel schedule (which stored formation, which weights, at every stage time)
    against the per-step path's host schedule, frames and every observable (Euler on a
    straight path, RK4 on a spline)."""
    formation, schedule, straight, spline = CHAIN[dim]
    m = dict(path=straight if integrator == "euler" else spline, formation=formation,
             schedule=schedule, integrator=integrator)
    sc = scenario_in(dim, m, N=9, steps=40, every=8, arrays=("position", "velocity"),
                     obs_every=3)
    (a, fa), (_, fb) = on_both_paths(sc)
    assert fa.steps == fb.steps == [*range(0, 40, 8), 40]
    for x, y in zip(fa.frames, fb.frames, strict=True):
        for k in x:
            np.testing.assert_allclose(x[k], y[k], rtol=1e-12, atol=1e-11, err_msg=k)
    assert a.observables["formation_error_max"].max() > 1.0  # the changes do show
    assert ("leader_z" in a.observables) == (dim == 3)


@pytest.mark.parametrize("integrator", ["euler", "rk4"])
def test_a_snapshot_buffer_smaller_than_a_window_does_not_change_a_bit(taichi_cpu,
                                                                       monkeypatch,
                                                                       integrator):
    """3D F2's D3 snapshots: a buffer of 3 rows cuts every window into launches of one
    observation interval (the host's D3 after each); F1 in the batch takes none."""
    scenarios = [scenario_in(3, dict(m, integrator=integrator), every=0, **kw)
                 for m, kw in MIX_3D]
    whole = kernels.run_batch(scenarios)
    monkeypatch.setattr(fused, "SNAP_DOUBLES", 1)
    small = FormationBatch(scenarios)
    assert (small.snaps.K, small.snaps.chunk) == (3, 2)  # the smallest observables_every: 2
    assert small.snap == [False] * 3 + [True] * 3
    launches = []
    launch = FormationBatch._launch
    monkeypatch.setattr(FormationBatch, "_launch",
                        lambda self, s0, s1: (launches.append(s1 - s0), launch(self, s0, s1)))
    cut = kernels.run_batch(scenarios)
    assert max(launches) == 2 and len(launches) >= 30
    for a, b in zip(whole, cut, strict=True):
        assert a.status == "completed", a.error
        same_result(a, b)


@pytest.mark.parametrize("integrator", ["euler", "rk4"])
@pytest.mark.parametrize("case", range(len(F2_3D)))
def test_both_paths_agree_on_f2_in_3d(taichi_cpu, monkeypatch, integrator, case):
    """3D F2 fused (D1, D2, isolated, components in the kernel, D3 the host's LP on its
    snapshots) against the per-step path: every observable and the frames; D3 takes both
    values."""
    m, kw = F2_3D[case]
    sc = scenario_in(3, dict(m, integrator=integrator), every=20, **kw)
    (a, fa), (b, fb) = on_both_paths(sc)
    for k in ("D1", "D2", "D3", "isolated", "components"):
        assert np.array_equal(a.observables[k], b.observables[k]), k
    assert set(a.observables["D3"]) == {0.0, 1.0}
    assert fa.steps == fb.steps
    for x, y in zip(fa.frames, fb.frames, strict=True):
        np.testing.assert_allclose(x["position"], y["position"], rtol=1e-12, atol=1e-11)
