"""The Cucker–Smale engine against an independent numpy reference (reference.py) at small
N, on every schedule, in 2D and 3D, for every normalisation, all-to-all and with a
cutoff, under both integrators; and the model's properties: the mean velocity is
conserved (mean and sum normalisation: symmetric psi), and at beta = 0 every velocity
relaxes to the mean by exactly (1 - lambda K dt) per Euler step, by RK4's stability
polynomial per RK4 step (e^{-lambda K t} to fourth order)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from flocklab import kernels
from flocklab.schemas import Scenario, get_preset

from . import reference as ref

pytestmark = pytest.mark.usefixtures("taichi_cpu")
TOL = 1e-11
EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


class Frames:
    """A FrameSink keeping every frame."""

    def __init__(self) -> None:
        self.steps: list[int] = []
        self.pos: list[np.ndarray] = []
        self.vel: list[np.ndarray] = []

    def frame(self, step, time, arrays):
        self.steps.append(step)
        self.pos.append(np.array(arrays["position"]))
        self.vel.append(np.array(arrays["velocity"]))


def scenario(*, n=24, dim=2, steps=8, dt=0.05, side=4.0, every=1, **model) -> Scenario:
    return Scenario.model_validate({
        "model": {"kind": "cucker_smale", **model},
        "space": {"kind": "plane", "dimension": dim},
        "initial": {"kind": "random", "N": n,
                    "region": {"kind": "box", "low": [0.0] * dim, "high": [side] * dim},
                    "speed_range": [0.0, 1.0]},
        "time": {"steps": steps, "dt": dt},
        "recording": {"every": every, "arrays": ["position", "velocity"],
                      "observables_every": 1},
        "seed": 5,
    })


def run(sc: Scenario, path: str):
    sink = Frames()
    try:
        res = kernels.run(sc, path=path, sink=sink)
    except kernels.PathUnavailable as exc:
        pytest.skip(str(exc))
    assert res.status == "completed" and res.extra["engine_path"] == path
    return res, sink


def params(sc: Scenario) -> dict:
    p = sc.model
    return dict(K=p.K, sigma=p.sigma, beta=p.beta, coupling=p.coupling,
                normalization=p.normalization, cutoff=p.cutoff)


# The fast lane keeps a pairwise covering set: every two values of any two parameters meet
# in some fast case (each case compiles kernels of its own; the whole grid runs with --all).
@pytest.mark.fast_cases("2-mean-None-semi_implicit_euler-per_step", "3-mean-1.3-rk4-fused",
                        "2-sum-1.3-rk4-per_step", "3-sum-None-semi_implicit_euler-fused",
                        "2-local-None-rk4-fused", "3-local-1.3-semi_implicit_euler-per_step")
@pytest.mark.parametrize("path", ["per_step", "fused"])
@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("cutoff", [None, 1.3])
@pytest.mark.parametrize("normalization", ["mean", "sum", "local"])
@pytest.mark.parametrize("dim", [2, 3])
def test_steps_match_the_reference(dim, normalization, cutoff, integrator, path):
    """Every frame's positions and velocities are the reference's, stepped from frame 0;
    the observables are the reference's functions of the frames."""
    n = 40 if cutoff else 16
    sc = scenario(n=n, dim=dim, normalization=normalization, cutoff=cutoff,
                  integrator=integrator, beta=0.4, K=1.5, sigma=0.7, coupling=0.8,
                  dt=0.02 if normalization == "sum" else 0.05)
    res, f = run(sc, path)
    x, v = f.pos[0], f.vel[0]
    for k in range(1, len(f.steps)):
        x, v = ref.step(x, v, sc.time.dt, integrator, **params(sc))
        np.testing.assert_allclose(f.pos[k], x, rtol=0, atol=TOL)
        np.testing.assert_allclose(f.vel[k], v, rtol=0, atol=TOL)
    obs = res.observables
    for k, s in enumerate(f.steps):
        t = list(obs["step"]).index(s)
        assert obs["velocity_diameter"][t] == pytest.approx(ref.diameter(f.vel[k]), abs=1e-12)
        assert obs["position_diameter"][t] == pytest.approx(ref.diameter(f.pos[k]), abs=1e-12)
        for c, axis in enumerate("xyz"[:dim]):
            assert obs[f"mean_velocity_{axis}"][t] == pytest.approx(f.vel[k][:, c].mean(),
                                                                    abs=1e-14)
        var = ((f.vel[k] - f.vel[k].mean(axis=0)) ** 2).sum(axis=1).mean()
        assert obs["velocity_variance"][t] == pytest.approx(var, rel=1e-12, abs=1e-15)
    if cutoff:  # the cutoff matters here: some pairs interact, some do not
        r = ref.diameter(f.pos[0])
        assert r > cutoff


