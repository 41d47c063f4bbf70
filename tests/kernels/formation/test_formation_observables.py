"""recording.observables for M4: a run reports the named observables alone, on both engine
paths and in both dimensions; the trajectory and the named columns keep their bits; 3D F2
skips D3's linear program when D3 is not named; an unknown name is refused."""

import numpy as np
import pytest
from pydantic import ValidationError

from flocklab import kernels
from flocklab.kernels.models.formation import fused
from flocklab.kernels.models.formation import kernel as per_step
from flocklab.schemas import Scenario
from tests.kernels.formation.test_formation_fused import F2_3D, MIX, MIX_3D, scenario_in
from tests.selection import counted, run, with_observables

CHEAP = ["V2", "D1", "D2", "isolated", "components", "min_distance", "leader_x"]


@pytest.mark.parametrize("path", ["fused", "per_step"], indirect=True)
@pytest.mark.parametrize("case", range(len(F2_3D)))
def test_3d_f2_without_d3_skips_its_lp_and_keeps_every_bit(taichi_cpu, monkeypatch, path,
                                                           case):
    """D3 not named: no LP is solved, no D3 column; the named columns and the frames equal
    the full run's bit for bit. Named: the LP runs at every observation."""
    m, kw = F2_3D[case]
    sc = scenario_in(3, m, every=20, **kw)
    full, full_frames = run(sc)
    # The fused path calls the LP per observation; the per-step path D3 per observation.
    lp = (counted(monkeypatch, fused, "d3_holds_3d") if path == "fused" else
          counted(monkeypatch, per_step.FormationKernel, "_d3"))
    some, some_frames = run(with_observables(sc, CHEAP))
    assert lp[0] == 0
    assert some.extra["engine_path"] == path
    assert set(some.observables) == {"step", "time", *CHEAP}
    for k in some.observables:
        assert np.array_equal(some.observables[k], full.observables[k]), k
    for x, y in zip(some_frames.frames, full_frames.frames, strict=True):
        assert np.array_equal(x["position"], y["position"])
    run(with_observables(sc, ["D3"]))
    assert lp[0] >= len(full.observables["D3"])


@pytest.mark.slow_cases("2-per_step", "3-per_step")
@pytest.mark.parametrize("path", ["fused", "per_step"], indirect=True)
@pytest.mark.parametrize("dim", [2, 3])
def test_a_batch_reports_each_replica_its_own_selection(taichi_cpu, path, dim):
    """F1 and F2 replicas side by side, each naming its own observables (one none of them
    reports): each result has its chosen columns, equal to those of its run alone with
    every observable."""
    mix = (MIX if dim == 2 else MIX_3D)[:4]
    chosen = [["formation_error", "V1"], ["lag", "leader_speed", "D3"],
              ["V2", "D3", "centroid_x"], None]
    scenarios = [with_observables(scenario_in(dim, m, every=0, **kw), c)
                 for (m, kw), c in zip(mix, chosen, strict=True)]
    results = kernels.run_batch(scenarios)
    for sc, res, c in zip(scenarios, results, chosen, strict=True):
        assert res.status == "completed", res.error
        assert res.extra["engine_path"] == path
        alone = kernels.run(with_observables(sc, None))
        reported = set(alone.observables) if c is None else {"step", "time"} | (
            set(c) & set(alone.observables))
        assert set(res.observables) == reported
        for k in res.observables:
            assert np.array_equal(res.observables[k], alone.observables[k]), k


def test_an_unknown_observable_is_refused():
    sc = scenario_in(3, F2_3D[0][0], every=0, **F2_3D[0][1])
    doc = sc.model_dump(mode="json")
    doc["recording"]["observables"] = ["V2", "polarization"]
    with pytest.raises(ValidationError, match="polarization not reported by model formation"):
        Scenario.model_validate(doc)


def test_the_declared_names_are_those_the_models_report():
    """The schema's list is every column the fused path can report, and no other."""
    from flocklab.schemas.formation import FormationParams

    assert set(FormationParams.observables) == set(fused.OBS) - {"step"}
