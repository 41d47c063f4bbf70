"""Checkpoint and resume of the formation model (Xi-Abed F1/F2 with virtual leaders,
docs/CHECKPOINTS.md): on both schedules, in 2D and 3D, a run stopped once a checkpoint is
on disk and resumed ends with the frames, observables and final state of the
uninterrupted run, bit for bit, across F1's formation changes (a rotation, and a morph
through a third stored formation), a spline leader, RK4, F2's D1-D3 and the dense
regime's coarse steps; a real `flocklab run` killed with SIGKILL at random moments
resumes the same way; a corrupted or foreign checkpoint is refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from flocklab.schemas import Scenario
from flocklab.service import cli
from flocklab.service.checkpoints import CHECKPOINT
from flocklab.service.execute import execute_to_dir
from tests.kernels.test_checkpoint import (
    assert_same_run,
    flocklab,
    kill_and_resume,
    refused,
    stopped_run,
)

ROOT = Path(__file__).resolve().parents[2]


def example(name: str, steps: int, every: int, **model: object) -> dict:
    """An example scenario cut to `steps`, checkpointing every `every` steps, with frames
    (positions and velocities: the latter reads the leader at the frame's time) and
    observations off the checkpoint grid."""
    d = json.loads((ROOT / "examples" / name).read_text())
    d["time"]["steps"] = steps
    d["model"].update(model)
    d["recording"] = {"every": 45, "arrays": ["position", "velocity"],
                      "observables_every": 15, "checkpoint_every": every}
    d["backend"] = "cpu"
    return d


MORPHS = [{"start": 2.0, "end": 4.0, "rotate": 1.0},
          {"start": 5.0, "end": 7.0, "formation": {"kind": "named", "shape": "line"}},
          {"start": 8.0, "end": 9.0, "formation": {"kind": "named", "shape": "circle"}}]

# (scenario, schedule, step of the checkpoint the stopped run lands with)
CASES = {
    # F1 2D: the rotation over t in [8, 12] is under way at the checkpoint (step 900).
    "f1-2d-fused": (example("formation_f1.json", 1400, 900), "fused"),
    "f1-2d-per_step": (example("formation_f1.json", 1400, 900), "per_step"),
    # Three stored formations (two morphs): the device slots are refilled as they go.
    "f1-2d-morphs-per_step": (example("formation_f1.json", 1000, 550, schedule=MORPHS),
                              "per_step"),
    "f1-2d-morphs-rk4-fused": (example("formation_f1.json", 1000, 550, schedule=MORPHS,
                                       integrator="rk4"), "fused"),
    "f2-2d-fused": (example("formation_f2.json", 600, 240), "fused"),
    "f2-2d-per_step": (example("formation_f2.json", 600, 240), "per_step"),
    # F1 3D: a spline leader and a rotation about the x axis from t = 8.
    "f1-3d-fused": (example("formation_3d.json", 1100, 850), "fused"),
    "f1-3d-rk4-per_step": (example("formation_3d.json", 1000, 850, integrator="rk4"),
                           "per_step"),
}


def f2_3d(steps: int = 300, every: int = 120) -> dict:
    """F2 in 3D with D3 (a linear program per component, the host's on the fused path)."""
    d = example("formation_f2.json", steps, every)
    d["space"]["dimension"] = 3
    d["model"]["path"] = {"kind": "straight", "target": [-40.0, -40.0, 10.0],
                          "arrival_time": 20.0}
    d["initial"]["region"] = {"kind": "box", "low": [0.0] * 3, "high": [50.0] * 3}
    d["initial"]["N"] = 40
    return d


CASES["f2-3d-fused"] = (f2_3d(), "fused")
CASES["f2-3d-per_step"] = (f2_3d(), "per_step")


@pytest.mark.parametrize("case", list(CASES))
# Each case compiles its formation kernels (seconds): the fast lane keeps F1 and F2, 2D and
# 3D, both schedules and RK4; --all runs every case.
@pytest.mark.fast_cases("f1-2d-fused", "f1-2d-morphs-rk4-fused", "f2-3d-fused")
def test_a_stopped_formation_run_resumes_to_the_uninterrupted_bits(tmp_path, capsys, case):
    data, path = CASES[case]
    ref = tmp_path / "ref"
    execute_to_dir(Scenario.model_validate(data), ref, path=path)
    summary = json.loads((ref / "summary.json").read_text())
    assert summary["engine_path"] == path and summary["status"] == "completed"
    out = stopped_run(tmp_path, data, path=path)
    assert cli.main(["run", "--resume", str(out), "--quiet"]) == 0
    line = json.loads(capsys.readouterr().out)
    assert line["status"] == "completed"
    assert line["resumed_from_step"] == data["recording"]["checkpoint_every"]
    assert_same_run(ref, out)


@pytest.mark.slow
def test_dense_regime_counters_resume(tmp_path, capsys):
    """Euler steps coarse-grained (N = 300 in a small box, a low cap): the counters of
    the dense regime the summary reports go on from the checkpoint's."""
    data = example("formation_f2.json", 200, 80, max_exact_candidates=200)
    data["initial"]["N"] = 300
    data["initial"]["region"] = {"kind": "box", "low": [0.0, 0.0], "high": [30.0, 30.0]}
    ref = tmp_path / "ref"
    execute_to_dir(Scenario.model_validate(data), ref, path="per_step")
    dense = json.loads((ref / "summary.json").read_text())["dense_regime"]
    assert dense["steps"] > 80 and dense["max_reach"] > 1, dense
    out = stopped_run(tmp_path, data, path="per_step")
    assert cli.main(["run", "--resume", str(out), "--quiet"]) == 0
    assert json.loads(capsys.readouterr().out)["resumed_from_step"] == 80
    assert_same_run(ref, out)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["f1-2d-fused", "f1-3d-rk4-per_step"])
def test_kill_9_at_random_moments_then_resume_formation(tmp_path, case):
    data, path = CASES[case]
    data = {**data, "time": {**data["time"], "steps": 6000},
            "recording": {**data["recording"], "checkpoint_every": 300}}
    if path == "fused":  # ~0.2 us a step at N = 6 (the launch runs many): 30M steps take
        # seconds, so the kills land mid-run, not in the fixed cost of a process start
        data["time"]["steps"] = 30_000_000
        data["recording"].update(every=225_000, observables_every=75_000,
                                 checkpoint_every=1_500_000)
    if data["space"].get("dimension") == 3:  # the spline's leader: slower per step
        data["time"]["steps"] = 2500
        data["model"]["path"]["arrival_time"] = 40.0
    scenario = tmp_path / "scenario.json"
    scenario.write_text(json.dumps(data))
    ref = tmp_path / "ref"
    import subprocess

    done = subprocess.run(flocklab("run", str(scenario), "--out", str(ref), "--quiet",
                                   "--path", path), capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    out = tmp_path / "killed"
    hit = kill_and_resume(scenario, out, path, seed=len(case), kills=3)
    assert hit >= 2, "the runs ended before the kills: make them longer"
    assert_same_run(ref, out)


def test_corrupted_and_foreign_formation_checkpoints_are_refused(tmp_path, capsys):
    data = example("formation_f1.json", 300, 120)
    out = stopped_run(tmp_path, data, path="per_step")
    good = (out / CHECKPOINT).read_bytes()
    bad = bytearray(good)
    bad[len(bad) // 2] ^= 0xFF
    (out / CHECKPOINT).write_bytes(bytes(bad))
    assert "corrupted" in refused(out, capsys)
    # A checkpoint of the same model with another seed: another scenario.
    other = stopped_run(tmp_path, {**data, "seed": 2}, "other", path="per_step")
    shutil.copy(other / CHECKPOINT, out / CHECKPOINT)
    assert "another scenario" in refused(out, capsys)
    # The folder is left as it was: the stopped run's results, which resume.
    assert json.loads((out / "summary.json").read_text())["status"] == "interrupted"
    (out / CHECKPOINT).write_bytes(good)
    assert cli.main(["run", "--resume", str(out), "--quiet"]) == 0
    capsys.readouterr()


def test_a_checkpoint_of_another_model_under_a_formation_fingerprint_is_refused(
        tmp_path, capsys):
    """A Vicsek run's arrays (as many agents) under a formation run's fingerprint: the
    fingerprint's checks pass, the arrays do not fit the formation kernel; the refusal
    says so, without a traceback."""
    out = stopped_run(tmp_path, example("formation_f1.json", 300, 120), path="per_step")
    vic = stopped_run(tmp_path, {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.1, "eta": 1.0},
        "space": {"kind": "periodic", "L": 5.0}, "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 6}, "time": {"steps": 300, "dt": 1.0},
        "recording": {"every": 45, "arrays": ["position"], "observables_every": 15,
                      "checkpoint_every": 120},
        "seed": 1, "backend": "cpu"}, "vicsek", path="per_step")
    with np.load(vic / CHECKPOINT) as z:
        state = {k: z[k] for k in z.files}
    with np.load(out / CHECKPOINT) as z:
        own = json.loads(str(z["__meta__"]))
    meta = json.loads(str(state.pop("__meta__")))
    for key in ("scenario_sha256", "frames", "frames_chain"):
        meta[key] = own[key]
    np.savez(out / CHECKPOINT, **state, __meta__=np.array(json.dumps(meta)))
    err = refused(out, capsys)
    assert "does not fit" in err and "formation" in err, err
