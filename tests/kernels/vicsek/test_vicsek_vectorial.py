"""Vectorial noise (rule vicsek, Grégoire & Chaté 2004): the step against the brute-force
reference on the fused and per-step paths in 2D and 3D, the by-cell step and the batched
schedule to the same bits, the rule's limits (eta = 0 aligns a connected swarm in one step;
a large eta scatters it), and the schema's refusal for the JLM rules."""

import math

import numpy as np
import pytest
from pydantic import ValidationError

from flocklab import kernels
from flocklab.kernels.models.vicsek.step import RULES, block_step_kernel, step_kernel
from flocklab.kernels.space import rng
from flocklab.schemas import Scenario
from tests.kernels.vicsek.test_vicsek import Frames, wrapped_diff
from tests.kernels.vicsek.test_vicsek_batched import both, same_frames
from tests.kernels.vicsek.test_vicsek_by_cell import build, one_step, positions
from tests.kernels.vicsek.test_vicsek_fused import same_result
from tests.reference import vicsek_step_vectorial


def scenario(dim=2, N=60, L=5.0, r=1.0, eta=0.4, steps=8, v0=0.2, seed=7, inclusive=None,
             move="new_heading", initial=None):
    space = {"kind": "periodic", "L": L, "dimension": dim} if L else {"kind": "plane",
                                                                    "dimension": dim}
    init = initial or {"kind": "random", "N": N}
    if not L and initial is None:
        init["region"] = ({"kind": "box", "low": [0, 0], "high": [3, 3]} if dim == 2 else
                          {"kind": "ball", "center": [1, 1, 1], "radius": 1.5})
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "v0": v0, "eta": eta, "noise": "vectorial",
                  "position_update": move},
        "space": space,
        "neighbours": {"radius": r, "inclusive": inclusive},
        "initial": init,
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"every": 1, "arrays": ["position", "heading"]},
        "seed": seed,
    })


def unit(heading: np.ndarray) -> np.ndarray:
    """A recorded heading as unit vectors (2D frames hold angles, 3D ones vectors)."""
    if heading.ndim == 1:
        return np.stack([np.cos(heading), np.sin(heading)], axis=1)
    return heading


CASES = [
    dict(dim=2),
    dict(dim=2, eta=0.0, move="old_heading"),
    dict(dim=2, eta=1.7, inclusive=False, N=30),
    dict(dim=2, L=2.5, eta=0.8),  # fewer than 3 cells across: minimum image, every cell
    dict(dim=2, L=None, eta=0.6),
    dict(dim=3, L=4.0),
    dict(dim=3, L=4.0, eta=2.0, inclusive=False, move="old_heading"),
    dict(dim=3, L=None, eta=0.5, N=40),
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(f"{k}={v}" for k, v in c.items()))
# Each case compiles kernels of its own (seconds, 3D the most): the fast lane keeps a few
# covering every option on each schedule; --all runs every case.
@pytest.mark.fast_cases("fused-dim=2", "fused-dim=3-L=None-eta=0.5-N=40",
                        "per_step-dim=2-eta=0.0-move=old_heading",
                        "per_step-dim=2-eta=1.7-inclusive=False-N=30",
                        "per_step-dim=2-L=2.5-eta=0.8",
                        "per_step-dim=3-L=4.0-eta=2.0-inclusive=False-move=old_heading")
def test_matches_brute_force_step_by_step(taichi_cpu, path, case):
    sc = scenario(**case)
    sink = Frames()
    result = kernels.run(sc, sink=sink)
    assert result.status == "completed", result.error
    p, dim = sc.model, sc.dimension
    L = sc.space.L if sc.space.kind == "periodic" else None
    pos, e = sink.pos[0].copy(), unit(sink.theta[0])
    ids = np.arange(sc.n_agents)
    for step in range(sc.time.steps):
        u1 = rng.uniform_np(rng.step_key(sc.seed, 0, step), ids)
        u2 = rng.uniform_np(rng.step_key(sc.seed, 1, step), ids)
        pos, e = vicsek_step_vectorial(pos, e, r=1.0, L=L, inclusive=sc.inclusive, v0dt=p.v0,
                                       eta=p.eta, u1=u1, u2=u2,
                                       move_new=p.position_update == "new_heading")
        assert np.abs(wrapped_diff(sink.pos[step + 1], pos, L)).max() < 1e-9, step
        assert np.abs(unit(sink.theta[step + 1]) - e).max() < 1e-9, step
    assert dim == pos.shape[1]


