"""Order-parameter statistics (reduce moments / binder / susceptibility / tau_int): tau_int
of AR(1) series of known coefficient, the tau_int-aware sem against the spread of
independent series, the pooled table cells against numpy, and the engine's Vicsek runs
against exact values: the Binder cumulant of random headings and of an aligned swarm.

Exact values used (derived in docs/SWEEPS.md, "Transition statistics"):
- AR(1) x_t = a x_{t-1} + e_t: rho(t) = a^t, tau_int = 1/2 + sum_t a^t = (1+a) / (2(1-a)).
- N iid uniform unit vectors in the plane, phi = |sum_i e_i| / N: <phi^2> = 1/N,
  <phi^4> = (2N^2 - N) / N^4, so G = 1 - <phi^4> / (3 <phi^2>^2) = 1/3 + 1/(3N).
- A constant phi: <phi^4> = <phi^2>^2, G = 2/3.
"""

import csv
import math

import numpy as np
import pytest
from scipy.signal import lfilter

from flocklab.schemas.sweep import Measure, SweepError, load_sweep
from flocklab.service.sweeps import run_sweep
from flocklab.service.sweeps.autocorr import integrated_time, time_mean
from flocklab.service.sweeps.measures import pooled_stats, reduce_run


def ar1(a, n, rng, size=None):
    """AR(1) series started in its stationary law (var 1 / (1 - a^2))."""
    e = rng.normal(size=(size or 1, n))
    e[:, 0] /= math.sqrt(1 - a * a)
    x = lfilter([1.0], [1.0, -a], e, axis=1)
    return x if size else x[0]


@pytest.mark.parametrize("a", [0.0, 0.5, 0.9, 0.97])
def test_tau_int_of_ar1_series(a):
    rng = np.random.default_rng(7)
    x = ar1(a, 400_000, rng)
    it = integrated_time(x)
    exact = (1 + a) / (2 * (1 - a))
    assert abs(it.tau - exact) < 3 * it.err, (it, exact)
    assert it.err < 0.06 * exact  # the error bar is tight enough for the check to bite
    assert it.window >= 6 * it.tau  # Sokal's window rule
    # Through the sweep measure, on an observable of any name, from a step window.
    obs = {"step": np.arange(len(x)), "time": np.arange(len(x), dtype=float), "x": x}
    m = Measure(observable="x", reduce="tau_int", from_step=1000)
    cols = reduce_run("t", m, obs, 1e-3, 1)
    assert cols["t"] == pytest.approx(integrated_time(x[1000:]).tau, rel=1e-12)
    assert cols["t_window"] == integrated_time(x[1000:]).window


def test_sem_of_a_time_mean_matches_the_spread_of_independent_runs():
    """sem = sqrt(2 tau var / n): 400 independent AR(1) runs (a = 0.8, tau = 4.5); their
    means scatter by the sem, not by the naive sd / sqrt(n) (3x smaller here)."""
    rng = np.random.default_rng(11)
    runs = ar1(0.8, 5000, rng, size=400)
    sems = np.array([time_mean(r).sem for r in runs])
    spread = runs.mean(axis=1).std(ddof=1)
    assert np.mean(sems) == pytest.approx(spread, rel=0.12)
    naive = np.mean(runs.std(axis=1) / math.sqrt(runs.shape[1]))
    assert spread / naive == pytest.approx(3.0, rel=0.15)


def test_constant_series():
    tm = time_mean(np.full(50, 0.7))
    assert (tm.mean, tm.sem, tm.tau) == (pytest.approx(0.7), 0.0, None)
    assert integrated_time(np.full(50, 0.7)) is None


