"""M1 in 3D (rule vicsek): the step against the brute-force reference on both engine paths
(fused small-N and per-step), and the properties of the rule: alignment in one step,
isotropy at eta = 2 pi, a batch's bits, outputs."""

import math

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels.space import rng
from flocklab.schemas import Scenario
from tests.kernels.vicsek.test_vicsek import Frames, wrapped_diff
from tests.reference import vicsek_step_3d


def scenario(N=60, L=4.0, r=1.0, eta=0.0, steps=8, v0=0.1, seed=11, inclusive=None,
             move="old_heading", every=1, region=None, initial=None, **model):
    space = {"kind": "periodic", "L": L, "dimension": 3} if L else {"kind": "plane",
                                                                    "dimension": 3}
    init = initial or {"kind": "random", "N": N}
    if region or (not L and initial is None):
        init["region"] = region or {"kind": "ball", "center": [1, 1, 1], "radius": 2.0}
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "v0": v0, "eta": eta, "position_update": move, **model},
        "space": space,
        "neighbours": {"radius": r, "inclusive": inclusive},
        "initial": init,
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"every": every, "arrays": ["position", "heading"]},
        "seed": seed,
    })


def run_frames(sc):
    sink = Frames()
    result = kernels.run(sc, sink=sink)
    assert result.status == "completed", result.error
    return result, sink


CASES = [
    dict(eta=0.0),
    dict(eta=0.9),
    dict(eta=2.5, inclusive=False),
    dict(eta=0.9, L=2.5),  # fewer than 3 cells across: every cell once, minimum image
    dict(eta=1.3, L=None, move="new_heading"),
    dict(eta=2 * math.pi, L=None, N=40),
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(f"{k}={v}" for k, v in c.items()))
# A 3D kernel variant (schedule, box or plane, per step: inclusiveness) compiles for
# seconds: the fast lane keeps every case fused and the plane's per step (its other cases
# share those variants); --all runs the periodic per-step ones too.
@pytest.mark.fast_cases("fused-eta=0.0", "fused-eta=0.9", "fused-eta=2.5-inclusive=False",
                        "fused-eta=0.9-L=2.5", "fused-eta=1.3-L=None-move=new_heading",
                        "fused-eta=6.283185307179586-L=None-N=40",
                        "per_step-eta=1.3-L=None-move=new_heading",
                        "per_step-eta=6.283185307179586-L=None-N=40")
def test_matches_brute_force_step_by_step(taichi_cpu, path, case):
    sc = scenario(**case)
    result, sink = run_frames(sc)
    assert result.extra["engine_path"] == path
    p = sc.model
    L = sc.space.L if sc.space.kind == "periodic" else None
    assert sink.pos[0].shape == (sc.n_agents, 3) and sink.theta[0].shape == (sc.n_agents, 3)
    pos, e = sink.pos[0].copy(), sink.theta[0].copy()
    assert np.allclose(np.linalg.norm(e, axis=1), 1.0)
    ids = np.arange(sc.n_agents)
    for step in range(sc.time.steps):
        u1 = rng.uniform_np(rng.step_key(sc.seed, 0, step), ids)
        u2 = rng.uniform_np(rng.step_key(sc.seed, 1, step), ids)
        pos, e = vicsek_step_3d(pos, e, r=1.0, L=L, inclusive=sc.inclusive, v0dt=p.v0,
                                eta=p.eta, u1=u1, u2=u2,
                                move_new=p.position_update == "new_heading")
        assert np.abs(wrapped_diff(sink.pos[step + 1], pos, L)).max() < 1e-9, step
        assert np.abs(sink.theta[step + 1] - e).max() < 1e-9, step


