"""trajectory.gsd (recording.format gsd, `flocklab convert`): from real 2D and 3D runs, it
reads back through gsd.hoomd equal to the run's trajectory.h5 (positions shifted into
HOOMD's origin-centred box, float32), OVITO's `ovito.io.import_file` opens it with the
same positions and cell, and freud, given the frame's box, counts each agent's neighbours
as flocklab's own recorded `degree` (periodic) or a brute-force count (unbounded)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import gsd.hoomd
import h5py
import numpy as np
import pytest
from pydantic import ValidationError

from flocklab.schemas import Scenario
from flocklab.service.execute import execute_to_dir

pytestmark = pytest.mark.usefixtures("taichi_cpu")

X = np.array([1.0, 0.0, 0.0])


def vicsek(dimension: int, **recording) -> Scenario:
    """A periodic Vicsek run whose agents cross the edges (v0 = 0.3 in a box of side 4)."""
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.3, "eta": 0.4},
        "space": {"kind": "periodic", "L": 4.0, "dimension": dimension},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 60},
        "time": {"steps": 12, "dt": 1.0},
        "recording": {"every": 3, "arrays": ["position", "heading", "degree"],
                      "format": ["h5md", "gsd"], **recording},
        "seed": 7,
    })


def flocking(dimension: int) -> Scenario:
    """An unbounded flocking run (velocities, time step 0.01)."""
    return Scenario.model_validate({
        "model": {"kind": "flocking", "topology": "switching",
                  "potential": {"kind": "log_barrier", "d": 1.0}},
        "space": {"kind": "plane", "dimension": dimension},
        "neighbours": {"radius": 1.5},
        "initial": {"kind": "random", "N": 50, "speed_range": [0.0, 1.0],
                    "region": {"kind": "lattice", "low": [0.0] * dimension, "spacing": 1.1,
                               "jitter": 0.2}},
        "time": {"steps": 40, "dt": 0.01},
        "recording": {"every": 10, "arrays": ["position", "velocity"],
                      "format": ["h5md", "gsd"]},
        "seed": 1,
    })


def read_h5(run: Path) -> dict[str, np.ndarray]:
    with h5py.File(run / "trajectory.h5") as f:
        swarm = f["particles/swarm"]
        out = {name: swarm[f"{name}/value"][:] for name in swarm if name != "box"}
        out["step"] = swarm["position/step"][:]
        out["time"] = swarm["position/time"][:]
    return out


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v rotated by the unit quaternions q (w, x, y, z): v + 2w (u x v) + 2u x (u x v)."""
    w, u = q[:, :1], q[:, 1:]
    t = 2 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def check_equal(run: Path, scenario: Scenario) -> list[gsd.hoomd.Frame]:
    """trajectory.gsd holds trajectory.h5's frames, as the GSD writer's docstring says."""
    h5 = read_h5(run)
    d = scenario.dimension
    periodic = scenario.space.kind == "periodic"
    with gsd.hoomd.open(run / "trajectory.gsd") as traj:
        frames = list(traj)
    assert len(frames) == len(h5["step"]) == scenario.n_frames
    for k, f in enumerate(frames):
        assert f.configuration.step == h5["step"][k]
        assert f.log["flocklab/time"][0] == h5["time"][k]
        assert f.configuration.dimensions == d
        assert f.particles.N == scenario.n_agents and f.particles.types == ["A"]
        np.testing.assert_array_equal(f.particles.typeid, 0)
        pos = h5["position"][k]
        box = np.asarray(f.configuration.box)
        if periodic:
            L = scenario.space.L
            np.testing.assert_array_equal(box, [L, L, L if d == 3 else 0, 0, 0, 0])
            want = (pos - L / 2).astype(np.float32)
        else:
            side = np.float32(4 * np.abs(pos).max())
            np.testing.assert_array_equal(box[:d], side)
            assert box[2] == (side if d == 3 else 0)
            want = pos.astype(np.float32)
        assert f.particles.position.dtype == np.float32
        np.testing.assert_array_equal(f.particles.position[:, :d], want)
        np.testing.assert_array_equal(f.particles.position[:, d:], 0)
        # Inside HOOMD's box [-L/2, L/2)^D.
        assert np.all(np.abs(f.particles.position[:, :d]) <= box[:d] / 2)
        if "velocity" in h5:
            np.testing.assert_array_equal(f.particles.velocity[:, :d],
                                          h5["velocity"][k].astype(np.float32))
        if "heading" in h5:
            q = f.particles.orientation.astype(np.float64)
            np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-6)
            h = h5["heading"][k]
            heading = np.column_stack([np.cos(h), np.sin(h), 0 * h]) if d == 2 else h
            np.testing.assert_allclose(rotate(q, np.tile(X, (len(q), 1))), heading,
                                       atol=1e-6)
        if "image" in h5:
            np.testing.assert_array_equal(f.particles.image[:, :d], h5["image"][k])
        if "degree" in h5:
            np.testing.assert_array_equal(f.log["particles/degree"], h5["degree"][k])
    return frames


