"""The fused small-N path of M2 and M3 (kernels/models/flocking/fused.py): a replica gives the
same bits alone, in a batch, cut into any windows, and the same prefix when cancelled; it
agrees with the per-step path; the engine picks the path from the scenario alone. M2 and M3
in 2D and 3D (all pairs, the 3x3x3 cells, hashed buckets; M3's point and sphere obstacles in
the 3x3x3 cells of their own grid, damping, the adaptive radius).

(The family runs on the plane only, so there is no periodic case.)"""

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels import engine
from flocklab.kernels.models.flocking import fused as flocking_fused
from flocklab.schemas import Scenario
from tests.kernels.flocking.test_flocking_3d import lattice_3d, two_clusters_3d
from tests.kernels.flocking.test_flocking_3d import m3_scenario as m3_scenario_3d
from tests.kernels.flocking.test_flocking_reference import lattice, m2_scenario, m3_scenario


class Frames:
    """A FrameSink keeping every frame in memory (small runs only)."""

    def __init__(self):
        self.steps, self.frames = [], []

    def frame(self, step, time, arrays):
        self.steps.append(step)
        self.frames.append(arrays)


def with_recording(sc: Scenario, **recording) -> Scenario:
    spec = sc.model_dump(mode="json")
    spec["recording"].update(recording, arrays=["position", "velocity"])
    return Scenario.model_validate(spec)


def obstacles_world(n: int, seed: int, **model) -> Scenario:
    return m3_scenario(n=n, steps=60, seed=seed, **model)


def obstacles_world_3d(n: int, seed: int, **model) -> Scenario:
    """test_flocking_3d's point and sphere obstacles around a jittered cubic lattice of n."""
    spec = m3_scenario_3d(steps=60, **model).model_dump(mode="json")
    spec.update(initial=lattice_3d(n, 1.05, seed, speed=0.4), seed=seed)
    return Scenario.model_validate(spec)


# 64 point obstacles on a 4x4x4 lattice through the flock: a 4x4x4 obstacle grid, so an
# agent folds the obstacles of its 3x3x3 cells.
OBSTACLE_LATTICE = [[1.4 * i + 0.3, 1.4 * j + 0.2, 1.4 * k + 0.4]
                    for i in range(4) for j in range(4) for k in range(4)]


def in_3d(sc: Scenario, initial: dict | None = None) -> Scenario:
    """The scenario in 3D: a jittered cubic lattice (spacing as m2_scenario's default) unless
    `initial` is given."""
    spec = sc.model_dump(mode="json")
    spec["space"]["dimension"] = 3
    spec["initial"] = initial or lattice_3d(sc.n_agents, 1.1, sc.seed)
    return Scenario.model_validate(spec)


def sprawling(n: int = 70) -> Scenario:
    """Two flocks 1000 apart: more cells than the budget, so hashed buckets."""
    init = lattice(n, 1.1, 3)
    init["positions"][n - 10:] = [[1000.0 + 1.1 * i, -500.0] for i in range(10)]
    return Scenario.model_validate({
        "model": {"kind": "flocking"}, "space": {"kind": "plane"},
        "neighbours": {"radius": 2.0}, "initial": init, "time": {"steps": 20, "dt": 0.01},
    })


