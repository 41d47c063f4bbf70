"""M1: every rule against the brute-force reference, and the papers' properties."""

import math

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels.space import rng
from flocklab.schemas import Scenario
from tests.reference import vicsek_step

# Taichi on the CPU for every test (the two-path `path` fixture does not start it).
pytestmark = pytest.mark.usefixtures("taichi_cpu")


class Frames:
    """A FrameSink keeping every frame in memory (small runs only)."""

    def __init__(self):
        self.steps, self.pos, self.theta = [], [], []

    def frame(self, step, time, arrays):
        self.steps.append(step)
        self.pos.append(arrays["position"])
        self.theta.append(arrays["heading"])


def scenario(rule="vicsek", N=60, L=6.0, r=1.0, eta=0.0, steps=20, v0=0.1, seed=11,
             g=None, inclusive=None, move="old_heading", every=1, region=None, **model):
    space = {"kind": "periodic", "L": L} if L else {"kind": "plane"}
    init = {"kind": "random", "N": N}
    if region or not L:
        init["region"] = region or {"kind": "box", "low": [0, 0], "high": [4, 4]}
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": rule, "v0": v0, "eta": eta, "g": g,
                  "position_update": move, **model},
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


def wrapped_diff(a, b, L):
    d = a - b
    return d - L * np.round(d / L) if L else d


CASES = [
    dict(rule="vicsek", eta=0.0),
    dict(rule="vicsek", eta=0.9, N=30),  # all pairs (the fused path's small-N visit)
    dict(rule="vicsek", eta=0.9, L=2.5),  # fewer than 3 cells across: all pairs
    dict(rule="average", eta=0.2, N=30, L=None),
    dict(rule="vicsek", eta=1.3),
    dict(rule="vicsek", eta=0.4, L=None, move="new_heading"),
    dict(rule="average"),
    dict(rule="average", eta=0.2, L=None),
    dict(rule="laplacian", g=61.0),
    dict(rule="laplacian", g=100.0, L=None, inclusive=False),
    dict(rule="leader", L=None, leader_heading=0.7),
    dict(rule="leader", eta=0.3, leader_heading=-1.0),
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(f"{k}={v}" for k, v in c.items()))
# Each fused variant compiles for seconds: the fast lane keeps the fused path on the
# vicsek rule (periodic, the small-N all-pairs visit, the plane) and every rule per step;
# --all runs every case on both schedules.
@pytest.mark.fast_cases("fused-rule=vicsek-eta=0.0", "fused-rule=vicsek-eta=0.9-N=30",
                        "fused-rule=vicsek-eta=0.4-L=None-move=new_heading",
                        "per_step-rule=vicsek-eta=0.9-L=2.5", "per_step-rule=average",
                        "per_step-rule=average-eta=0.2-N=30-L=None",
                        "per_step-rule=laplacian-g=100.0-L=None-inclusive=False",
                        "per_step-rule=leader-L=None-leader_heading=0.7",
                        "per_step-rule=leader-eta=0.3-leader_heading=-1.0")
def test_matches_brute_force_step_by_step(path, case):
    sc = scenario(**case)
    _, sink = run_frames(sc)
    p = sc.model
    L = sc.space.L if sc.space.kind == "periodic" else None
    pos, theta = sink.pos[0].copy(), sink.theta[0].copy()
    ids = np.arange(sc.n_agents)
    for step in range(sc.time.steps):
        noise = rng.uniform_np(rng.step_key(sc.seed, 0, step), ids)
        pos, theta = vicsek_step(
            pos, theta, rule=p.rule, r=1.0, L=L, inclusive=sc.inclusive, v0dt=p.v0,
            eta=p.eta, g=p.g, theta0=p.leader_heading, noise=noise,
            move_new=p.position_update == "new_heading",
        )
        assert np.abs(wrapped_diff(sink.pos[step + 1], pos, L)).max() < 1e-9, step
        # The vicsek rule's headings are angles (reported in (-pi, pi]); the others are
        # real numbers and compare as such.
        period = 2 * np.pi if p.rule == "vicsek" else None
        assert np.abs(wrapped_diff(sink.theta[step + 1], theta, period)).max() < 1e-9, step