def freud_degree(frame: gsd.hoomd.Frame, r: float) -> np.ndarray:
    """Each agent's neighbours within r (itself excluded), by freud in the frame's box."""
    import freud

    box = freud.box.Box.from_box(frame.configuration.box,
                                 dimensions=int(frame.configuration.dimensions))
    points = frame.particles.position
    nlist = freud.locality.AABBQuery(box, points).query(
        points, {"r_max": r, "exclude_ii": True}).toNeighborList()
    return np.bincount(nlist.query_point_indices, minlength=len(points))


def check_ovito(run: Path, frames: list[gsd.hoomd.Frame]) -> None:
    """OVITO's importer: every frame, the same positions and the box as its cell."""
    from ovito.io import import_file

    pipeline = import_file(str(run / "trajectory.gsd"))
    assert pipeline.num_frames == len(frames)
    for k in (0, len(frames) - 1):
        data = pipeline.compute(k)
        f = frames[k]
        np.testing.assert_array_equal(data.particles.positions[...], f.particles.position)
        d = int(f.configuration.dimensions)
        assert data.cell.is2D == (d == 2)
        np.testing.assert_allclose(np.diag(data.cell[:d, :d]), f.configuration.box[:d])
        np.testing.assert_allclose(data.cell[:d, 3], -np.asarray(f.configuration.box[:d]) / 2)


@pytest.mark.slow_cases("2")
@pytest.mark.parametrize("dimension", [2, 3])
def test_periodic_vicsek_gsd_equals_h5md_and_opens_in_ovito_and_freud(tmp_path, dimension):
    scenario = vicsek(dimension)
    execute_to_dir(scenario, tmp_path / "run")
    frames = check_equal(tmp_path / "run", scenario)
    assert "image" in read_h5(tmp_path / "run")  # the agents' images are in both files
    assert np.abs(frames[-1].particles.image).max() >= 1
    check_ovito(tmp_path / "run", frames)
    # freud in the GSD box finds flocklab's own neighbourhoods (|r_ij| <= 1, periodic).
    degree = read_h5(tmp_path / "run")["degree"]
    for k, f in enumerate(frames):
        np.testing.assert_array_equal(freud_degree(f, 1.0), degree[k])
    assert degree.max() > 0


@pytest.mark.parametrize("dimension", [2, 3])
def test_unbounded_flocking_gsd_equals_h5md_and_freud_sees_true_distances(tmp_path,
                                                                          dimension):
    scenario = flocking(dimension)
    execute_to_dir(scenario, tmp_path / "run")
    frames = check_equal(tmp_path / "run", scenario)
    check_ovito(tmp_path / "run", frames)
    # The box of side 4 max|x| leaves no periodic image near: freud's counts are the
    # plane's, for a radius up to the frame's whole extent.
    for f in frames:
        p = f.particles.position.astype(np.float64)
        dist = np.linalg.norm(p[:, None] - p[None], axis=-1)
        for r in (1.5, 0.9 * dist.max()):
            np.testing.assert_array_equal(freud_degree(f, r), (dist < r).sum(1) - 1)