# Mixes a sweep would batch together: different N (all pairs and cells), graphs, radii,
# obstacles, steps, seeds and observation cadences.
MIXES = {
    "fixed": [
        m2_scenario("fixed", n=10, steps=40, graph={"kind": "ring"}),
        m2_scenario("fixed", n=80, steps=30, seed=2, spacing=1.2),
        with_recording(m2_scenario("fixed", n=30, steps=33, graph={"kind": "complete"},
                                   dt=0.005), observables_every=4),
    ],
    "switching": [
        m2_scenario(n=10, steps=40),
        m2_scenario(n=100, steps=30, seed=2, R=2.5, d=1.3, spacing=1.2),
        with_recording(m2_scenario(n=40, steps=37, seed=3, R=1.6, inclusive=True,
                                   search="grid"), observables_every=3),
        m2_scenario(n=70, steps=25, seed=4, search="all_pairs"),
        sprawling(),
    ],
    "fixed-3d": [
        in_3d(m2_scenario("fixed", n=10, steps=40, graph={"kind": "ring"})),
        in_3d(m2_scenario("fixed", n=80, steps=30, seed=2)),
        with_recording(in_3d(m2_scenario("fixed", n=30, steps=33, graph={"kind": "complete"},
                                         dt=0.005)), observables_every=4),
    ],
    # 216 agents over a 6x6x6 lattice: 4x4x4 cells; 70 in two clusters 1000 apart: hashed.
    "switching-3d": [
        in_3d(m2_scenario(n=10, steps=40)),
        in_3d(m2_scenario(n=216, steps=30, seed=2, R=1.8)),
        with_recording(in_3d(m2_scenario(n=40, steps=37, seed=3, R=1.6, inclusive=True,
                                         search="grid")), observables_every=3),
        in_3d(m2_scenario(n=70, steps=25, seed=4, search="all_pairs")),
        in_3d(m2_scenario(n=70, steps=20), initial=two_clusters_3d(70, 1000.0, 6)),
    ],
    "mission": [
        obstacles_world(5, 1),
        obstacles_world(90, 2, neighbour_search="auto", kappa=2.0),
        obstacles_world(12, 3, damping_region="below_vmin", radius_every=7),
        obstacles_world(20, 4, obstacles=[], discs=[], damping_region="everywhere"),
    ],
    # 216 agents over a 6x6x6 lattice: 3x3x3 cells and more.
    "mission-3d": [
        obstacles_world_3d(12, 7),
        obstacles_world_3d(216, 2, neighbour_search="auto", kappa=2.0),
        obstacles_world_3d(27, 3, damping_region="below_vmin", radius_every=7),
        obstacles_world_3d(20, 4, obstacles=[], discs=[], damping_region="everywhere"),
        obstacles_world_3d(64, 5, obstacles=OBSTACLE_LATTICE, neighbour_search="grid"),
    ],
}


def as_rk4(sc: Scenario) -> Scenario:
    spec = sc.model_dump(mode="json")
    spec["model"]["integrator"] = "rk4"
    return Scenario.model_validate(spec)


# The same mixes under RK4 (the fused kernels of their own): cells rebuilt at every stage.
for _mode in ("fixed", "switching", "mission", "switching-3d", "mission-3d"):
    MIXES[f"{_mode}-rk4"] = [as_rk4(sc) for sc in MIXES[_mode]]
# Each RK4 mode compiles its own kernel: the 2D switching one stays in the fast lane.
SLOW_RK4 = ("fixed-rk4", "mission-rk4", "switching-3d-rk4", "mission-3d-rk4")
SLOW_BATCH_RK4 = ("switching-rk4", *SLOW_RK4)  # its agreement case stays fast


def same_result(a, b):
    assert a.status == b.status and a.steps == b.steps
    assert list(a.observables) == list(b.observables)
    for k in a.observables:
        assert np.array_equal(a.observables[k], b.observables[k]), k
    for k in ("closest_approach", "graph", "adaptive_radius"):
        assert a.extra.get(k) == b.extra.get(k), k


@pytest.mark.parametrize("mode", list(MIXES))
@pytest.mark.slow_cases(*SLOW_BATCH_RK4)
def test_a_batch_gives_each_replica_its_bits_alone(taichi_cpu, mode):
    scenarios = MIXES[mode]
    together = kernels.run_batch(scenarios)
    assert len(engine._batches(scenarios)) == 1  # one launch for all of them
    for sc, res in zip(scenarios, together, strict=True):
        assert res.extra["engine_path"] == "fused"
        same_result(res, kernels.run(sc))


