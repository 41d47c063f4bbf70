"""Paper 000's monotone quantities checked on every M2 run (kernels/checks.py): a run whose
dt does not resolve the stiffest pair reports Q rising, on both engine paths, and the
command warns; a resolved run reports that Q held."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels.checks import monotone_checks
from flocklab.schemas import Scenario


def m2(dt: float, spacing: float, speed: float, steps: int = 400) -> dict:
    """100 agents on a jittered lattice; spacing 0.7 < d with speeds up to 2 presses pairs
    close enough that dt = 0.05 (inside the schema's limit at the potential's minimum)
    no longer resolves them."""
    return {"model": {"kind": "flocking", "topology": "switching",
                      "potential": {"kind": "log_barrier", "d": 1.0}},
            "space": {"kind": "plane"}, "neighbours": {"radius": 2.0},
            "initial": {"kind": "random", "N": 100, "speed_range": [0.0, speed],
                        "region": {"kind": "lattice", "low": [0.0, 0.0], "spacing": spacing,
                                   "jitter": 0.2}},
            "time": {"steps": steps, "dt": dt}, "recording": {"observables_every": 5},
            "seed": 3}


@pytest.mark.slow_cases("per_step")  # the fused twin stays fast
def test_q_rise_reported_on_both_paths(taichi_cpu, path):
    res = kernels.run(Scenario.model_validate(m2(0.05, 0.7, 2.0)))
    assert res.status == "completed" and res.extra["engine_path"] == path
    check = res.extra["checks"]["Q_non_increasing"]
    q = res.observables["Q"]
    assert not check["held"] and check["rises"] == int((np.diff(q) > 1e-9 * abs(q).max()).sum())
    assert check["rises"] > 0 and check["largest_rise"] > 0.01
    first = int(np.argmax(np.diff(q) > 1e-9 * abs(q).max())) + 1
    assert check["first_rise_time"] == res.observables["time"][first]


def test_q_held_on_a_resolved_run(taichi_cpu, path):
    res = kernels.run(Scenario.model_validate(m2(0.01, 1.0, 0.5)))
    check = res.extra["checks"]["Q_non_increasing"]
    assert check == {"held": True, "rises": 0, "largest_rise": 0.0, "first_rise_time": None,
                     "claim": check["claim"]}
    assert "eq. 10" in check["claim"]


def test_fixed_graph_checks_w_and_vicsek_claims_nothing(taichi_cpu):
    spec = m2(0.01, 1.0, 0.5, steps=50)
    spec["model"].update(topology="fixed", graph={"kind": "ring"})
    del spec["neighbours"]
    res = kernels.run(Scenario.model_validate(spec))
    assert set(res.extra["checks"]) == {"W_non_increasing"}
    vicsek = {"model": {"kind": "vicsek"}, "space": {"kind": "periodic", "L": 5.0},
              "neighbours": {"radius": 1.0}, "initial": {"kind": "random", "N": 20},
              "time": {"steps": 10}}
    assert "checks" not in kernels.run(Scenario.model_validate(vicsek)).extra


@pytest.mark.parametrize("precision,held", [("float64", False), ("float32", True)])
def test_rounding_is_not_a_rise(precision, held):
    obs = {"time": np.arange(3.0), "Q": np.array([1.0, 1.0 + 1e-7, 0.5])}
    check = monotone_checks({"Q": "claim"}, obs, precision)["Q_non_increasing"]
    assert check["held"] is held and check["rises"] == (0 if held else 1)


@pytest.mark.slow
def test_command_warns_and_summary_says_so(tmp_path):
    sc = tmp_path / "stiff.json"
    sc.write_text(json.dumps(m2(0.05, 0.7, 2.0)))
    proc = subprocess.run([sys.executable, "-m", "flocklab", "run", str(sc), "--out",
                           str(tmp_path / "out"), "--quiet"], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "warning: Q rose" in proc.stderr and "smaller time.dt" in proc.stderr
    assert "Traceback" not in proc.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["checks"]["Q_non_increasing"]["held"] is False
