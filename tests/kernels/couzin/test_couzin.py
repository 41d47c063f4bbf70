"""Couzin's zone model against an independent numpy reference (reference.py) at small N,
on both schedules, in 2D and 3D, with and without noise and a blind angle; the two
schedules' agreement, same-seed bits, checkpoints, and the limits of the rules: a
repulsion partner overrides every other zone, the turn is at most theta tau per step, the
speed is constant."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from flocklab import kernels
from flocklab.schemas import Scenario

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


def scenario(*, n=30, dim=3, steps=6, dt=0.1, side=5.0, every=1, seed=5, **model) -> Scenario:
    return Scenario.model_validate({
        "model": {"kind": "couzin", **model},
        "space": {"kind": "plane", "dimension": dim},
        "initial": {"kind": "random", "N": n,
                    "region": {"kind": "box", "low": [0.0] * dim, "high": [side] * dim}},
        "time": {"steps": steps, "dt": dt},
        "recording": {"every": every, "arrays": ["position", "velocity"],
                      "observables_every": 1},
        "seed": seed,
    })


def run(sc: Scenario, path: str):
    sink = Frames()
    res = kernels.run(sc, path=path, sink=sink)
    assert res.status == "completed" and res.extra["engine_path"] == path
    return res, sink


def params(sc: Scenario) -> dict:
    p = sc.model
    return dict(r_r=p.r_r, dr_o=p.dr_o, dr_a=p.dr_a, field_of_view=p.field_of_view,
                turning_rate=p.turning_rate, speed=p.speed, sigma=p.sigma, dt=sc.time.dt,
                combine=p.combine)


CASES = {  # zones that split a box of side 5 between all three; a wide turn, so the
    # desired direction is often reached and often not
    "paper": dict(r_r=1.0, dr_o=1.0, dr_a=1.5, turning_rate=300.0),
    "noiseless-360": dict(r_r=0.8, dr_o=0.7, dr_a=2.0, field_of_view=360.0, sigma=0.0,
                          turning_rate=500.0),
    "narrow-view-unit": dict(r_r=0.6, dr_o=1.2, dr_a=1.0, field_of_view=120.0, sigma=0.3,
                             turning_rate=200.0, combine="unit"),
}


@pytest.mark.parametrize("path", ["per_step", "fused"])
@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("dim", [2, 3])
def test_steps_match_the_reference(dim, case, path):
    """Every frame's positions and velocities are the reference's, stepped from frame 0
    with the same noise; the observables are the reference's order parameters."""
    sc = scenario(dim=dim, **CASES[case])
    res, f = run(sc, path)
    x, e = f.pos[0], f.vel[0] / sc.model.speed
    for k in range(1, len(f.steps)):
        x, e = ref.step(x, e, seed=sc.seed, step_no=f.steps[k - 1], **params(sc))
        np.testing.assert_allclose(f.pos[k], x, rtol=0, atol=TOL)
        np.testing.assert_allclose(f.vel[k], sc.model.speed * e, rtol=0, atol=TOL)
    obs = res.observables
    for k, s in enumerate(f.steps):
        t = list(obs["step"]).index(s)
        p, m = ref.order_parameters(f.pos[k], f.vel[k] / sc.model.speed)
        assert obs["polarization"][t] == pytest.approx(p, abs=1e-12)
        assert obs["milling"][t] == pytest.approx(m, abs=1e-12)


def zone_counts(x: np.ndarray, r_r: float, r_a: float) -> tuple[int, int]:
    """Agents with a repulsion partner, and with a partner in the other zones only."""
    d = np.sqrt(((x[None] - x[:, None]) ** 2).sum(axis=-1))
    np.fill_diagonal(d, np.inf)
    rep = (d < r_r).any(axis=1)
    return int(rep.sum()), int((~rep & (d < r_a).any(axis=1)).sum())


def test_the_reference_cases_meet_every_zone():
    """The cases above are not vacuous: the start holds agents with repulsion partners and
    agents steered by orientation and attraction alone."""
    for case in CASES.values():
        sc = scenario(dim=3, **case)
        _, f = run(sc, "fused")
        p = sc.model
        rep, rest = zone_counts(f.pos[0], p.r_r, p.r_a)
        assert rep >= 3 and rest >= 3, (case, rep, rest)