def test_laplacian_keeps_the_mean_heading(taichi_cpu):
    sc = scenario(rule="laplacian", g=61.0, steps=50, every=10)
    _, sink = run_frames(sc)
    means = [t.mean() for t in sink.theta]
    assert np.ptp(means) < 1e-12
    assert np.ptp(sink.theta[-1]) < np.ptp(sink.theta[0])  # ... while the headings agree


@pytest.mark.parametrize("rule", ["average", "leader"])
def test_consensus_on_a_connected_static_graph(taichi_cpu, rule):
    # v0 = 0 freezes a connected chain-like graph: the theorems' hypotheses hold for ever.
    xs = np.arange(12, dtype=float) * 0.9
    sc = Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": rule, "v0": 0.0, "leader_heading": 0.4},
        "space": {"kind": "plane"},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "explicit", "positions": [[x, 0.0] for x in xs],
                    "headings": list(np.linspace(-1.5, 1.5, 12))},
        "time": {"steps": 3000},
        "recording": {"observables_every": 100},
        "convergence": {"tolerance": 1e-6},
    })
    result = kernels.run(sc)
    assert result.final["components"] == 1
    assert result.final["heading_spread"] < 1e-6
    assert result.convergence["heading_spread"] is not None
    if rule == "leader":
        assert result.final["leader_error"] < 1e-6  # converged to theta_0


def test_full_noise_polarization_matches_random_headings(taichi_cpu):
    n, steps = 1000, 200
    sc = scenario(rule="vicsek", N=n, L=20.0, eta=2 * math.pi, steps=steps, every=0)
    result = kernels.run(sc)
    phi = result.observables["polarization"][1:]  # after the first noisy update
    expected = math.sqrt(math.pi / (4 * n))
    stderr = math.sqrt((1 - math.pi / 4) / n) / math.sqrt(len(phi))
    assert abs(phi.mean() - expected) < 4 * stderr, (phi.mean(), expected, stderr)


def test_no_noise_all_in_range_aligns_in_one_step(path):
    sc = scenario(rule="vicsek", N=200, L=10.0, steps=1, every=0,
                  region={"kind": "disc", "center": [5, 5], "radius": 0.45})
    result = kernels.run(sc)
    assert result.observables["polarization"][0] < 0.5
    assert result.final["polarization"] == pytest.approx(1.0, abs=1e-12)
    assert result.observables["degree_mean"][0] == 199  # everyone saw everyone


def test_same_seed_same_trajectory_bit_for_bit(path):
    a = run_frames(scenario(eta=1.0, N=2000, L=20.0, steps=15))[1]
    b = run_frames(scenario(eta=1.0, N=2000, L=20.0, steps=15))[1]
    c = run_frames(scenario(eta=1.0, N=2000, L=20.0, steps=15, seed=12))[1]
    assert all((x == y).all() for x, y in zip(a.pos, b.pos, strict=True))
    assert all((x == y).all() for x, y in zip(a.theta, b.theta, strict=True))
    assert not (a.theta[-1] == c.theta[-1]).all()


@pytest.mark.slow_cases("per_step", "fused")
@pytest.mark.resets_taichi
def test_thread_count_does_not_change_the_trajectory(path):
    base = scenario(eta=1.0, N=3000, L=25.0, steps=10)
    one = run_frames(base.model_copy(update={"threads": 1}))[1]
    two = run_frames(base.model_copy(update={"threads": 2}))[1]
    assert all((x == y).all() for x, y in zip(one.theta, two.theta, strict=True))
    assert all((x == y).all() for x, y in zip(one.pos, two.pos, strict=True))


def test_linked_intervals_counted(path):
    sc = scenario(rule="average", N=40, L=4.0, steps=30, every=0)  # dense: always connected
    result = kernels.run(sc)
    li = result.extra["linked_intervals"]
    assert li["count"] == 30 and li["longest_steps"] == 1