@pytest.mark.parametrize("path", ["per_step", "fused"])
@pytest.mark.parametrize("normalization", ["mean", "sum"])
@pytest.mark.parametrize("dim", [2, 3])
def test_mean_velocity_is_conserved(dim, normalization, path):
    """Symmetric psi: sum_i dv_i/dt = 0, so the mean velocity keeps its value while the
    velocities converge (beta = 0.25)."""
    sc = scenario(n=30, dim=dim, normalization=normalization, steps=400, every=400,
                  dt=0.05 if normalization == "mean" else 0.002)
    res, _ = run(sc, path)
    obs = res.observables
    for axis in "xyz"[:dim]:
        m = obs[f"mean_velocity_{axis}"]
        assert np.abs(m - m[0]).max() < 1e-14
    assert obs["velocity_diameter"][-1] < 0.5 * obs["velocity_diameter"][0]


@pytest.mark.slow_cases("100.0-mean-rk4-per_step", "100.0-sum-rk4-per_step")
@pytest.mark.parametrize("path", ["per_step", "fused"])
@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("normalization", ["mean", "sum"])
@pytest.mark.parametrize("cutoff", [None, 100.0])
def test_beta_zero_relaxes_exactly(cutoff, normalization, integrator, path):
    """beta = 0: psi = K, dv_i/dt = -lambda K D (v_i - mean v), D = 1 (mean) or N (sum).
    Euler: v_i - mean v shrinks by exactly z = 1 - lambda K D dt per step; RK4: by
    R(-h) = 1 - h + h^2/2 - h^3/6 + h^4/24, h = lambda K D dt, within 1e-5 relative of
    e^{-lambda K D t} after t = 2. A cutoff wider than the swarm changes nothing."""
    K, lam, dt, n, steps = 0.7, 1.3, 0.01, 20, 200
    rate = lam * K * (1.0 if normalization == "mean" else n)
    dt = dt if normalization == "mean" else dt / n
    sc = scenario(n=n, dim=3, beta=0.0, K=K, coupling=lam, normalization=normalization,
                  cutoff=cutoff, integrator=integrator, dt=dt, steps=steps, every=steps)
    _, f = run(sc, path)
    h = rate * dt
    z = 1.0 - h if integrator == "semi_implicit_euler" else (
        1.0 - h + h**2 / 2 - h**3 / 6 + h**4 / 24)
    d0 = f.vel[0] - f.vel[0].mean(axis=0)
    d1 = f.vel[-1] - f.vel[-1].mean(axis=0)
    np.testing.assert_allclose(d1, z**steps * d0, rtol=0, atol=1e-13)
    if integrator == "rk4":
        np.testing.assert_allclose(d1, math.exp(-rate * dt * steps) * d0, rtol=0,
                                   atol=1e-5 * np.abs(d0).max() * math.exp(-rate * dt * steps))


@pytest.mark.parametrize("path", ["per_step", "fused"])
def test_same_seed_same_bits_with_a_cutoff(path):
    sc = scenario(n=200, dim=2, steps=20, every=20, cutoff=0.8, side=6.0)
    _, a = run(sc, path)
    _, b = run(sc, path)
    assert all(np.array_equal(x, y) for x, y in zip(a.pos + a.vel, b.pos + b.vel,
                                                    strict=True))


@pytest.mark.parametrize("beta", [0.25, 0.5, 1.0, 0.3])
def test_each_psi_branch_matches_the_reference(beta):
    """law.psi takes roots or a division for beta = 1/4, 1/2, 1 and pow otherwise."""
    sc = scenario(n=12, dim=2, beta=beta, sigma=0.6, K=2.0, steps=3)
    for path in ("per_step", "fused"):
        _, f = run(sc, path)
        x, v = ref.step(f.pos[0], f.vel[0], sc.time.dt, "semi_implicit_euler", **params(sc))
        np.testing.assert_allclose(f.vel[1], v, rtol=0, atol=TOL)
        np.testing.assert_allclose(f.pos[1], x, rtol=0, atol=TOL)


