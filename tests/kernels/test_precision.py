"""Single precision (`precision: "float32"`): every family against the brute-force
references on both engine paths, at float32 tolerances, and float32's own determinism.

A float32 run cannot follow a float64 reference for long (rounding differences grow in
every chaotic or contracting system), so each check is one step at a time: the reference
(float64) advances the engine's own recorded float32 state by one step, and the engine's
next state must agree within a few float32 roundings of the quantities' scale.
"""

from __future__ import annotations

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels import runtime
from flocklab.kernels.space import rng
from flocklab.schemas import Scenario
from tests.kernels.flocking import test_flocking_reference as fr
from tests.kernels.formation import test_formation as fm
from tests.kernels.vicsek import test_vicsek as vk
from tests.reference import vicsek_step

F32 = float(np.finfo(np.float32).eps)  # 1.19e-7
# One step's disagreement allowed, in units of the quantity's scale (1 + max |value|).
# Measured worst cases (both paths): Vicsek 3.7 eps (headings: atan2 and the noise in
# float32), flocking 0.4 eps, formation 0.5 eps; 32 eps leaves a margin and is still far
# below a wrong neighbour set or formula (differences of 1e-3 and above).
TOL_X = 32 * F32
TOL_V = 32 * F32


def f32(sc: Scenario) -> Scenario:
    return Scenario.model_validate({**sc.model_dump(mode="json"), "precision": "float32"})


# float32 runtimes (and a thread count's) reset Taichi: this module runs after the others.
pytestmark = pytest.mark.resets_taichi


@pytest.fixture(scope="module", autouse=True)
def back_to_float64():
    """Other test modules build kernels on the session's float64 runtime directly: leave
    this module with that runtime current again."""
    yield
    runtime.ensure("cpu")


def scale(a: np.ndarray) -> float:
    return 1.0 + float(np.abs(a).max())


# --- every family against its reference, one step at a time -------------------------------

VICSEK_CASES = [vk.CASES[k] for k in (0, 1, 3, 4, 5, 8, 9, 10, 11)]


@pytest.mark.parametrize("case", VICSEK_CASES,
                         ids=lambda c: "-".join(f"{k}={v}" for k, v in c.items()))
# Each float32 case compiles its kernels afresh; every rule keeps a fast case on each path.
@pytest.mark.slow_cases("fused-rule=leader-L=None-leader_heading=0.7",
                        "fused-rule=laplacian-g=100.0-L=None-inclusive=False",
                        "per_step-rule=laplacian-g=100.0-L=None-inclusive=False")
# The fast lane: each rule once, fused on the vicsek and average rules (each float32 variant
# compiles for seconds); --all runs the rest.
@pytest.mark.fast_cases("fused-rule=vicsek-eta=0.0", "fused-rule=average-eta=0.2-N=30-L=None",
                        "per_step-rule=vicsek-eta=0.4-L=None-move=new_heading",
                        "per_step-rule=laplacian-g=61.0",
                        "per_step-rule=leader-eta=0.3-leader_heading=-1.0")
def test_vicsek_float32_matches_reference_step_by_step(path, case):
    sc = f32(vk.scenario(**case))
    result, sink = vk.run_frames(sc)
    assert result.extra["engine_path"] == path
    assert sink.pos[0].dtype == np.float32  # the state really is single precision
    p = sc.model
    L = sc.space.L if sc.space.kind == "periodic" else None
    ids = np.arange(sc.n_agents)
    period = 2 * np.pi if p.rule == "vicsek" else None
    worst = 0.0
    for step in range(sc.time.steps):
        pos, theta = sink.pos[step].astype(np.float64), sink.theta[step].astype(np.float64)
        noise = rng.uniform_np(rng.step_key(sc.seed, 0, step), ids, "float32")
        pos, theta = vicsek_step(
            pos, theta, rule=p.rule, r=1.0, L=L, inclusive=sc.inclusive, v0dt=p.v0,
            eta=p.eta, g=p.g, theta0=p.leader_heading, noise=noise,
            move_new=p.position_update == "new_heading",
        )
        dx = np.abs(vk.wrapped_diff(sink.pos[step + 1], pos, L)).max() / scale(pos)
        dth = np.abs(vk.wrapped_diff(sink.theta[step + 1], theta, period)).max() / scale(theta)
        worst = max(worst, dx, dth)
        assert dx < TOL_X and dth < TOL_X, (step, dx / F32, dth / F32)
    assert worst > 0.0  # float32 rounding is visible: the run was not float64