@pytest.mark.parametrize("rule,observables,tracked", [
    ("vicsek", None, False),  # no theorem covers the vicsek rule: not tracked by default
    ("vicsek", ["polarization", "linked_intervals"], True),  # named: tracked
    ("average", None, True),  # Theorem 2's rule: tracked by default
    ("average", ["polarization"], False),  # a list without it: not tracked
])
def test_linked_intervals_are_tracked_when_asked_for(path, rule, observables, tracked):
    sc = scenario(rule=rule, N=40, L=4.0, steps=12, every=0)
    sc = sc.model_copy(update={"recording": sc.recording.model_copy(
        update={"observables": observables})})
    result = kernels.run(sc)
    assert ("linked_intervals" in result.extra) is tracked
    assert ("linked_intervals" in result.observables) is tracked
    if tracked:  # dense: linked at every step
        assert result.extra["linked_intervals"]["count"] == 12


def test_blow_up_is_reported_with_its_step(path):
    sc = scenario(rule="vicsek", L=None, v0=1e300, steps=50, every=5)
    result = kernels.run(sc)
    assert result.status == "diverged"
    assert result.error["step"] <= 2
    assert "non-finite" in result.error["message"] or "spans" in result.error["message"]
    assert result.steps < 50


@pytest.mark.parametrize("L", [6.0, None])
def test_graph_observables_match_brute_force(path, L):
    """Degrees and components of G(0), as fused into the step kernel, against numpy."""
    from scipy.sparse.csgraph import connected_components

    from tests.reference import adjacency

    sc = scenario(N=150, L=L, r=0.4, steps=1, every=1, inclusive=False,
                  region=None if L else {"kind": "box", "low": [0, 0], "high": [6, 6]})
    result, sink = run_frames(sc)
    a = adjacency(sink.pos[0], 0.4, L, inclusive=False)
    deg = a.sum(axis=1)
    obs = {k: v[0] for k, v in result.observables.items()}
    assert obs["components"] == connected_components(a, directed=False)[0] > 1
    assert obs["degree_mean"] == pytest.approx(deg.mean(), abs=1e-12)
    assert (obs["degree_min"], obs["degree_max"]) == (deg.min(), deg.max())
    assert obs["isolated"] == np.count_nonzero(deg == 0)


@pytest.mark.parametrize("n", [1000, 40_000])
@pytest.mark.parametrize("spread", [0.0, 1e-6, 0.5, 3.0, 6.2, "even", "full", "hole"])
def test_bucketed_circular_spread_equals_the_sorted_one(taichi_cpu, spread, n):
    # N/8 buckets first, N when their largest gap is under a bucket: "even" (equal gaps
    # of 2 pi / N: the first pass cannot tell) and "full" (uniform on the circle: at
    # N = 1000 the largest gap is under a bucket of N/8, at 40000 over it) take both paths;
    # "hole" hides the largest gap inside one N/8 bucket (7/8 of it wide, every gap
    # between buckets 1/8): a first pass trusted too readily answers the small gap.
    import taichi as ti

    from flocklab.kernels.models.vicsek.kernel import VicsekKernel
    from flocklab.kernels.space.observables import circular_spread

    k = VicsekKernel(scenario(N=n), taichi_cpu.policy)
    gen = np.random.default_rng(n + (7 if isinstance(spread, str) else int(spread * 10)))
    if spread in ("even", "hole"):
        idx = np.arange(n)
        if spread == "hole":  # bucket 10 keeps its first and last; the rest repeat others
            idx[81:87] = idx[:6]
        theta = 2 * np.pi * (idx + 0.1) / n  # clear of the bucket edges
    elif spread == "full":
        theta = gen.uniform(-np.pi, np.pi, size=n)
    else:
        theta = gen.uniform(2.0, 2.0 + spread, size=n) + 2 * np.pi * gen.integers(-3, 3, n)
    arr = ti.ndarray(ti.f64, shape=(n, 2))
    arr.from_numpy(np.stack([np.cos(theta), np.sin(theta)], axis=1))
    assert k.circular_spread(arr) == pytest.approx(circular_spread(theta), abs=1e-12)
    if not isinstance(spread, str):  # the draws span the arc they were drawn from
        assert spread - 5e-2 <= circular_spread(theta) <= spread + 1e-12
