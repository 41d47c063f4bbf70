"""The batched schedule (every replica's agents in one launch a step) gives each replica
the fused schedule's bits: the same functions, in the same order for each replica."""

import numpy as np
import pytest

from flocklab import kernels
from tests.kernels.vicsek import test_vicsek_3d as v3
from tests.kernels.vicsek.test_vicsek import Frames, scenario
from tests.kernels.vicsek.test_vicsek_fused import mix, same_result


def both(sc):
    """(fused result, frames), (batched result, frames) of one scenario alone."""
    out = []
    for path in ("fused", "batched"):
        sink = Frames()
        res = kernels.run(sc, sink=sink, path=path)
        assert res.extra["engine_path"] == path
        out.append((res, sink))
    return out


def same_frames(a: Frames, b: Frames) -> None:
    assert a.steps == b.steps
    for x, y in zip(a.pos, b.pos, strict=True):
        assert np.array_equal(x, y)
    for x, y in zip(a.theta, b.theta, strict=True):
        assert np.array_equal(x, y)


@pytest.mark.parametrize("rule", ["vicsek", "average", "laplacian", "leader"])
@pytest.mark.parametrize("L", [True, None], ids=["periodic", "plane"])
# Each rule's batched and fused kernels compile for seconds (9 s of CPU a rule): the vicsek
# and leader rules stay fast in the box, the plane with the vicsek rule; --all runs all.
@pytest.mark.fast_cases("periodic-vicsek", "plane-vicsek")
def test_batched_gives_the_fused_bits_alone_and_together(taichi_cpu, rule, L):
    scenarios = mix(rule, bool(L), every=7, track_linked_intervals=True)
    (fused, fs), (batched, bs) = both(scenarios[1])
    same_result(fused, batched)
    same_frames(fs, bs)
    together = kernels.run_batch(scenarios, path="batched")
    for sc, res in zip(scenarios, together, strict=True):
        assert res.extra["engine_path"] == "batched"
        same_result(res, kernels.run(sc, path="fused"))


@pytest.mark.parametrize("L", [6.0, None], ids=["periodic", "plane"])
@pytest.mark.slow_cases("plane")  # 3D's batched kernels stay fast in the box
def test_batched_in_3d(taichi_cpu, L):
    sc = v3.scenario(N=400, L=L, eta=1.1, steps=15, every=5, track_linked_intervals=True)
    (fused, fs), (batched, bs) = both(sc)
    same_result(fused, batched)
    same_frames(fs, bs)


def test_batched_divergence_stops_only_its_replica(taichi_cpu):
    good = scenario(N=50, L=None, eta=0.5, steps=20, every=0)
    bad = scenario(N=50, L=None, v0=1e300, steps=20, every=0)
    res = kernels.run_batch([good, bad], path="batched")
    assert res[0].status == "completed" and res[0].steps == 20
    assert res[1].status == "diverged" and res[1].error["step"] == res[1].steps < 20
    same_result(res[1], kernels.run(bad, path="fused"))
    same_result(res[0], kernels.run(good, path="fused"))