def _flocking_check(path: str, sc: Scenario, accel_for, radius_for=None) -> float:
    """Step the engine's kernel (float32) and compare each step with the reference step
    from the engine's previous state; returns the worst velocity error in eps units."""
    runtime.ensure("cpu", precision="float32")
    fr.fused_or_skip(path, sc)
    k = fr.make_kernel(sc, path=path)
    dt, worst = sc.time.dt, 0.0
    x, v = (a.astype(np.float64) for a in fr.state(k))
    for step in range(sc.time.steps):
        k.step(step)
        R = radius_for(k) if radius_for else None
        accel = accel_for(R)
        if sc.model.integrator == "rk4":
            rx, rv = fr.rk4(x, v, accel, dt)
        else:
            rx, rv = fr.euler(x, v, accel(x, v), dt)
        kx, kv = (a.astype(np.float64) for a in fr.state(k))
        ex, ev = np.abs(kx - rx).max() / scale(rx), np.abs(kv - rv).max() / scale(rv)
        assert ex < TOL_X and ev < TOL_V, (step, ex / F32, ev / F32)
        worst = max(worst, ev / F32)
        x, v = kx, kv
    assert np.abs(v).max() > 1e-3  # the run did something
    return worst


M2_CASES = [fr.M2_CASES[k] for k in (0, 1, 3, 5, 6)]


@pytest.mark.parametrize("case", M2_CASES, ids=lambda c: "-".join(f"{v}" for v in c.values()))
# The fixed graph stays fast on per_step, the switching grid on fused.
@pytest.mark.slow_cases("fused-fixed", "per_step-switching-grid")
@pytest.mark.fast_cases("per_step-fixed-rk4-{'kind': 'ring'}", "per_step-switching-all_pairs")
def test_flocking_float32_matches_reference_step_by_step(path, case):
    sc = f32(fr.m2_scenario(**case, steps=60))
    a, _ = sc.model.potential.coefficients()
    if sc.model.topology == "fixed":
        runtime.ensure("cpu", precision="float32")
        adj = fr.fixed_adjacency(fr.make_kernel(sc))

        def accel_for(R):
            return lambda x, v: fr.m2_accel(x, v, a=a, adj=adj)
    else:
        def accel_for(R):
            return lambda x, v: fr.m2_accel(x, v, a=a, R=sc.neighbours.radius,
                                            inclusive=sc.inclusive)
    assert _flocking_check(path, sc, accel_for) > 0.0


M3_CASES = [fr.M3_CASES[k] for k in (0, 2, 6, 9)]


@pytest.mark.parametrize("case", M3_CASES, ids=lambda c: "-".join(f"{v}" for v in c.values()))
# The grid stays fast on fused; RK4 in float32 in the flocking test above.
@pytest.mark.slow_cases("per_step-grid", "per_step-rk4-3-grid")
@pytest.mark.fast_cases("per_step-all_pairs")
def test_obstacles_float32_matches_reference_step_by_step(path, case):
    sc = f32(fr.m3_scenario(**dict(case), steps=60))
    ref = fr.M3Ref(sc.model, sc.neighbours.radius, sc.inclusive)

    def radii(k):  # the radii the step used: the engine's own (eq. 4 is a threshold rule)
        return k.state.in_id_order("rad").astype(np.float64)

    def accel_for(R):
        return lambda x, v: ref.accel(x, v, R)

    assert _flocking_check(path, sc, accel_for, radii) > 0.0


@pytest.mark.parametrize("name", list(fm.CASES))
@pytest.mark.fast_cases("fused-F1-linear-rotate", "per_step-F2-linear-stops",
                        "per_step-F1-linear-rk4-rotate")
def test_formation_float32_matches_reference_step_by_step(path, name):
    m = fm.CASES[name]
    sc = f32(fm.scenario(m, obs_every=40))
    result, sink = fm.run(sc)
    assert result.status == "completed", result.error
    assert result.extra["engine_path"] == path
    full = sc.model.model_dump(mode="json")
    p0 = sink.pos[0].astype(np.float64).mean(axis=0)
    for step in range(sc.time.steps):
        x = sink.pos[step].astype(np.float64)
        x = fm.ref_step(x, step * sc.time.dt, sc.time.dt, full, p0, full["integrator"])
        err = np.abs(sink.pos[step + 1] - x).max() / scale(x)
        assert err < TOL_X, (name, step, err / F32)