def flocklab(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "flocklab", *args], capture_output=True,
                          text=True, timeout=300)


def test_convert_existing_run_gives_the_runs_own_gsd(tmp_path):
    """A run recorded to H5MD only, converted, is byte for byte the GSD file the same run
    writes with recording.format [h5md, gsd] (same seed, same bits)."""
    execute_to_dir(vicsek(2, format="h5md"), tmp_path / "old")
    execute_to_dir(vicsek(2), tmp_path / "new")
    assert not (tmp_path / "old" / "trajectory.gsd").exists()
    proc = flocklab("convert", str(tmp_path / "old"), "--to", "gsd")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"{tmp_path / 'old' / 'trajectory.gsd'}: 5 frames"
    assert ((tmp_path / "old" / "trajectory.gsd").read_bytes()
            == (tmp_path / "new" / "trajectory.gsd").read_bytes())
    check_equal(tmp_path / "old", vicsek(2))
    assert not [p for p in (tmp_path / "old").iterdir() if p.name.startswith(".")]


def test_gsd_alone_keeps_observables_in_h5_and_frames_in_gsd(tmp_path):
    scenario = vicsek(3, format="gsd")
    summary = execute_to_dir(scenario, tmp_path / "run")
    assert summary["frames"] == 5 and "trajectory.gsd" in summary["files"]
    with h5py.File(tmp_path / "run" / "trajectory.h5") as f:
        assert "position" not in f["particles/swarm"] and "polarization" in f["observables"]
    with gsd.hoomd.open(tmp_path / "run" / "trajectory.gsd") as traj:
        assert len(traj) == 5 and traj[4].configuration.step == 12
        assert np.abs(traj[4].particles.image).max() >= 1  # tracked by the GSD writer
    proc = flocklab("convert", str(tmp_path / "run"), "--to", "gsd", "--overwrite")
    assert proc.returncode == 2 and "holds no frames" in proc.stderr


@pytest.mark.slow
def test_convert_bad_input_is_one_line_and_exit_2(tmp_path):
    execute_to_dir(vicsek(2), tmp_path / "run")
    (tmp_path / "empty").mkdir()
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "trajectory.h5").write_text("not HDF5")
    cases = [([str(tmp_path / "nowhere")], "no such run folder"),
             ([str(tmp_path / "empty")], "has no trajectory.h5"),
             ([str(tmp_path / "junk")], "not a readable HDF5 file"),
             ([str(tmp_path / "run")], "exists (--overwrite replaces it)")]
    before = (tmp_path / "run" / "trajectory.gsd").read_bytes()
    for args, message in cases:
        proc = flocklab("convert", *args, "--to", "gsd")
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0] and "Traceback" not in proc.stderr
    assert (tmp_path / "run" / "trajectory.gsd").read_bytes() == before
    assert not (tmp_path / "empty" / "trajectory.gsd").exists()
    proc = flocklab("convert", str(tmp_path / "run"), "--to", "xyz")
    assert proc.returncode == 2 and "invalid choice" in proc.stderr


@pytest.mark.parametrize("recording, message", [
    ({"format": "gsd"}, "recording.every > 0"),  # every 0: no frames
    ({"every": 1, "format": "gsd", "arrays": ["heading"]}, "position in recording.arrays"),
    ({"every": 1, "format": ["gsd", "gsd"]}, "at most once"),
    ({"every": 1, "format": []}, "at least one"),
])
def test_format_refusals(recording, message):
    doc = json.loads(vicsek(2).model_dump_json())
    doc["recording"] = {"arrays": ["position"], **recording}
    with pytest.raises(ValidationError, match=message.replace("(", r"\(")):
        Scenario.model_validate(doc)
    assert Scenario.model_validate({**doc, "recording": {}}).recording.formats == ("h5md",)
