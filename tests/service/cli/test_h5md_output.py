"""The H5MD file's periodic images, units and frame storage options, from real runs."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from flocklab.schemas import Scenario, get_preset
from flocklab.service.execute import execute_to_dir
from flocklab.service.h5md import image_is_exact


def fast_vicsek(every: int = 1, **recording) -> Scenario:
    """Agents crossing the box's edges often: v0 = 0.5 per step in a box of side 5."""
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.5, "eta": 0.3},
        "space": {"kind": "periodic", "L": 5.0},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 40},
        "time": {"steps": 120, "dt": 1.0},
        "recording": {"every": every, "arrays": ["position", "heading"], **recording},
        "seed": 3,
    })


def test_image_unwraps_periodic_tracks(taichi_cpu, tmp_path):
    execute_to_dir(fast_vicsek(), tmp_path / "run")
    with h5py.File(tmp_path / "run" / "trajectory.h5") as f:
        swarm = f["particles/swarm"]
        pos = swarm["position/value"][:]
        image = swarm["image/value"][:]
        assert image.dtype == np.int32 and image.shape == pos.shape
        assert list(swarm["image/step"][:]) == list(swarm["position/step"][:])
        unwrapped = pos + image * swarm["box/edges"][:]
    assert np.abs(image).max() >= 2  # the agents did cross the edges, some twice
    # Vicsek agents move exactly v0 dt per step: the unwrapped tracks have no jumps.
    steps = np.linalg.norm(np.diff(unwrapped, axis=0), axis=-1)
    np.testing.assert_allclose(steps, 0.5, rtol=1e-9)


def test_no_image_when_frames_are_too_far_apart(taichi_cpu, tmp_path):
    scenario = fast_vicsek(every=5)  # 5 x 0.5 = L/2: a crossing could not be told apart
    assert not image_is_exact(scenario) and image_is_exact(fast_vicsek(every=4))
    execute_to_dir(scenario, tmp_path / "run")
    with h5py.File(tmp_path / "run" / "trajectory.h5") as f:
        assert "image" not in f["particles/swarm"] and "position" in f["particles/swarm"]


@pytest.mark.slow
def test_float32_and_gzip_frames(taichi_cpu, tmp_path):
    execute_to_dir(fast_vicsek(), tmp_path / "f64")
    execute_to_dir(fast_vicsek(precision="float32", compression="gzip"), tmp_path / "f32")
    with h5py.File(tmp_path / "f64" / "trajectory.h5") as a, \
            h5py.File(tmp_path / "f32" / "trajectory.h5") as b:
        full, small = a["particles/swarm/position/value"], b["particles/swarm/position/value"]
        assert full.dtype == np.float64 and full.compression is None
        assert small.dtype == np.float32 and small.compression == "gzip" and small.shuffle
        # The same run (computed in float64 either way), stored rounded to float32.
        np.testing.assert_array_equal(small[:], full[:].astype(np.float32))
        assert b["particles/swarm/heading/value"].dtype == np.float32
        assert b["observables/polarization/value"].dtype == np.float64
        # Half the bytes per value, and gzip on top: the frames take less than half.
        assert small.id.get_storage_size() < 0.5 * full.id.get_storage_size()


def test_recording_options_are_checked():
    with pytest.raises(ValueError, match="precision"):
        fast_vicsek(precision="float16")
    with pytest.raises(ValueError, match="compression"):
        fast_vicsek(compression="zstd")


def test_units_where_the_paper_states_them(taichi_cpu, tmp_path):
    doc = get_preset("tjp-switching").model_dump(mode="json")
    doc["time"]["steps"] = 20
    doc["recording"].update(every=10, arrays=["position", "velocity"])
    execute_to_dir(Scenario.model_validate(doc), tmp_path / "m2")
    with h5py.File(tmp_path / "m2" / "trajectory.h5") as f:
        assert list(f["h5md/modules/units"].attrs["version"]) == [1, 0]
        swarm = f["particles/swarm"]
        assert swarm["position/value"].attrs["unit"] == "m"
        assert swarm["position/time"].attrs["unit"] == "s"
        assert swarm["velocity/value"].attrs["unit"] == "m s-1"
        assert f["observables/speed_mean/time"].attrs["unit"] == "s"
        assert [b.decode() for b in swarm["box"].attrs["boundary"]] == ["none", "none"]
    execute_to_dir(fast_vicsek(), tmp_path / "m1")
    with h5py.File(tmp_path / "m1" / "trajectory.h5") as f:  # dimensionless: no units
        assert "modules" not in f["h5md"]
        assert "unit" not in f["particles/swarm/position/value"].attrs
        assert f["particles/swarm/heading/value"].attrs["unit"] == "rad"