def test_noise_stays_in_the_cap(taichi_cpu):
    # Every agent alone (far apart): its new heading is its old one turned by at most eta/2.
    eta = 1.0
    pts = [[10.0 * i, 0.0, 0.0] for i in range(200)]
    vel = np.random.default_rng(1).normal(size=(200, 3))
    sc = scenario(eta=eta, L=None, steps=1, initial={
        "kind": "explicit", "positions": pts, "velocities": vel.tolist()})
    _, sink = run_frames(sc)
    cos = (sink.theta[0] * sink.theta[1]).sum(axis=1)
    angle = np.arccos(np.clip(cos, -1, 1))
    assert angle.max() <= eta / 2 + 1e-12
    assert angle.max() > 0.9 * eta / 2  # ... and fills it: P(all < 0.45) = (1-0.19)^200
    # Uniform in area: 1 - cos t is uniform on [0, 1 - cos(eta/2)], mean half of that.
    h = (1 - cos) / (1 - np.cos(eta / 2))
    assert abs(h.mean() - 0.5) < 0.07


def test_eta_zero_every_agent_in_range_aligns_in_one_step(taichi_cpu):
    sc = scenario(N=50, L=None, r=2.0, steps=1, region={
        "kind": "ball", "center": [0, 0, 0], "radius": 0.9})
    result, sink = run_frames(sc)
    e1 = sink.theta[1]
    assert np.abs(e1 - e1[0]).max() < 1e-12
    assert result.observables["heading_spread"][0] > 1.0  # random start: spread out
    assert result.final["heading_spread"] < 1e-6
    assert abs(result.final["polarization"] - 1.0) < 1e-12
    assert result.final["components"] == 1 and result.final["degree_min"] == 49


def test_full_noise_polarization_scales_as_on_the_sphere(taichi_cpu):
    # eta = 2 pi: i.i.d. uniform directions on the sphere, so sqrt(N) |mean e| has the
    # mean of |Gaussian(0, I/3)| in 3D: E chi_3 / sqrt 3 = sqrt(8 / (3 pi)) = 0.921
    # (2D: sqrt(pi) / 2 = 0.886). 200 steps: standard error 0.389 / sqrt(200) = 0.028.
    n = 400
    sc = scenario(N=n, L=8.0, eta=2 * math.pi, steps=200, every=0)
    result = kernels.run(sc)
    pol = result.observables["polarization"][1:]
    assert abs(pol.mean() * math.sqrt(n) - math.sqrt(8 / (3 * math.pi))) < 0.1


@pytest.mark.parametrize("L", [4.0, None], ids=["periodic", "plane"])
def test_a_batch_gives_each_3d_replica_its_bits_alone(taichi_cpu, L):
    scs = [scenario(seed=s, eta=0.5 * s, N=40 + 30 * s, L=L, steps=12, every=0)
           for s in (1, 2, 3)]
    alone = [kernels.run(sc) for sc in scs]
    together = kernels.engine.run_batch(scs)
    assert len(together) == 3
    for a, b in zip(alone, together, strict=True):
        assert a.extra["engine_path"] == b.extra["engine_path"] == "fused"
        for k in a.observables:
            assert np.array_equal(a.observables[k], b.observables[k]), k


@pytest.mark.parametrize("L", [6.0, None], ids=["periodic", "plane"])
def test_fused_and_per_step_agree_in_3d(taichi_cpu, monkeypatch, L):
    # The two paths sum the neighbours in different orders: equal to rounding, with the
    # graph observables exactly equal (the cell budget's cube root: N = 400, 5 cells across).
    sc = scenario(N=400, L=L, eta=1.1, steps=15, every=0)
    fused = kernels.run(sc)
    per_step = kernels.run(sc, path="per_step")
    assert (fused.extra["engine_path"], per_step.extra["engine_path"]) == ("fused", "per_step")
    for k in ("components", "degree_mean", "degree_min", "degree_max", "isolated"):
        assert np.array_equal(fused.observables[k], per_step.observables[k]), k
    for k in ("polarization", "heading_spread"):
        assert np.allclose(fused.observables[k], per_step.observables[k], atol=1e-9), k


def test_linked_intervals_and_graph_in_3d(taichi_cpu):
    # A tight ball, every agent within r of every other: one component, all linked.
    sc = scenario(N=30, L=None, r=3.0, steps=4, region={
        "kind": "ball", "center": [0, 0, 0], "radius": 1.0}, track_linked_intervals=True)
    result, _ = run_frames(sc)
    assert result.extra["linked_intervals"]["count"] == 4
    assert result.final["degree_mean"] == 29