# --- float32's own determinism ----------------------------------------------------------------

def _bits(result) -> dict[str, bytes]:
    return {k: np.asarray(v).tobytes() for k, v in result.observables.items()}


DETERMINISM = {
    "vicsek": lambda: vk.scenario(eta=0.9, N=200, L=8.0, steps=30, every=0),
    "flocking": lambda: fr.m2_scenario(n=30, steps=40),
    "formation": lambda: fm.scenario(fm.CASES["F2-linear-stops"], obs_every=5),
}


@pytest.mark.parametrize("family", list(DETERMINISM))
# Each family stays fast on one path (Taichi restarts per thread count: seconds each).
@pytest.mark.slow_cases("fused-flocking", "per_step-vicsek", "fused-formation", "fused-vicsek",
                        "per_step-formation")
def test_float32_same_seed_same_bits_alone_in_a_batch_and_on_any_threads(path, family):
    base = DETERMINISM[family]().model_dump(mode="json")
    alone = kernels.run(Scenario.model_validate({**base, "precision": "float32"}))
    one = kernels.run(Scenario.model_validate({**base, "precision": "float32", "threads": 1}))
    # A batch mate that runs longer: the two share every launch.
    other = {**base, "precision": "float32", "time": {**base["time"],
                                                      "steps": base["time"]["steps"] + 7}}
    batch = kernels.run_batch([Scenario.model_validate(other),
                               Scenario.model_validate({**base, "precision": "float32"})])
    assert alone.status == "completed", alone.error
    assert batch[1].extra["engine_path"] == alone.extra["engine_path"] == path
    assert _bits(alone) == _bits(batch[1]) == _bits(one)


@pytest.mark.slow
def test_a_sweep_may_mix_precisions(monkeypatch):
    """Runs of either precision in one run_batch: each equals its run alone, and the two
    precisions really differ (float32's rounding shows in the observables)."""
    base = vk.scenario(eta=0.5, N=80, L=6.0, steps=25, every=0).model_dump(mode="json")
    scs = [Scenario.model_validate({**base, "precision": p, "seed": s})
           for p, s in (("float32", 1), ("float64", 1), ("float32", 2), ("float64", 2))]
    mixed = kernels.run_batch(scs)
    for sc, res in zip(scs, mixed, strict=True):
        assert _bits(res) == _bits(kernels.run(sc)), sc.precision
    p32, p64 = mixed[0].observables["polarization"], mixed[1].observables["polarization"]
    assert not np.array_equal(p32, p64)
    np.testing.assert_allclose(p32[:5], p64[:5], atol=1e-5)  # the same run, rounded apart


def test_float32_noise_stays_below_one():
    """The float32 draw keeps the top 24 of the hash's 32 bits: h 2^-32 rounded to float32
    reaches 1.0 for the largest h, (h >> 8) 2^-24 never does."""
    h = np.uint32(0xFFFFFFFF)
    assert np.float32(float(h) / 2**32) == 1.0  # the naive draw would fail
    u = rng.uniform_np(rng.step_key(3, 0, 7), np.arange(200_000), "float32")
    assert u.dtype == np.float32 and u.min() >= 0.0 and u.max() < 1.0
    u64 = rng.uniform_np(rng.step_key(3, 0, 7), np.arange(200_000))
    # The same draw: the float32 value is the float64 one truncated to 24 bits.
    assert np.all((u64 - u >= 0) & (u64 - u < 2.0**-24))


@pytest.mark.slow_cases("fused")
def test_float32_inclusive_radius_keeps_pairs_exactly_at_r(path):
    """Two agents exactly r apart (r = 0.75: r^2 exact in float32): neighbours when
    inclusive (the fused path's d2 < next float32 above r^2; a float64 nextafter would
    round back to r^2 and lose the pair), not when exclusive."""
    for inclusive, degree in ((True, 1.0), (False, 0.0)):
        sc = Scenario.model_validate({
            "model": {"kind": "vicsek", "v0": 0.0, "eta": 0.0},
            "space": {"kind": "plane"}, "neighbours": {"radius": 0.75, "inclusive": inclusive},
            "initial": {"kind": "explicit", "positions": [[0.0, 0.0], [0.75, 0.0]],
                        "headings": [0.0, 1.0]},
            "time": {"steps": 1}, "precision": "float32"})
        res = kernels.run(sc)
        assert res.observables["degree_mean"][0] == degree, (inclusive, path)