@pytest.mark.parametrize("dim", [2, 3])
def test_schedules_agree_over_a_preset_like_run(dim):
    """The paper's parameters, 60 agents, 40 steps: per-step and fused schedules agree to
    rounding (their sums run in grid and id order)."""
    sc = scenario(n=60, dim=dim, steps=40, every=40, side=6.0, dr_o=2.0, dr_a=14.0)
    _, a = run(sc, "per_step")
    _, b = run(sc, "fused")
    np.testing.assert_allclose(a.pos[-1], b.pos[-1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.vel[-1], b.vel[-1], rtol=0, atol=1e-9)


@pytest.mark.parametrize("path", ["per_step", "fused"])
def test_turn_speed_and_same_seed_same_bits(path):
    """Each step turns every direction by at most theta tau (4 degrees at the paper's 40
    degrees per second and 0.1 s), moves it s tau, and a second run has the same bits."""
    sc = scenario(n=80, dim=3, steps=30, side=4.0, dr_o=2.0, dr_a=6.0)
    _, a = run(sc, path)
    _, b = run(sc, path)
    assert all(np.array_equal(u, v) for u, v in zip(a.pos + a.vel, b.pos + b.vel,
                                                    strict=True))
    s, tau = sc.model.speed, sc.time.dt
    for k in range(1, len(a.steps)):
        e0, e1 = a.vel[k - 1] / s, a.vel[k] / s
        ang = np.degrees(np.arccos(np.clip((e0 * e1).sum(axis=1), -1, 1)))
        assert ang.max() <= 40.0 * tau + 1e-6
        step = np.linalg.norm(a.pos[k] - a.pos[k - 1], axis=1)
        np.testing.assert_allclose(step, s * tau, rtol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(e1, axis=1), 1.0, rtol=1e-14)


@pytest.mark.parametrize("path", ["per_step", "fused"])
def test_repulsion_overrides_orientation_and_attraction(path):
    """Two agents 0.5 apart face the same way along y, a third in the other zones: the
    pair turns apart along x (repulsion alone), noiseless, turning unlimited."""
    sc = Scenario.model_validate({
        "model": {"kind": "couzin", "r_r": 1.0, "dr_o": 2.0, "dr_a": 5.0, "sigma": 0.0,
                  "turning_rate": 1800.0, "field_of_view": 360.0},
        "space": {"kind": "plane", "dimension": 2},
        "initial": {"kind": "explicit", "positions": [[0.0, 0.0], [0.5, 0.0], [3.0, 0.0]],
                    "velocities": [[0.0, 1.0], [0.0, 1.0], [0.0, -1.0]]},
        "time": {"steps": 1, "dt": 0.1},
        "recording": {"every": 1, "arrays": ["position", "velocity"]},
        "seed": 1,
    })
    _, f = run(sc, path)
    e = f.vel[1] / sc.model.speed
    np.testing.assert_allclose(e[0], [-1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(e[1], [1.0, 0.0], atol=1e-15)
    # agent 2 sees 1 in its zone of orientation (2.5 < r_o = 3) and 0 in attraction (3)
    want = 0.5 * (np.array([0.0, 1.0]) + np.array([-1.0, 0.0]))
    np.testing.assert_allclose(e[2], want / np.linalg.norm(want), atol=1e-15)


@pytest.mark.parametrize("path", ["per_step", "fused"])
def test_a_run_resumed_from_a_checkpoint_has_the_uninterrupted_bits(path):
    spec = scenario(n=40, steps=60, every=20, dr_o=2.0, dr_a=4.0).model_dump(mode="json")
    spec["recording"]["checkpoint_every"] = 15
    sc = Scenario.model_validate(spec)
    states = {}
    full = Frames()
    res = kernels.run(sc, path=path, sink=full,
                      on_checkpoint=lambda step, state: states.__setitem__(step, state))
    tail = Frames()
    again = kernels.run(sc, path=path, sink=tail, resume=states[30])
    assert tail.steps == full.steps[-len(tail.steps):] and tail.steps[0] > 30
    for a, b in zip(full.pos[-len(tail.pos):] + full.vel[-len(tail.vel):],
                    tail.pos + tail.vel, strict=True):
        assert np.array_equal(a, b)
    for k, v in res.observables.items():
        assert np.array_equal(v, again.observables[k]), k


def test_milling_of_a_rotating_ring_is_one():
    """Agents on a circle moving tangentially: m = 1, p = 0 (the order parameters'
    definition, on the fused schedule's observation and the reference's)."""
    n = 24
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    pos = 5.0 * np.c_[np.cos(a), np.sin(a)]  # compact: the dense grid, as elsewhere
    vel = 3.0 * np.c_[-np.sin(a), np.cos(a)]
    sc = Scenario.model_validate({
        "model": {"kind": "couzin", "r_r": 1.0, "dr_o": 1.0, "dr_a": 1.0},
        "space": {"kind": "plane", "dimension": 2},
        "initial": {"kind": "explicit", "positions": pos.tolist(),
                    "velocities": vel.tolist()},
        "time": {"steps": 1, "dt": 0.1}, "recording": {"observables_every": 1}, "seed": 3,
    })
    for path in ("per_step", "fused"):
        res = kernels.run(sc, path=path)
        assert res.observables["milling"][0] == pytest.approx(1.0, abs=1e-14)
        assert res.observables["polarization"][0] == pytest.approx(0.0, abs=1e-14)
    assert ref.order_parameters(pos, vel / 3.0) == pytest.approx((0.0, 1.0), abs=1e-14)


def test_examples_validate():
    for path in sorted(EXAMPLES.glob("couzin*.json")):
        Scenario.model_validate_json(path.read_text())
    assert sorted(EXAMPLES.glob("couzin*.json"))