# The largest scenario of each mix (cells, obstacles, lambda_2 by eigsh), and 3D's hashed
# buckets.
AGREEMENT = {mode: max(mix, key=lambda s: s.n_agents) for mode, mix in MIXES.items()}
AGREEMENT["switching-3d-hashed"] = MIXES["switching-3d"][-1]
AGREEMENT["mission-3d-obstacle-lattice"] = MIXES["mission-3d"][-1]
AGREEMENT["mission-3d-adaptive"] = MIXES["mission-3d"][0]


@pytest.mark.parametrize("case", list(AGREEMENT))
# Its own kernels (most of a minute); missions in 3D stay fast in mission-3d.
@pytest.mark.slow_cases("mission-3d-obstacle-lattice", *SLOW_RK4)
def test_the_fused_path_agrees_with_the_per_step_path(taichi_cpu, monkeypatch, case):
    """Every observable, the extras and the frames, to rounding (the summation order
    differs), Euler and RK4 alike."""
    sc = with_recording(AGREEMENT[case], every=10)
    fused_sink, step_sink = Frames(), Frames()
    fused = kernels.run(sc, sink=fused_sink)
    per_step = kernels.run(sc, sink=step_sink, path="per_step")
    assert (fused.extra["engine_path"], per_step.extra["engine_path"]) == ("fused", "per_step")
    assert fused.status == per_step.status == "completed"
    assert list(fused.observables) == list(per_step.observables)
    for k, v in per_step.observables.items():
        np.testing.assert_allclose(fused.observables[k], v, rtol=1e-9, atol=1e-9, err_msg=k)
    assert fused.extra.get("graph") == per_step.extra.get("graph")
    assert fused.extra.get("adaptive_radius") == per_step.extra.get("adaptive_radius")
    assert fused.extra["closest_approach"]["pair"] == per_step.extra["closest_approach"]["pair"]
    assert fused_sink.steps == step_sink.steps == [*range(0, sc.time.steps, 10), sc.time.steps]
    for f, g in zip(fused_sink.frames, step_sink.frames, strict=True):
        for k in g:
            np.testing.assert_allclose(f[k], g[k], rtol=1e-9, atol=1e-12, err_msg=k)


@pytest.mark.slow_cases("mission-3d")
@pytest.mark.parametrize("mode", ["switching", "switching-3d", "mission-3d"])
def test_windows_frames_and_snapshot_launches_do_not_change_a_bit(taichi_cpu, monkeypatch,
                                                                    fixed_windows, mode):
    sc = MIXES[mode][1]  # N = 100 (216 in 3D) in cells; lambda_2 from snapshots
    steps = sc.time.steps
    whole = kernels.run(sc)
    sink = Frames()
    framed = kernels.run(with_recording(sc, every=7), sink=sink)
    assert sink.steps == [*range(0, steps, 7), steps]
    fixed_windows(sc.n_agents * 3)  # windows of 3 steps
    cut = kernels.run(sc)
    monkeypatch.setattr(flocking_fused, "SNAP_DOUBLES", 1)  # lambda_2 every launch of 1 step
    snapped = kernels.run(sc)
    for res in (framed, cut, snapped):
        same_result(whole, res)
    assert whole.observables["lambda2"].min() > 0  # computed, and connected


def test_cancel_keeps_the_prefix_and_observes_the_stop(taichi_cpu, fixed_windows):
    sc = MIXES["mission"][1]
    whole = kernels.run(sc)
    fixed_windows(sc.n_agents * 10)  # windows of 10 steps
    polls = iter([False, True])
    part = kernels.run(sc, should_stop=lambda: next(polls))
    assert part.status == "cancelled" and part.steps == 20
    assert np.array_equal(part.observables["step"], np.arange(21))
    for k in whole.observables:
        assert np.array_equal(part.observables[k], whole.observables[k][:21]), k


