"""Real runs of every model family, written by `service.execute.execute_to_dir`, shared
by the render tests (small N, a few hundred steps, plus one N = 10^5 Vicsek frame), in the
plane and in 3D."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from flocklab.schemas import Scenario, get_preset

pytest.importorskip("matplotlib")

# preset, overrides: short versions of the papers' runs (same N, fewer steps)
FAMILIES: dict[str, tuple[str, dict[str, Any]]] = {
    "vicsek": ("vicsek-1995", {"time": {"steps": 100}}),
    "flocking_fixed": ("tjp-fixed", {"time": {"steps": 1000}, "convergence": {"tolerance": 0.5}}),
    "flocking_switching": ("tjp-switching", {"time": {"steps": 1000}}),
    "flocking_obstacles": ("tanner-obstacles", {"time": {"steps": 1500}}),
    "formation_F1": ("xi-abed-sim1", {"time": {"steps": 1000}, "recording": {"every": 50}}),
    "formation_F2": ("xi-abed-sim3", {"time": {"steps": 1000}, "recording": {"every": 50}}),
}


# The same families in 3D (space.dimension = 3): the 3D presets shortened, the 2D presets
# lifted to 3D, and M3 with point and sphere obstacles
# (tests/kernels/flocking/test_flocking_3d.py's).
FAMILIES_3D: dict[str, tuple[str, dict[str, Any]]] = {
    "vicsek": ("vicsek-3d", {"initial": {"N": 500}, "space": {"L": 5.0},
                             "time": {"steps": 60}, "recording": {"every": 5}}),
    "flocking_fixed": ("tjp-fixed", {
        "space": {"dimension": 3},
        "initial": {"N": 12, "region": {"low": [-2.5, -2.5, -2.5], "high": [2.5, 2.5, 2.5]}},
        "time": {"steps": 600}, "convergence": {"tolerance": 0.5}}),
    "flocking_switching": ("tjp-switching-3d", {"initial": {"N": 64},
                                                "time": {"steps": 400}}),
    "formation_F1": ("xi-abed-f1-3d", {"time": {"steps": 1000}, "recording": {"every": 50}}),
    "formation_F2": ("xi-abed-sim3", {
        "space": {"dimension": 3},
        "model": {"path": {"target": [-40.0, -40.0, 20.0]}},
        "initial": {"N": 60, "region": {"low": [0.0, 0.0, 0.0], "high": [50.0, 50.0, 50.0]}},
        "time": {"steps": 1000}, "recording": {"every": 50}}),
}


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def preset_scenario(name: str, overrides: dict[str, Any]) -> Scenario:
    return Scenario.model_validate(merge(get_preset(name).model_dump(mode="json"), overrides))


def run_to(folder: Path, scenario: Scenario) -> Path:
    from flocklab.service.execute import execute_to_dir

    execute_to_dir(scenario, folder)
    return folder


@pytest.fixture(scope="session")
def runs(tmp_path_factory: pytest.TempPathFactory, taichi_cpu) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("render-runs")
    return {fam: run_to(root / fam, preset_scenario(name, over))
            for fam, (name, over) in FAMILIES.items()}


@pytest.fixture(scope="session")
def runs_3d(tmp_path_factory: pytest.TempPathFactory, taichi_cpu) -> dict[str, Path]:
    from tests.kernels.flocking.test_flocking_3d import m3_scenario

    root = tmp_path_factory.mktemp("render-runs-3d")
    out = {fam: run_to(root / fam, preset_scenario(name, over))
           for fam, (name, over) in FAMILIES_3D.items()}
    out["flocking_obstacles"] = run_to(root / "flocking_obstacles", m3_scenario(steps=150))
    return out


@pytest.fixture(scope="session")
def large_run(tmp_path_factory: pytest.TempPathFactory, taichi_cpu) -> Path:
    """10^5 Vicsek agents at density 4, two frames."""
    n = 100_000
    sc = Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5},
        "space": {"kind": "periodic", "L": math.sqrt(n / 4)},
        "neighbours": {"radius": 1.0}, "initial": {"kind": "random", "N": n},
        "time": {"steps": 2, "dt": 1.0},
        "recording": {"every": 1, "arrays": ["position", "heading"], "observables_every": 1},
        "seed": 5})
    return run_to(tmp_path_factory.mktemp("render-large") / "vicsek-1e5", sc)


@pytest.fixture(scope="session")
def large_runs(tmp_path_factory: pytest.TempPathFactory, taichi_cpu) -> dict[str, Path]:
    """10^5 agents of the other families: the benchmark's own large-N scenarios
    (bench/workload_*.py), ten steps, three frames."""
    from bench.workload_flocking import flocking_obstacles, flocking_switching
    from bench.workload_formation import f1, f2

    root = tmp_path_factory.mktemp("render-large-families")
    short = {"time": {"steps": 10}, "recording": {
        "every": 5, "arrays": ["position", "velocity"], "observables_every": 5}}
    return {name: run_to(root / name, Scenario.model_validate(merge(make(100_000), short)))
            for name, make in [("flocking_switching", flocking_switching),
                               ("flocking_obstacles", flocking_obstacles),
                               ("formation_F1", f1), ("formation_F2", f2)]}


def read_image(path_or_bytes: Path | bytes) -> np.ndarray:
    """An image file as an (H, W, C) uint8 array (imageio decodes PNG)."""
    import imageio.v3 as iio

    return iio.imread(path_or_bytes)


def assert_picture(img: np.ndarray, width: int, height: int, min_ink: float = 0.03) -> None:
    """The requested size, and not blank: enough non-white pixels of varied colour
    (line plots hold less ink than snapshots: they pass a lower `min_ink`)."""
    assert img.shape[:2] == (height, width), img.shape
    rgb = img[..., :3].astype(np.int16)
    ink = np.any(rgb < 235, axis=2).mean()
    assert ink > min_ink, f"only {ink:.3%} of the picture is drawn on"
    assert rgb.std() > 10, "the picture is (nearly) one colour"