def test_pooled_binder_and_susceptibility_against_numpy():
    rng = np.random.default_rng(3)
    m = rng.uniform(0.2, 0.9, size=(5, 3))  # (m1, m2, m4) of 5 replicas
    runs = [{"G": 0.1 * i, "G_err": 0.01 * (i + 1), "G_m2": r[1], "G_m4": r[2],
             "c": 0.2 * i, "c_err": 0.02, "c_m1": r[0], "c_m2": r[1]}
            for i, r in enumerate(m)]
    g = 1 - m[:, 2].mean() / (3 * m[:, 1].mean() ** 2)
    loo = [1 - np.delete(m, i, 0)[:, 2].mean() / (3 * np.delete(m, i, 0)[:, 1].mean() ** 2)
           for i in range(5)]
    jack = math.sqrt(4 / 5 * np.sum((np.array(loo) - np.mean(loo)) ** 2))
    value, sd, sem, err, count = pooled_stats("binder", runs, "G", 100)
    assert value == pytest.approx(g, rel=1e-12) and sem == pytest.approx(jack, rel=1e-12)
    assert sd == pytest.approx(np.std([0.1 * i for i in range(5)], ddof=1))
    assert err == pytest.approx(math.sqrt(sum((0.01 * (i + 1)) ** 2 for i in range(5))) / 5)
    assert count == 5
    value, *_ = pooled_stats("susceptibility", runs, "c", 100)
    assert value == pytest.approx(100 * (m[:, 1].mean() - m[:, 0].mean() ** 2), rel=1e-12)


def test_measure_columns_may_not_collide():
    doc = {"name": "x", "preset": "vicsek-1995",
           "measure": {"p": {"observable": "polarization", "reduce": "moments"},
                       "p_m1": {"observable": "polarization", "reduce": "mean"}}}
    with pytest.raises(SweepError, match=r"'p_m1' of runs\.csv"):
        load_sweep(doc)


def _sweep(eta, sizes, steps, **initial):
    return load_sweep({
        "name": "headings", "preset": "vicsek-1995",
        "overrides": {"model": {"eta": eta}, "time": {"steps": steps},
                      "initial": initial,
                      "recording": {"every": 0, "observables_every": 1,
                                    "observables": ["polarization"]}},
        "axes": [{"zip": [{"path": "initial.N", "values": sizes},
                          {"path": "space.L", "values": [math.sqrt(n / 4) for n in sizes]}]}],
        "measure": {"G": {"observable": "polarization", "reduce": "binder"},
                    "phi": {"observable": "polarization", "reduce": "moments"},
                    "tau": {"observable": "polarization", "reduce": "tau_int"}},
        "keep": "table"})


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow
def test_binder_cumulant_of_random_headings(tmp_path, taichi_cpu):
    """eta = 2 pi: each new heading is the neighbours' mean plus noise uniform in
    [-pi, pi], so the headings are iid uniform every step (and at step 0), the series of
    phi is uncorrelated (tau_int = 1/2) and G = 1/3 + 1/(3N)."""
    sizes = [10, 100, 1000]
    out = run_sweep(_sweep(2 * math.pi, sizes, 20_000), tmp_path / "s")
    assert out.status == "completed"
    table = _rows(tmp_path / "s" / "table.csv")
    assert [int(r["initial.N"]) for r in table] == sizes
    for row, n in zip(table, sizes, strict=True):
        g, err = float(row["G_mean"]), float(row["G_err"])
        # iid phi^2 ~ N^-1 Exp(1) for large N gives sd(G) = 2 / (3 sqrt(n)), n = 20001.
        assert err == pytest.approx(2 / (3 * math.sqrt(20_001)), rel=0.25)
        assert abs(g - (1 / 3 + 1 / (3 * n))) < 3 * err, (n, g, err)
        assert abs(float(row["tau_mean"]) - 0.5) < 3 * float(row["tau_err"])
        m2, m2_err = float(row["phi_m2_mean"]), float(row["phi_m2_err"])
        assert abs(m2 * n - 1) < 3 * m2_err * n  # <phi^2> = 1/N
    # The check can fail: at N = 10 the large-N value 1/3 is many error bars away.
    g10, err10 = float(table[0]["G_mean"]), float(table[0]["G_err"])
    assert abs(g10 - 1 / 3) > 6 * err10


def test_binder_cumulant_of_an_aligned_swarm(tmp_path, taichi_cpu):
    """eta = 0 and one common initial heading: every heading stays the same, phi = 1 at
    every step, <phi^4> = <phi^2>^2 and G = 2/3 (the ordered phase's value)."""
    run_sweep(_sweep(0.0, [100], 500, heading_range=[0.3, 0.3]), tmp_path / "s")
    (row,) = _rows(tmp_path / "s" / "table.csv")
    assert float(row["G_mean"]) == pytest.approx(2 / 3, abs=1e-6)
    assert float(row["phi_m1_mean"]) == pytest.approx(1.0, abs=1e-6)
    assert float(row["G_err"]) < 1e-6