def test_divergence_stops_only_its_replica(taichi_cpu):
    good = MIXES["switching"][0]
    init = lattice(10, 1.1, 5)
    init["positions"][3] = init["positions"][4]  # two agents at the same point
    bad = Scenario.model_validate({**good.model_dump(mode="json"), "initial": init})
    res = kernels.run_batch([good, bad])
    assert res[0].status == "completed" and res[0].steps == 40
    assert res[1].status == "diverged" and res[1].steps == res[1].error["step"] == 0
    assert "same point" in res[1].error["cause"]
    assert res[1].error["quantity"] == "position/velocity"
    assert len(res[1].observables["step"]) == 1  # X(0) was observed before the blow-up
    same_result(res[0], kernels.run(good))


def test_the_path_is_chosen_from_the_scenario_alone(taichi_cpu):
    euler = m2_scenario(n=10, steps=1)
    rk4 = m2_scenario(n=10, steps=1, integrator="rk4")
    min_rule = m3_scenario(n=5, steps=1, radius_rule="min")
    assert engine.schedule(euler, "cpu")[1] is flocking_fused.FlockingBatch
    assert engine.schedule(MIXES["mission"][0], "cpu")[1] is flocking_fused.FlockingBatch
    assert engine.schedule(rk4, "cpu")[1] is flocking_fused.FlockingBatch
    assert engine.choose_path(min_rule, "cpu") == "per_step"
    assert engine.choose_path(euler, "cuda") == "per_step"
    mixed = [euler, rk4, MIXES["fixed"][0], euler, MIXES["mission"][0]]
    assert sorted(map(sorted, engine._batches(mixed))) == [[0, 3], [1], [2], [4]]
    assert kernels.run(rk4).extra["engine_path"] == "fused"
    # 3D: M2 and M3 fused, in launches of their own, apart from 2D
    flat = MIXES["switching"][0]
    deep = MIXES["switching-3d"][0]
    assert engine.schedule(deep, "cpu")[1] is flocking_fused.FlockingBatch
    assert engine.schedule(MIXES["fixed-3d"][0], "cpu")[1] is flocking_fused.FlockingBatch
    assert engine.schedule(m3_scenario_3d(steps=1), "cpu")[1] is flocking_fused.FlockingBatch
    assert engine.choose_path(m3_scenario_3d(steps=1, radius_rule="min"), "cpu") == "per_step"
    assert sorted(map(sorted, engine._batches([flat, deep, flat, deep]))) == [[0, 2], [1, 3]]
    mission = [MIXES["mission"][0], MIXES["mission-3d"][0], MIXES["mission"][1]]
    assert sorted(map(sorted, engine._batches(mission))) == [[0, 2], [1]]
    assert kernels.run(m3_scenario_3d(steps=1)).extra["engine_path"] == "fused"


@pytest.mark.parametrize("dim", [2, 3])
def test_a_runaway_swarm_is_reported_as_the_per_step_path_reports_it(taichi_cpu, monkeypatch,
                                                                      dim):
    """A pair 1e-6 apart is blown 4e14 apart in one step: the cell list refuses a swarm
    over 2^30 (in 3D 2^20) radii wide, at the same step and in the same words on both
    paths."""
    init = lattice(80, 1.1, 3) if dim == 2 else lattice_3d(80, 1.1, 3)
    init["positions"][1] = [init["positions"][0][0] + 1e-6, *init["positions"][0][1:]]
    sc = Scenario.model_validate({
        "model": {"kind": "flocking"}, "space": {"kind": "plane", "dimension": dim},
        "neighbours": {"radius": 2.0}, "initial": init, "time": {"steps": 20, "dt": 0.01},
    })
    fused = kernels.run(sc)
    per_step = kernels.run(sc, path="per_step")
    assert fused.extra["engine_path"] == "fused" and fused.status == "diverged"
    assert fused.error == per_step.error
    limit = 30 if dim == 2 else 20
    assert fused.error["step"] == 1 and f"2^{limit} neighbour radii" in fused.error["cause"]
