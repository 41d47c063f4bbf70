"""The `flocklab` conveniences, as a user meets them: --version, `models NAME`, the
no-frames warning of `validate`, and Ctrl-C during `run` (real subprocesses, real files)."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest

from flocklab.schemas import MODELS
from flocklab.service.cli_models import REFERENCES
from tests.project_version import VERSION

ROOT = Path(__file__).resolve().parents[3]


def flocklab(*args, stdin=None):
    return subprocess.run([sys.executable, "-m", "flocklab", *args], capture_output=True,
                          text=True, input=stdin, timeout=300)


def test_version():
    proc = flocklab("--version")
    assert proc.returncode == 0
    assert proc.stdout.strip() == f"flocklab {VERSION}"


def test_models_name_shows_one_model_and_its_documents():
    proc = flocklab("models", "formation")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("formation: ")
    assert "vicsek:" not in proc.stdout and "flocking:" not in proc.stdout
    assert f"details: {MODELS['formation'].details}" in proc.stdout
    assert f"full reference: {REFERENCES}" in proc.stdout
    one = json.loads(flocklab("models", "vicsek", "--json").stdout)
    assert one["kind"] == "vicsek" and one["references"] == REFERENCES
    assert {p["name"] for p in one["parameters"]} >= {"rule", "v0", "eta"}
    bad = flocklab("models", "boids")
    assert bad.returncode == 2
    assert "unknown model 'boids'" in bad.stderr and "vicsek" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_every_document_the_code_names_exists():
    """The files `flocklab models` and the code point to are in the checkout."""
    named = {REFERENCES, *(card.details for card in MODELS.values())}
    for text in (ROOT / "schemas").glob("*.py"):
        for word in text.read_text().split():
            if word.startswith("docs/") and word.rstrip("):.,").endswith(".md"):
                named.add(word.rstrip("):.,"))
    named.add("docs/SERVICE.md")  # service/jobs/problems.py documents problem types there
    missing = [d for d in sorted(named) if not (ROOT / d).is_file()]
    assert not missing, missing
    assert len(named) >= 4


def test_validate_warns_when_no_frames_are_recorded(tmp_path):
    doc = json.loads(flocklab("presets", "vicsek-1995").stdout)
    doc["recording"]["every"] = 0
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc))
    proc = flocklab("validate", str(path))
    assert proc.returncode == 0, proc.stderr
    assert "0 frames" in proc.stdout
    assert "warning" in proc.stderr and "records no frames" in proc.stderr
    quiet = flocklab("validate", "preset:vicsek-1995")
    assert quiet.returncode == 0 and "warning" not in quiet.stderr


@pytest.mark.slow
def test_ctrl_c_keeps_what_the_run_computed(tmp_path):
    """SIGINT (what Ctrl-C sends) stops the run between steps; the folder lands with
    status `interrupted`, the frames and observables so far, and exit code 1."""
    scenario = {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5},
        "space": {"kind": "periodic", "L": 16.0},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 1000},
        "time": {"steps": 1_000_000},
        "recording": {"every": 1000, "arrays": ["position"], "observables_every": 100},
        "seed": 1,
    }
    path = tmp_path / "long.json"
    path.write_text(json.dumps(scenario))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "flocklab", "run", str(path), "--out",
                             str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob(".out.partial-*")):  # the run has begun
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.1)
        time.sleep(4)  # past Taichi's start: some steps are computed
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, stderr
    assert "interrupted at step" in stderr and "Traceback" not in stderr
    assert json.loads(stdout)["status"] == "interrupted"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    assert 0 <= summary["steps"] < 1_000_000
    with h5py.File(out / "trajectory.h5") as f:
        steps = f["particles/swarm/position/step"][:]
        assert len(steps) == summary["frames"] >= 1
        assert steps[-1] == summary["steps"]  # the state at the stop is recorded
        assert f["observables/polarization/step"][-1] == summary["steps"]
    assert not list(tmp_path.glob(".out.partial-*"))
