"""One version: pyproject.toml's, read from the installed metadata by
`flocklab.schemas.version` and reported unchanged by everything that names a version
(`flocklab.__version__`, the OpenAPI document, the client's User-Agent, summary.json,
sweep.json and the H5MD creator); no source file writes it again."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import pytest

import flocklab
from flocklab.clients import _core
from flocklab.schemas.version import version
from tests.project_version import VERSION

ROOT = Path(__file__).resolve().parents[2]
SOURCES = ("schemas", "kernels", "service", "clients", "flocklab")
TINY = {"model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5},
        "space": {"kind": "periodic", "L": 4.0}, "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 20}, "time": {"steps": 5},
        "recording": {"every": 5, "observables_every": 5}, "seed": 1}


def test_the_installed_version_is_pyprojects():
    assert version() == VERSION == flocklab.__version__


def test_no_source_file_writes_the_version_again():
    copies = [f"{p.relative_to(ROOT)}:{n}"
              for top in SOURCES for p in sorted((ROOT / top).rglob("*"))
              if p.suffix in {".py", ".js", ".html"} and "__pycache__" not in p.parts
              for n, line in enumerate(p.read_text().splitlines(), 1)
              if f'"{VERSION}"' in line or f"'{VERSION}'" in line]
    assert copies == []


def test_the_service_and_the_client_report_it(tmp_path):
    from flocklab.service.app.factory import create_app
    from flocklab.service.app.settings import load_settings

    app = create_app(load_settings(data_dir=tmp_path))  # no lifespan: nothing starts
    assert app.openapi()["info"]["version"] == VERSION
    assert _core.headers(None)["User-Agent"] == f"flocklab-client/{VERSION}"


@pytest.mark.slow
def test_run_and_sweep_folders_record_it(tmp_path):
    scenario = tmp_path / "s.json"
    scenario.write_text(json.dumps(TINY))
    sweep = tmp_path / "w.json"
    sweep.write_text(json.dumps({"name": "v", "base": TINY, "axes": [{"path": "model.eta",
                                                          "values": [0.5]}],
                                 "measure": {"va": {"observable": "polarization",
                                                    "reduce": "final"}}}))
    for cmd in (["run", str(scenario), "--out", str(tmp_path / "run")],
                ["sweep", str(sweep), "--out", str(tmp_path / "sweep")]):
        proc = subprocess.run([sys.executable, "-m", "flocklab", *cmd, "--quiet"],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["flocklab_version"] == VERSION
    with h5py.File(tmp_path / "run" / "trajectory.h5") as f:
        assert f["h5md/creator"].attrs["version"] == VERSION
    doc = json.loads((tmp_path / "sweep" / "sweep.json").read_text())
    assert doc["flocklab_version"] == VERSION
    (run_summary,) = (tmp_path / "sweep" / "runs").glob("*/summary.json")
    assert json.loads(run_summary.read_text())["flocklab_version"] == VERSION
