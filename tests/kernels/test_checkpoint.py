"""Checkpoint and resume (docs/CHECKPOINTS.md): a real `flocklab run` killed with SIGKILL
at random moments and resumed with `--resume` ends with the frames, observables and final
state of the uninterrupted run, bit for bit; a run stopped in process resumes the same
way; corrupted, foreign, other-version and missing checkpoints are refused with a clear
message and exit code 2."""

from __future__ import annotations

import json
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from flocklab.schemas import Scenario
from flocklab.service import cli
from flocklab.service.checkpoints import CHECKPOINT, payload_hash
from flocklab.service.execute import execute_to_dir

ROOT = Path(__file__).resolve().parents[2]
# Summary fields that differ between any two runs of the same scenario.
TIMINGS = {"wall_seconds", "agent_steps_per_second", "setup_seconds", "resumed_from_step"}


def vicsek(rule: str = "vicsek", n: int = 300, steps: int = 400, every: int = 50,
           seed: int = 7, density: float = 2.0) -> dict:
    return {
        "model": {"kind": "vicsek", "rule": rule, "v0": 0.1, "eta": 1.0},
        "space": {"kind": "periodic", "L": (n / density) ** 0.5},
        "neighbours": {"radius": 1.0}, "initial": {"kind": "random", "N": n},
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"every": 30, "arrays": ["position", "heading"],
                      "observables_every": 7, "checkpoint_every": every},
        "seed": seed, "backend": "cpu",
    }


def flocking(steps: int, every: int) -> dict:
    d = json.loads((ROOT / "examples/flocking_switching.json").read_text())
    d["time"]["steps"] = steps
    d["recording"] = {"every": 70, "arrays": ["position", "velocity"],
                      "observables_every": 10, "checkpoint_every": every}
    return d


def datasets(path: Path) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    with h5py.File(path) as f:
        f.visititems(lambda n, o: out.__setitem__(n, o[()])
                     if isinstance(o, h5py.Dataset) else None)
    return out


def assert_same_run(ref: Path, got: Path) -> None:
    """Every dataset of trajectory.h5 (frames, images, observables, overlays), the
    observables.csv bytes and the summary but for its timings: equal."""
    a, b = datasets(ref / "trajectory.h5"), datasets(got / "trajectory.h5")
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k
    assert any(k.endswith("position/value") for k in a)
    assert (ref / "observables.csv").read_bytes() == (got / "observables.csv").read_bytes()
    sa, sb = (json.loads((d / "summary.json").read_text()) for d in (ref, got))
    assert {k: v for k, v in sa.items() if k not in TIMINGS} == {
        k: v for k, v in sb.items() if k not in TIMINGS}
    assert not (got / CHECKPOINT).exists() and not (got / "frames").exists()


def flocklab(*args: str) -> list[str]:
    return [sys.executable, "-m", "flocklab", *args]


def partial_checkpoint(out: Path) -> Path | None:
    found = sorted(out.parent.glob(f".{out.name}.partial-*/{CHECKPOINT}"))
    return found[-1] if found else None