def test_preset_flocks():
    """cucker-smale-2007 (beta = 0.25 < 1/2): the velocity diameter falls by over 10^4
    and the position diameter stays bounded (Theorem 1), on the schedule auto picks."""
    sc = get_preset("cucker-smale-2007")
    res = kernels.run(sc)
    obs = res.observables
    assert res.extra["engine_path"] == "fused"
    assert obs["velocity_diameter"][-1] < 1e-4 * obs["velocity_diameter"][0]
    assert obs["position_diameter"].max() < 3 * obs["position_diameter"][0]


@pytest.mark.parametrize("hashed", [False, True], ids=["dense", "hash"])
@pytest.mark.parametrize("dim", [2, 3])
def test_cutoff_grid_matches_a_sparse_reference_at_scale(taichi_cpu, dim, hashed):
    """20 000 agents on the plane grids (dense rows and hashed buckets) against a k-d tree
    reference, local normalisation, 3 Euler steps."""
    from flocklab.kernels.model import kernel_for
    from flocklab.kernels.runtime import DevicePolicy

    spec = json.loads((EXAMPLES / "cucker_smale_cutoff_3d.json").read_text())
    spec["model"].update(integrator="semi_implicit_euler", normalization="local")
    spec["space"]["dimension"] = dim
    spec["initial"]["region"]["low"] = [0.0] * dim
    sc = Scenario.model_validate(spec)
    policy = DevicePolicy(serial_scatter=True, dense_grid=not hashed)
    k = kernel_for("cucker_smale")(sc, policy)
    f = k.frame(["position", "velocity"])
    x, v = f["position"], f["velocity"]
    for s in range(3):
        k.step(s)
        v = v + sc.time.dt * ref.sparse_accel(x, v, **params(sc))
        x = x + sc.time.dt * v
        f = k.frame(["position", "velocity"])
        np.testing.assert_allclose(f["velocity"], v, rtol=0, atol=TOL)
        np.testing.assert_allclose(f["position"], x, rtol=0, atol=TOL)
    assert k.grid.layout == ("hash" if hashed else "dense")


@pytest.mark.parametrize("shape", ["disc", "ring", "segment", "point"])
def test_streamed_hull_diameter_is_the_pairwise_one(taichi_cpu, shape):
    """observe.diameter over 3 blocks of rows (hulls of blocks and carried vertices)
    against the pairwise maximum, degenerate sets included (collinear, all equal)."""
    import taichi as ti

    from flocklab.kernels.models.cucker_smale import observe
    from flocklab.kernels.space.stream import Rows

    rng = np.random.default_rng(1)
    n = 5000
    p = {"disc": rng.normal(size=(n, 3)),
         "ring": np.c_[np.cos(t := rng.uniform(0, 7, n)), np.sin(t), np.zeros(n)],
         "segment": np.outer(rng.uniform(size=n), [1.0, -2.0, 0.5]),
         "point": np.ones((n, 3))}[shape]
    a = ti.ndarray(float, shape=p.shape)
    a.from_numpy(p)
    got = observe.diameter(Rows(a, block=2000), n, block=2000)
    assert got == pytest.approx(observe.max_pair_distance(p), rel=1e-12, abs=1e-15)


def test_examples_validate():
    for path in sorted(EXAMPLES.glob("cucker_smale*.json")):
        Scenario.model_validate_json(path.read_text())


@pytest.mark.parametrize(("path", "cutoff"), [("per_step", 1.3), ("fused", None),
                                              ("fused", 1.3)])
def test_a_run_resumed_from_a_checkpoint_has_the_uninterrupted_bits(path, cutoff):
    """Checkpoints at every 25th step; the run resumed from the one at step 50 ends on the
    uninterrupted run's frames and observables, bit for bit."""
    spec = scenario(n=40, steps=100, every=20, cutoff=cutoff).model_dump(mode="json")
    spec["recording"]["checkpoint_every"] = 25
    sc = Scenario.model_validate(spec)
    states = {}
    full = Frames()
    res = kernels.run(sc, path=path, sink=full,
                      on_checkpoint=lambda step, state: states.__setitem__(step, state))
    assert 50 in states
    tail = Frames()
    again = kernels.run(sc, path=path, sink=tail, resume=states[50])
    assert tail.steps == full.steps[-len(tail.steps):] and tail.steps[0] > 50
    for a, b in zip(full.pos[-len(tail.pos):] + full.vel[-len(tail.vel):],
                    tail.pos + tail.vel, strict=True):
        assert np.array_equal(a, b)
    for k, v in res.observables.items():
        assert np.array_equal(v, again.observables[k]), k
