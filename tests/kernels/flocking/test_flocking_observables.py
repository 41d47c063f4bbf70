"""recording.observables for M2 and M3: the declared names cover every observable a run
reports (per-agent valency_<i> included); a run reports the named ones alone, on both
engine paths and in both dimensions, with the bits of the full run; lambda_2's eigensolve
is skipped when lambda2 is not named; a name the model does not report is refused."""

import numpy as np
import pytest
from pydantic import ValidationError

from flocklab import kernels
from flocklab.kernels.models.flocking import fused
from flocklab.kernels.models.flocking import observe as fo
from flocklab.schemas import Scenario
from flocklab.schemas.flocking import HIST_BINS
from tests.kernels.flocking.test_flocking_fused import MIXES
from tests.selection import counted, run, with_observables

FRAMES = {"arrays": ["position", "velocity"], "every": 10}


@pytest.mark.slow_cases("mission-3d-per_step", "mission-3d-rk4-fused", "mission-3d-rk4-per_step",
                        "mission-per_step", "mission-rk4-fused", "mission-rk4-per_step",
                        "switching-3d-per_step", "switching-3d-rk4-fused",
                        "switching-3d-rk4-per_step", "switching-per_step", "switching-rk4-per_step")
@pytest.mark.parametrize("path", ["fused", "per_step"], indirect=True)
@pytest.mark.parametrize("mode", list(MIXES))
def test_every_reported_observable_is_declared(taichi_cpu, path, mode):
    """Fixed and switching M2, M3, 2D and 3D, all pairs and grids, per-agent valencies and
    the histogram: each name a run reports is one its model declares."""
    for sc in MIXES[mode]:
        res = kernels.run(sc)
        assert res.status == "completed", res.error
        undeclared = [k for k in res.observables if k not in ("step", "time")
                      and not type(sc.model).reports(k)]
        assert undeclared == [], (mode, sc.n_agents)


# A switching flock of 40 in 3D (the valency histogram), an M3 flock of 27 in 3D and a
# switching flock of 10 in 2D (each agent's valency).
CASES = {"switching-3d": MIXES["switching-3d"][2], "mission-3d": MIXES["mission-3d"][2],
         "switching": MIXES["switching"][0]}
CHOSEN = {"switching-3d": ["Q", "valency_hist_2", "valency_hist_16plus", "mean_velocity_z",
                           "components"],
          "mission-3d": ["radius_min", "destination_distance_mean", "Q", "valency_5"],
          "switching": ["heading_spread", "valency_0", "valency_9", "min_distance"]}


@pytest.mark.parametrize("path", ["fused", "per_step"], indirect=True)
@pytest.mark.parametrize("case", list(CASES))
def test_without_lambda2_no_eigensolve_and_every_bit_kept(taichi_cpu, monkeypatch, path,
                                                          case):
    """lambda2 not named: no eigensolve; the run reports the named columns alone, equal to
    the full run's bit for bit, and the same frames. Named: it is solved again."""
    sc = CASES[case]
    full, full_frames = run(with_observables(sc, None, **FRAMES))
    solve = (counted(monkeypatch, fused, "lambda2_rows") if path == "fused" else
             counted(monkeypatch, fo, "algebraic_connectivity"))
    some, some_frames = run(with_observables(sc, CHOSEN[case], **FRAMES))
    assert solve[0] == 0
    assert some.extra["engine_path"] == path
    assert set(some.observables) == {"step", "time", *CHOSEN[case]}
    for k in some.observables:
        assert np.array_equal(some.observables[k], full.observables[k]), k
    assert some_frames.steps == full_frames.steps
    for x, y in zip(some_frames.frames, full_frames.frames, strict=True):
        for k in x:
            assert np.array_equal(x[k], y[k]), k
    again, _ = run(with_observables(sc, ["lambda2"], **FRAMES))
    assert solve[0] > 0
    assert np.array_equal(again.observables["lambda2"], full.observables["lambda2"])
    assert full.observables["lambda2"].max() > 0.0  # computed, not the -1 of "not computed"


@pytest.mark.parametrize("kind, name", [
    ("flocking", "radius_min"),  # M3's
    ("flocking", "valency_x"),
    ("flocking", "valency_07"),  # agent 7 is valency_7
    ("flocking", "valency_hist_17"),
    ("flocking", "polarization"),
    ("flocking_obstacles", "W"),  # M2's fixed graph
])
def test_a_name_the_model_does_not_report_is_refused(kind, name):
    sc = CASES["switching"] if kind == "flocking" else CASES["mission-3d"]
    doc = sc.model_dump(mode="json")
    doc["recording"]["observables"] = ["components", name]
    with pytest.raises(ValidationError, match=f"{name} not reported by model {kind}"):
        Scenario.model_validate(doc)


def test_the_refusal_lists_the_histogram_as_one_run_of_names():
    doc = CASES["switching"].model_dump(mode="json")
    doc["recording"]["observables"] = ["Qx"]
    with pytest.raises(ValidationError) as err:
        Scenario.model_validate(doc)
    message = str(err.value)
    assert (f"valency_<i>, valency_hist_0 .. valency_hist_{HIST_BINS - 1}, "
            f"valency_hist_{HIST_BINS}plus, min_distance") in message
    assert "valency_hist_1," not in message and "lambda2, W" in message
