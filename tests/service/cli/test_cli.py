"""The `flocklab` command as a user runs it: a real subprocess, real files."""

import json
import subprocess
import sys

import h5py
import numpy as np
import pytest

SMALL = {
    "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.05, "eta": 0.3},
    "space": {"kind": "periodic", "L": 8.0},
    "neighbours": {"radius": 1.0},
    "initial": {"kind": "random", "N": 500},
    "time": {"steps": 30},
    "recording": {"every": 10, "arrays": ["position", "heading"], "observables_every": 5},
    "seed": 5,
}


def flocklab(*args, stdin=None):
    return subprocess.run([sys.executable, "-m", "flocklab", *args], capture_output=True,
                          text=True, input=stdin, timeout=300)


@pytest.mark.slow
def test_run_writes_every_artifact(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps(SMALL))
    out = tmp_path / "out"
    proc = flocklab("run", str(path), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "eta" not in proc.stderr  # no progress bar when stderr is not a terminal
    assert json.loads(proc.stdout)["status"] == "completed"  # stdout: one JSON line
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["backend"] == "cpu"
    assert summary["steps"] == 30 and summary["agent_steps_per_second"] > 0
    assert 0 <= summary["final"]["polarization"] <= 1
    assert "heading_spread" in summary["convergence"]
    table = np.genfromtxt(out / "observables.csv", delimiter=",", names=True)
    assert list(table["step"]) == [0, 5, 10, 15, 20, 25, 30]
    with h5py.File(out / "trajectory.h5") as f:
        assert list(f["h5md"].attrs["version"]) == [1, 1]
        assert [b.decode() for b in f["particles/swarm/box"].attrs["boundary"]] == ["periodic"] * 2
        assert list(f["particles/swarm/box/edges"][:]) == [8.0, 8.0]
        pos = f["particles/swarm/position/value"]
        assert pos.shape == (4, 500, 2)
        assert list(f["particles/swarm/position/step"][:]) == [0, 10, 20, 30]
        assert f["particles/swarm/heading/value"].shape == (4, 500)
        assert ((pos[...] >= 0) & (pos[...] < 8.0)).all()
        pol = f["observables/polarization/value"][:]
        assert pol[-1] == pytest.approx(summary["final"]["polarization"])
    assert json.loads((out / "scenario.json").read_text())["seed"] == 5
    # Refuses to overwrite without being asked; leaves the folder as it was.
    again = flocklab("run", str(path), "--out", str(out))
    assert again.returncode == 2 and "--overwrite" in again.stderr
    assert json.loads((out / "summary.json").read_text()) == summary


def test_validate_reports_every_problem_at_once(tmp_path):
    bad = dict(SMALL, model={"kind": "vicsek", "rule": "laplacian", "g": 10, "eta": True},
               time={"steps": -1, "dt": 0}, colour="red")
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    proc = flocklab("validate", str(path))
    assert proc.returncode == 2
    for fragment in ("model.eta", "time.steps", "time.dt", "colour"):
        assert fragment in proc.stderr, proc.stderr
    run = flocklab("run", str(path), "--out", str(tmp_path / "never"))
    assert run.returncode == 2 and not (tmp_path / "never").exists()


def test_validate_refuses_nan_and_explains_g(tmp_path):
    path = tmp_path / "nan.json"
    path.write_text(json.dumps(SMALL).replace('"eta": 0.3', '"eta": NaN'))
    proc = flocklab("validate", str(path))
    assert proc.returncode == 2 and "NaN" in proc.stderr
    lap = dict(SMALL, model={"kind": "vicsek", "rule": "laplacian", "g": 100})
    proc = flocklab("validate", "-", stdin=json.dumps(lap))
    assert proc.returncode == 2 and "g > N" in proc.stderr


def test_models_lists_every_rule_with_equations():
    proc = flocklab("models")
    assert proc.returncode == 0
    for text in ("vicsek", "laplacian", "eq. 22", "eta", "leader_heading"):
        assert text in proc.stdout
    catalog = json.loads(flocklab("models", "--json").stdout)
    assert any(m["kind"] == "vicsek" and m["json_schema"] for m in catalog)


def test_presets_run_by_name(tmp_path):
    listing = flocklab("presets")
    assert "vicsek-1995" in listing.stdout
    proc = flocklab("presets", "nope")
    assert proc.returncode == 2 and "vicsek-1995" in proc.stderr
    missing = flocklab("run", "does-not-exist.json", "--out", str(tmp_path / "x"))
    assert missing.returncode == 2 and "cannot read" in missing.stderr


def test_unavailable_gpu_backend_fails_clearly(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps(dict(SMALL, backend="cuda")))
    proc = flocklab("run", str(path), "--out", str(tmp_path / "gpu"))
    if proc.returncode == 0:
        pytest.skip("a CUDA device is present")
    assert proc.returncode == 3 and "cuda" in proc.stderr
    assert not (tmp_path / "gpu").exists()