@pytest.mark.slow_cases("2-3.5-random-200", "3-4.0-ties-0", "3-5.3-crowded-400")
@pytest.mark.parametrize("dim,L,layout,n", [(2, 3.5, "random", 200), (2, 5.0, "ties", 0),
                                            (3, 4.0, "ties", 0), (3, 5.3, "crowded", 400)])
def test_by_cell_step_counts_the_neighbourhood_as_the_per_agent_step(taichi_cpu, dim, L,
                                                                     layout, n):
    gen = np.random.default_rng(dim + n)
    k = build(dim, L, 1.0, positions(layout, dim, L, n, 1.0, gen), 0.7, True, "new_heading",
              gen, noise="vectorial")
    assert k.kernel is block_step_kernel(True, True, dim, True)
    k.state.sort(k.grid, 0)
    want = one_step(k, step_kernel(RULES["vicsek"], True, True, True, False, dim, True))
    got = one_step(k, k.kernel)
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)
    # The noise is vectorial: the angular kernel's step differs.
    angular = one_step(k, step_kernel(RULES["vicsek"], True, True, True, False, dim, False))
    assert not np.array_equal(angular[1], got[1])


@pytest.mark.slow_cases("3")
@pytest.mark.parametrize("dim", [2, 3])
def test_batched_and_fused_schedules_give_the_same_bits(taichi_cpu, dim):
    scs = [scenario(dim=dim, N=n, eta=eta, seed=s, steps=30)
           for n, eta, s in [(50, 0.3, 1), (120, 0.9, 2), (20, 0.0, 3)]]
    (fused, fs), (batched, bs) = both(scs[1])
    same_result(fused, batched)
    same_frames(fs, bs)
    together = kernels.run_batch(scs, path="batched")
    for sc, res in zip(scs, together, strict=True):
        assert res.extra["engine_path"] == "batched"
        same_result(res, kernels.run(sc, path="fused"))


@pytest.mark.parametrize("dim", [2, 3])
def test_zero_noise_aligns_a_connected_swarm_in_one_step(taichi_cpu, dim):
    # Every pair within r: each agent's w is the same sum, so all share its direction.
    sc = scenario(dim=dim, L=None, eta=0.0, steps=1, N=30, initial={
        "kind": "random", "N": 30,
        "region": {"kind": "box", "low": [0] * dim, "high": [0.5] * dim}})
    res = kernels.run(sc)
    assert res.observables["polarization"][-1] == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_large_noise_scatters_an_aligned_swarm(taichi_cpu, dim):
    # eta n_i u_i dominates S (|S| <= n_i): at eta = 6 the new headings are nearly
    # independent, so the polarization of N agents falls to O(1/sqrt(N)).
    N = 2000
    sc = scenario(dim=dim, L=None, eta=6.0, steps=1, N=N, initial={
        "kind": "explicit", "positions": [[0.0] * dim] * N,
        "velocities": [[1.0] + [0.0] * (dim - 1)] * N})
    res = kernels.run(sc)
    phi = res.observables["polarization"]
    assert phi[0] == pytest.approx(1.0)
    # One cell, aligned: w_i = N (e + 6 u_i) for all i, so the new headings are i.i.d.
    # (e + 6u)/|e + 6u|; their mean's length, by Monte Carlo over u, within 4 sd of a mean
    # of N (each component's sd below 1 / sqrt(N)).
    gen = np.random.default_rng(0)
    u = gen.normal(size=(400_000, dim))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = u * 6.0
    w[:, 0] += 1.0
    expected = np.linalg.norm((w / np.linalg.norm(w, axis=1, keepdims=True)).mean(axis=0))
    assert 0.05 < expected < 0.2
    assert phi[-1] == pytest.approx(expected, abs=4 / math.sqrt(N) + 0.01)


def test_the_jlm_rules_refuse_vectorial_noise():
    with pytest.raises(ValidationError, match="noise 'vectorial'"):
        Scenario.model_validate({
            "model": {"kind": "vicsek", "rule": "average", "noise": "vectorial"},
            "space": {"kind": "periodic", "L": 5.0}, "neighbours": {"radius": 1.0},
            "initial": {"kind": "random", "N": 10}, "time": {"steps": 1}})
