"""A 3D run through the `flocklab` command: H5MD with dimension 3, (F, N, 3) frames; a 3D
scenario for a 2D-only rule refused with the field named, no traceback."""

import copy
import json

import h5py
import numpy as np
import pytest

from tests.service.cli.test_cli import SMALL, flocklab

SMALL_3D = copy.deepcopy(SMALL)
SMALL_3D["space"] = {"kind": "periodic", "L": 5.0, "dimension": 3}


@pytest.mark.slow
def test_run_writes_a_3d_trajectory(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps(SMALL_3D))
    out = tmp_path / "out"
    proc = flocklab("run", str(path), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and 0 <= summary["final"]["polarization"] <= 1
    with h5py.File(out / "trajectory.h5") as f:
        box = f["particles/swarm/box"]
        assert box.attrs["dimension"] == 3
        assert [b.decode() for b in box.attrs["boundary"]] == ["periodic"] * 3
        assert list(box["edges"][:]) == [5.0] * 3
        pos = f["particles/swarm/position/value"]
        assert pos.shape == (4, 500, 3)
        assert ((pos[...] >= 0) & (pos[...] < 5.0)).all()
        head = f["particles/swarm/heading/value"][...]
        assert head.shape == (4, 500, 3)
        assert np.allclose(np.linalg.norm(head, axis=2), 1.0)


@pytest.mark.slow
def test_render_draws_a_3d_snapshot_and_plots_its_observables(tmp_path):
    """`flocklab render` of a 3D run: its last frame through the 3D camera (every agent),
    and its observables (tests/service/render/test_render_3d.py: the pictures themselves)."""
    path = tmp_path / "s.json"
    path.write_text(json.dumps({**SMALL_3D, "time": {"steps": 5}}))
    out = tmp_path / "out"
    assert flocklab("run", str(path), "--out", str(out)).returncode == 0
    proc = flocklab("render", str(out), "--out", str(tmp_path / "a.png"))
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["agents"] == SMALL_3D["initial"]["N"]
    assert (tmp_path / "a.png").read_bytes().startswith(b"\x89PNG")
    plot = flocklab("render", str(out), "--out", str(tmp_path / "b.png"), "--plot")
    assert plot.returncode == 0, plot.stderr
    assert (tmp_path / "b.png").stat().st_size > 0


def test_a_3d_angle_rule_is_refused_with_its_field(tmp_path):
    doc = copy.deepcopy(SMALL_3D)
    doc["model"]["rule"] = "average"
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc))
    proc = flocklab("validate", str(path))
    assert proc.returncode == 2
    assert "model" in proc.stderr and "2D only" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("example,preset", [("vicsek_3d", "vicsek-3d"),
                                            ("flocking_3d", "tjp-switching-3d")])
def test_the_3d_examples_and_presets_agree(example, preset):
    from pathlib import Path

    from flocklab.schemas import Scenario, get_preset

    path = Path(__file__).resolve().parents[3] / "examples" / f"{example}.json"
    sc = Scenario.model_validate_json(path.read_text())
    assert sc == get_preset(preset) and sc.dimension == 3
