"""M4 (Xi–Abed) on the plane's two grid layouts: the per-step kernel on the dense row-major
grid (kernels/space/plane_grid.py, the CPU's) against the same kernel on the hashed grid
(a GPU's policy, on the CPU). The neighbour sets are the same, only the order of each
agent's neighbour sum differs: positions, rates and observables agree to rounding, and the
graph observables (components, D1-D3, degrees) exactly. A swarm too sprawling for the dense
grid falls back to the hashed one, bit for bit."""

import numpy as np
import pytest

from flocklab.kernels.model import all_kernels
from flocklab.kernels.runtime import DevicePolicy
from flocklab.schemas import Scenario

D = 20.0
STRAIGHT = {"kind": "straight", "target": [-40.0, -30.0], "speed": 6.0}
HEX = {"kind": "named", "shape": "hex"}
EXACT = ("components", "D1", "D2", "D3", "isolated", "degree_mean")


def scenario(model: dict, init: dict, steps: int = 12, dim: int = 2) -> Scenario:
    return Scenario.model_validate({
        "model": {"kind": "formation", "path": STRAIGHT, **model},
        "space": {"kind": "plane", "dimension": dim},
        "neighbours": {"radius": D},
        "initial": init,
        "time": {"steps": steps, "dt": 0.002},
        "recording": {"every": 1, "arrays": ["position", "velocity"]},
        "seed": 7,
    })


def box(n: int, side: float, dim: int = 2) -> dict:
    return {"kind": "random", "N": n,
            "region": {"kind": "box", "low": [0.0] * dim, "high": [side] * dim}}


def trajectory(sc: Scenario, dense: bool) -> tuple[list, list, list, object]:
    """Per step: positions and rates in id order, and the observables; and the kernel."""
    k = all_kernels()["formation"](sc, DevicePolicy(serial_scatter=True, dense_grid=dense))
    pos, vel, obs = [], [], []
    for step in range(sc.time.steps):
        obs.append(k.observe(step))
        f = k.frame(["position", "velocity"])
        pos.append(f["position"])
        vel.append(f["velocity"])
        k.step(step)
    return pos, vel, obs, k


def assert_same_to_rounding(sc: Scenario, dense_layout: str) -> object:
    """The dense-policy kernel (whose grid ends in `dense_layout`) against the hashed one."""
    a_pos, a_vel, a_obs, k = trajectory(sc, dense=True)
    b_pos, b_vel, b_obs, h = trajectory(sc, dense=False)
    assert k.grid.layout == dense_layout and h.grid.layout == "hash"
    scale = max(np.abs(b_pos[0]).max(), 1.0)
    rate = max(np.abs(v).max() for v in b_vel)
    for step, (xa, xb, va, vb) in enumerate(zip(a_pos, b_pos, a_vel, b_vel, strict=True)):
        np.testing.assert_allclose(xa, xb, rtol=0, atol=1e-12 * scale, err_msg=f"step {step}")
        np.testing.assert_allclose(va, vb, rtol=0, atol=1e-12 * rate, err_msg=f"step {step}")
    for oa, ob in zip(a_obs, b_obs, strict=True):
        assert oa.keys() == ob.keys()
        for key in oa:
            if key in EXACT:
                assert oa[key] == ob[key], key
            else:
                assert oa[key] == pytest.approx(ob[key], rel=1e-12, abs=1e-12 * scale), key
    return k, a_pos, b_pos


CASES = {
    "F1-euler": dict(formation=HEX),
    "F1-rk4": dict(formation=HEX, integrator="rk4"),
    "F2-euler": dict(design="F2"),
    "F2-rk4": dict(design="F2", integrator="rk4", repulsion={"kind": "inverse", "k_g": 50.0}),
}


@pytest.mark.parametrize("name", list(CASES))
def test_dense_grid_matches_hashed(taichi_cpu, name):
    """400 agents, about 20 neighbours each: every step and observation on the dense grid."""
    sc = scenario(CASES[name], box(400, 150.0))
    assert_same_to_rounding(sc, "dense")


def test_dense_grid_matches_hashed_3d(taichi_cpu):
    sc = scenario({"design": "F2", "path": {**STRAIGHT, "target": [-40.0, -30.0, 25.0]}},
                  box(300, 60.0, 3), dim=3)
    assert_same_to_rounding(sc, "dense")


def test_sprawling_swarm_falls_back_to_the_hashed_grid(taichi_cpu):
    """Two clusters 10^5 apart: far more cells than CELLS_PER_AGENT per agent, so the
    dense policy builds the hashed grid, and the run is the hashed one bit for bit."""
    rng = np.random.default_rng(3)
    pts = np.concatenate([rng.uniform(0.0, 40.0, (30, 2)),
                          rng.uniform(0.0, 40.0, (30, 2)) + np.array([1e5, 0.0])])
    sc = scenario({"design": "F2"}, {"kind": "explicit", "positions": pts.tolist()})
    k, a_pos, b_pos = assert_same_to_rounding(sc, "hash")
    assert k.grid.dense is not None  # the policy allowed it: the swarm's extent refused it
    for xa, xb in zip(a_pos, b_pos, strict=True):
        assert np.array_equal(xa, xb)


def test_dense_regime_on_the_dense_grid(taichi_cpu):
    """Above max_exact_candidates the step coarse-grains on the (hashed) fine grid, sized
    by the densest cell of the dense d-grid: the same reach and steps as on the hashed."""
    sc = scenario({"design": "F2", "max_exact_candidates": 256},
                  {"kind": "random", "N": 3000, "region": {"kind": "disc", "radius": 50.0}},
                  steps=3)
    k = assert_same_to_rounding(sc, "dense")[0]
    regime = k.extra()["dense_regime"]
    assert regime["steps"] == 3 and regime["max_reach"] >= 2
