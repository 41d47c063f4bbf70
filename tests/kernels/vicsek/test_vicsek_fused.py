"""The fused small-N path: a replica gives the same bits alone, in a batch, cut into any
windows, and the same prefix when cancelled; the engine picks the path from the scenario."""

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels import engine
from tests.kernels.vicsek.test_vicsek import Frames, scenario

# A mix a sweep would batch together: different N, L, noise, steps and seeds.
MIX = [
    dict(N=30, L=5.0, eta=1.0, seed=1, steps=40),
    dict(N=120, L=6.0, eta=2.0, seed=2, steps=25),
    dict(N=400, L=10.0, eta=0.5, seed=3, steps=40, move="new_heading"),
    dict(N=60, L=6.0, eta=6.0, seed=4, steps=33, inclusive=False),
]


def same_result(a, b):
    assert a.status == b.status and a.steps == b.steps
    assert a.observables.keys() == b.observables.keys()
    for k in a.observables:
        assert np.array_equal(a.observables[k], b.observables[k]), k
    assert a.extra.get("linked_intervals") == b.extra.get("linked_intervals")


def mix(rule: str, periodic: bool, **kw):
    """MIX's scenarios under `rule`, in the periodic box or the plane."""
    specs = [dict(m, rule=rule, L=m["L"] if periodic else None) for m in MIX]
    for m in specs:
        if rule == "laplacian":
            m["g"] = m["N"] + 1.0
        if not periodic:
            m["region"] = {"kind": "box", "low": [0, 0], "high": [m["N"] ** 0.5 / 2] * 2}
    return [scenario(**m, **kw) for m in specs]


@pytest.mark.parametrize("rule", ["vicsek", "average", "laplacian", "leader"])
@pytest.mark.parametrize("L", [True, None], ids=["periodic", "plane"])
# Each rule's fused kernel compiles for seconds: every rule stays fast in a box, the plane
# with the vicsek rule; --all runs the plane with every rule.
@pytest.mark.fast_cases("periodic-vicsek", "periodic-average", "periodic-laplacian",
                        "periodic-leader", "plane-vicsek")
def test_a_batch_gives_each_replica_its_bits_alone(taichi_cpu, rule, L):
    scenarios = mix(rule, bool(L), every=0)
    together = kernels.run_batch(scenarios)
    assert len(engine._batches(scenarios)) == 1  # one launch for all four
    for sc, res in zip(scenarios, together, strict=True):
        assert res.extra["engine_path"] == "fused"
        same_result(res, kernels.run(sc))


def test_windows_and_frames_do_not_change_a_bit(taichi_cpu, fixed_windows):
    sc = scenario(N=200, L=8.0, eta=1.5, steps=60, every=0)
    whole = kernels.run(sc)
    sink = Frames()
    framed = kernels.run(scenario(N=200, L=8.0, eta=1.5, steps=60, every=7), sink=sink)
    assert sink.steps == [*range(0, 60, 7), 60]
    fixed_windows(200 * 3)  # windows of 3 steps
    cut = kernels.run(sc)
    same_result(whole, framed)
    same_result(whole, cut)


def test_cancel_keeps_the_prefix_and_observes_the_stop(taichi_cpu, fixed_windows):
    sc = scenario(N=100, L=6.0, eta=1.0, steps=50, every=0)
    whole = kernels.run(sc)
    fixed_windows(100 * 10)  # windows of 10 steps
    polls = iter([False, True])
    part = kernels.run(sc, should_stop=lambda: next(polls))
    assert part.status == "cancelled" and part.steps == 20
    assert np.array_equal(part.observables["step"], np.arange(21))
    for k in whole.observables:
        assert np.array_equal(part.observables[k], whole.observables[k][:21]), k


def test_divergence_stops_only_its_replica(taichi_cpu):
    good = scenario(N=50, L=None, eta=0.5, steps=20, every=0)
    bad = scenario(N=50, L=None, v0=1e300, steps=20, every=0)
    res = kernels.run_batch([good, bad])
    assert res[0].status == "completed" and res[0].steps == 20
    assert res[1].status == "diverged" and res[1].steps < 20
    assert res[1].error["step"] == res[1].steps
    same_result(res[0], kernels.run(good))


def test_the_path_is_chosen_from_the_scenario_alone(taichi_cpu):
    small = scenario(N=engine.FUSED_MAX_N, L=80.0, steps=1)
    large = scenario(N=engine.FUSED_MAX_N + 1, L=80.0, steps=1)
    assert engine.choose_path(small, "cpu") == "fused"
    assert engine.choose_path(large, "cpu") == "per_step"
    assert engine.choose_path(small, "cuda") == "per_step"  # a GPU wants parallel agents
    groups = engine._batches([small, large, small])
    assert sorted(map(sorted, groups)) == [[0, 2], [1]]


@pytest.mark.parametrize("per_step", [False, True], ids=["fused", "per_step"])
def test_chosen_observables_are_the_same_numbers(taichi_cpu, per_step):
    path = "per_step" if per_step else "fused"
    full = kernels.run(scenario(N=150, L=7.0, eta=1.0, steps=30, every=0), path=path)
    sc = scenario(N=150, L=7.0, eta=1.0, steps=30, every=0)
    sc = sc.model_copy(update={"recording": sc.recording.model_copy(
        update={"observables": ["polarization", "degree_mean"]})})
    part = kernels.run(sc, path=path)
    assert list(part.observables) == ["step", "time", "polarization", "degree_mean"]
    for k in part.observables:
        assert np.array_equal(part.observables[k], full.observables[k]), k


def test_unknown_or_undeclared_observables_are_refused():
    from pydantic import ValidationError

    from flocklab.schemas import Scenario

    doc = scenario(N=20, L=5.0).model_dump(mode="json")
    doc["recording"]["observables"] = ["polarization", "energy"]
    with pytest.raises(ValidationError, match="energy not reported by model vicsek"):
        Scenario.model_validate(doc)