def kill_and_resume(scenario: Path, out: Path, path: str, seed: int, kills: int) -> int:
    """Run, SIGKILL it a random moment after a new checkpoint lands, resume, and so on
    `kills` times; then resume to the end. Returns the kills that hit a running run."""
    rng = random.Random(seed)
    args = ["run", str(scenario), "--out", str(out), "--quiet", "--path", path]
    hit = 0
    for _ in range(kills):
        ck = partial_checkpoint(out)
        before = ck.stat().st_mtime_ns if ck else 0
        proc = subprocess.Popen(flocklab(*args), stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE)
        deadline = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < deadline:
            ck = partial_checkpoint(out)
            if ck is not None and ck.stat().st_mtime_ns != before:
                break
            time.sleep(0.02)
        time.sleep(rng.uniform(0.0, 0.8))  # a random moment: mid-step, mid-frame, mid-write
        running = proc.poll() is None
        proc.send_signal(signal.SIGKILL)
        _, err = proc.communicate()
        assert proc.returncode in (0, -signal.SIGKILL), err.decode()
        # Ended before the kill, or killed on its way out with its folder complete: that
        # kill hit no running run, and there is nothing left to resume.
        if proc.returncode == 0 or (out / "summary.json").exists():
            return hit
        hit += running
        args = ["run", "--resume", str(out), "--quiet"]
    done = subprocess.run(flocklab(*args), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["resumed_from_step"] > 0
    return hit


CASES = {
    "vicsek-fused": (vicsek(n=2000, steps=4000, every=250), "fused"),
    # The rule "average" tracks Theorem 2's linked intervals: at density 1 an interval
    # spans tens of steps, so a checkpoint falls inside one (a forest to carry over).
    "vicsek-average-per_step": (vicsek("average", n=400, steps=2500, every=150, density=1.0),
                                "per_step"),
    "flocking-fused": (flocking(2500, 200), "fused"),
    "flocking-per_step": (flocking(2500, 200), "per_step"),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_kill_9_at_random_moments_then_resume_is_bit_identical(tmp_path, case):
    data, path = CASES[case]
    scenario = tmp_path / "scenario.json"
    scenario.write_text(json.dumps(data))
    ref = tmp_path / "ref"
    done = subprocess.run(flocklab("run", str(scenario), "--out", str(ref), "--quiet",
                                   "--path", path), capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert json.loads((ref / "summary.json").read_text())["engine_path"] == path
    out = tmp_path / "killed"
    hit = kill_and_resume(scenario, out, path, seed=len(case), kills=3)
    assert hit >= 2, "the runs ended before the kills: make them longer"
    assert_same_run(ref, out)
    assert not list(tmp_path.glob(".killed.partial-*"))


def stopped_run(tmp: Path, data: dict, name: str = "run", path: str = "auto") -> Path:
    """A run stopped (as by Ctrl-C) once its first checkpoint is on disk."""
    out = tmp / name
    execute_to_dir(Scenario.model_validate(data), out, stopped_status="interrupted", path=path,
                   should_stop=lambda: partial_checkpoint(out) is not None)
    assert json.loads((out / "summary.json").read_text())["status"] == "interrupted"
    assert (out / CHECKPOINT).exists()
    return out


@pytest.mark.parametrize("path", ["fused", "per_step"])
@pytest.mark.slow_cases("per_step")  # the fused twin stays fast
def test_a_stopped_run_resumes_to_the_uninterrupted_bits(tmp_path, capsys, path):
    # Theorem 2's intervals at density 1 span tens of steps: the one open at the
    # checkpoint (step 40) goes on after it.
    data = vicsek(rule="average", n=200, steps=300, every=40, density=1.0)
    ref = tmp_path / "ref"
    execute_to_dir(Scenario.model_validate(data), ref, path=path)
    out = stopped_run(tmp_path, data, path=path)
    assert cli.main(["run", "--resume", str(out), "--quiet"]) == 0
    line = json.loads(capsys.readouterr().out)
    assert line["status"] == "completed" and line["resumed_from_step"] == 40
    assert_same_run(ref, out)
    linked = json.loads((out / "summary.json").read_text())["linked_intervals"]
    assert linked["count"] > 0 and linked["longest_steps"] > 40
    # Finished: nothing left to resume.
    assert cli.main(["run", "--resume", str(out)]) == 2
    assert "nothing to resume" in capsys.readouterr().err


def refused(out: Path, capsys) -> str:
    assert cli.main(["run", "--resume", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "cannot resume" in err
    return err


def test_corrupted_foreign_and_other_version_checkpoints_are_refused(tmp_path, capsys):
    out = stopped_run(tmp_path, vicsek(n=100, steps=120, every=30))
    good = (out / CHECKPOINT).read_bytes()
    scenario = tmp_path / "scenario.json"
    shutil.copy(out / "scenario.json", scenario)
    # A flipped byte in the middle of the arrays, and a truncated file.
    bad = bytearray(good)
    bad[len(bad) // 2] ^= 0xFF
    (out / CHECKPOINT).write_bytes(bytes(bad))
    assert "corrupted" in refused(out, capsys)
    (out / CHECKPOINT).write_bytes(good[: len(good) // 3])
    assert "corrupted" in refused(out, capsys)
    # Another scenario's checkpoint (another seed) put in this folder.
    other = stopped_run(tmp_path, vicsek(n=100, steps=120, every=30, seed=8), "other")
    shutil.copy(other / CHECKPOINT, out / CHECKPOINT)
    assert "another scenario" in refused(out, capsys)
    # Written by an engine whose bits differ (its fingerprint's engine_bits), intact.
    with np.load(other / CHECKPOINT) as z:
        state = {k: z[k] for k in z.files}
    meta = json.loads(str(state.pop("__meta__")))
    assert meta["payload_sha256"] == payload_hash(state)
    shutil.copy(other / "scenario.json", out / "scenario.json")
    for key, value in (("engine_bits", "0.0-older"), ("flocklab_version", "0.0.1")):
        np.savez(out / CHECKPOINT, **state,
                 __meta__=np.array(json.dumps({**meta, key: value})))
        assert value in refused(out, capsys)
    # Another run's scenario and intact checkpoint, over this run's frames.
    shutil.copy(other / CHECKPOINT, out / CHECKPOINT)
    assert "frames" in refused(out, capsys)
    # The folder is left as it was: still the stopped run's results, which resume.
    assert json.loads((out / "summary.json").read_text())["status"] == "interrupted"
    shutil.copy(scenario, out / "scenario.json")
    (out / CHECKPOINT).write_bytes(good)
    assert cli.main(["run", "--resume", str(out), "--quiet"]) == 0


def test_resume_needs_a_checkpoint_and_takes_no_scenario(tmp_path, capsys):
    assert cli.main(["run", "--resume", str(tmp_path / "none")]) == 2
    assert "no checkpoint to resume from" in capsys.readouterr().err
    assert cli.main(["run", "preset:vicsek-1995", "--resume", str(tmp_path)]) == 2
    assert "give it alone" in capsys.readouterr().err