def test_long_float32_runs_take_the_per_step_path():
    """The fused path's observation rows hold step numbers in the kernels' float type,
    exact below 2^24 in float32: a float32 run that long goes per step (float64 does not)."""
    long = {**vk.scenario(N=50, steps=1, every=0).model_dump(mode="json"),
            "time": {"steps": 2**24, "dt": 1.0}}
    assert kernels.engine.choose_path(Scenario.model_validate(long), "cpu") == "fused"
    f32_long = Scenario.model_validate({**long, "precision": "float32"})
    assert kernels.engine.choose_path(f32_long, "cpu") == "per_step"
    short = Scenario.model_validate({**long, "precision": "float32",
                                     "time": {"steps": 2**24 - 1, "dt": 1.0}})
    assert kernels.engine.choose_path(short, "cpu") == "fused"


def test_float32_agent_within_rounding_of_L_keeps_its_neighbours(path):
    """In float32, x / cell rounds up to the cell count for an x within rounding of L
    (here x = the float32 below L = 3.13: x / cell = 3.0 = nc). That agent belongs to the
    last cell; put in cell 0 (x mod nc) it sat across the seam from its neighbours, and
    a neighbour 0.5 away went unseen."""
    L = 3.13
    x = float(np.nextafter(np.float32(L), np.float32(0.0)))
    sc = Scenario.model_validate({
        "model": {"kind": "vicsek", "v0": 0.0, "eta": 0.0},
        "space": {"kind": "periodic", "L": L}, "neighbours": {"radius": 1.0},
        "initial": {"kind": "explicit", "positions": [[x, 1.5], [x - 0.5, 1.5]],
                    "headings": [0.0, 1.0]},
        "time": {"steps": 1}, "precision": "float32"})
    res = kernels.run(sc)
    assert res.extra["engine_path"] == path
    assert res.observables["degree_min"][0] == 1.0, path


def test_an_unknown_precision_is_refused():
    with pytest.raises(ValueError, match="float64 or float32"):
        runtime.ensure("cpu", precision="float16")
    with pytest.raises(ValueError):
        Scenario.model_validate({**vk.scenario().model_dump(mode="json"),
                                 "precision": "float16"})


@pytest.mark.slow_cases("laplacian-6.0", "vicsek-None", "average-None")
@pytest.mark.parametrize("rule, L", [("average", None), ("vicsek", None), ("laplacian", 6.0)])
def test_a_float64_run_after_a_float32_one_of_the_same_kernel_is_float64(rule, L,
                                                                         monkeypatch):
    # Kernel factories are cached per variant, not per precision: nothing they build in
    # Python may keep the float width of the runtime that first called them (a vector
    # type made at factory time did: 1e-8 errors in the float64 runs that followed).
    sc = vk.scenario(rule=rule, L=L, eta=0.3, steps=10, every=0,
                     g=61.0 if rule == "laplacian" else None)
    assert kernels.run(f32(sc)).extra["engine_path"] == "fused"
    fused = kernels.run(sc)
    per_step = kernels.run(sc, path="per_step")
    assert (fused.extra["engine_path"], per_step.extra["engine_path"]) == ("fused", "per_step")
    for k in ("polarization", "heading_spread"):
        assert np.allclose(fused.observables[k], per_step.observables[k], rtol=0,
                           atol=1e-11), k


def test_switching_the_runtime_frees_the_old_ones_arrays_first():
    """An array of one runtime that only a reference cycle holds is freed before the
    reset: freed after it, its wrapper would delete the next runtime's array that sits
    at the same address (Taichi frees by address in the current program)."""
    import gc
    import weakref

    import taichi as ti

    runtime.ensure("cpu", threads=2)
    arr = ti.ndarray(ti.i32, shape=4)
    holder: dict = {"arr": arr}
    holder["self"] = holder  # a cycle: only the collector frees it
    alive = weakref.ref(arr)
    del arr, holder
    was_enabled = gc.isenabled()
    gc.disable()  # no automatic collection may do the runtime's work for it
    try:
        runtime.ensure("cpu", threads=1)
        assert alive() is None
    finally:
        if was_enabled:
            gc.enable()
        runtime.ensure("cpu")
