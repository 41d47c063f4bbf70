"""Reductions: one run's observable series to its runs.csv columns, and a grid point's
replicas to table.csv's mean/sd/sem/err/count.

The order-parameter statistics (reduce moments, binder, susceptibility, tau_int) follow
the finite-size-scaling literature for an order parameter x (Binder, Z. Phys. B 43, 119
(1981); for Vicsek's model Chaté, Ginelli, Grégoire & Raynaud, PRE 77, 046113 (2008)):

  m_k = <x^k>  (the time average over the measure's window)
  G   = 1 - m_4 / (3 m_2^2)          the Binder cumulant
  chi = N (m_2 - m_1^2)              the susceptibility, N the run's number of agents

each with its standard error from the series' tau_int (autocorr.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from flocklab.schemas.sweep import Measure

from .autocorr import integrated_time, linearised_sem, time_mean

Stats = tuple[float | None, float | None, float | None, int]


def reduce_run(name: str, m: Measure, observables: dict[str, np.ndarray], tolerance: float,
               n_agents: int) -> dict[str, float | None]:
    """The columns (`m.run_columns(name)`) of one run over the window [from_step,
    to_step] (both included); None where the window holds no observation, for
    converge_time when the value never settles below the tolerance, and for tau_int of a
    constant series. `tolerance` is the scenario's, used unless the measure gives its
    own; `n_agents` is the N of chi."""
    step = observables["step"]
    lo = m.from_step if m.from_step is not None else 0
    hi = m.to_step if m.to_step is not None else math.inf
    window = (step >= lo) & (step <= hi)
    v = np.asarray(observables[m.observable][window], dtype=np.float64)
    columns = m.run_columns(name)
    if len(v) == 0:
        return dict.fromkeys(columns)
    if m.reduce == "converge_time":
        from flocklab.kernels.checks import time_to_converge  # the engine's own definition

        tol = m.tolerance if m.tolerance is not None else tolerance
        return {name: time_to_converge(observables["time"][window], v, tol)}
    if m.reduce in ("moments", "binder", "susceptibility", "tau_int"):
        return dict(zip(columns, _order_statistics(m.reduce, v, n_agents), strict=True))
    value = {
        "mean": np.mean,
        "std": np.std,  # population std (ddof 0): the fluctuation within one run
        "final": lambda a: a[-1],
        "min": np.min,
        "max": np.max,
    }[m.reduce](v)
    return {name: float(value)}


def _order_statistics(reduce: str, x: np.ndarray, n_agents: int) -> list[float | None]:
    """The run columns of reduce moments / binder / susceptibility / tau_int, in the
    order of schemas.sweep.RUN_SUFFIXES."""
    if reduce == "tau_int":
        it = integrated_time(x)
        return [None, None, None] if it is None else [it.tau, it.err, float(it.window)]
    x2 = x * x
    x4 = x2 * x2
    if reduce == "moments":
        t1, t2, t4 = time_mean(x), time_mean(x2), time_mean(x4)
        assert t1 is not None and t2 is not None and t4 is not None  # x is not empty
        return [t1.mean, t1.sem, t2.mean, t2.sem, t4.mean, t4.sem, t1.tau]
    m1, m2, m4 = float(x.mean()), float(x2.mean()), float(x4.mean())
    if reduce == "binder":
        g, err = binder(m2, m4), None
        if m2 > 0:  # dG = -dm4 / (3 m2^2) + 2 m4 dm2 / (3 m2^3)
            err = linearised_sem([(-1.0 / (3 * m2 * m2), x4), (2 * m4 / (3 * m2 ** 3), x2)])
        return [g, err, m2, m4]
    # susceptibility: dchi = N (dm2 - 2 m1 dm1)
    err = linearised_sem([(float(n_agents), x2), (-2.0 * n_agents * m1, x)])
    return [susceptibility(m1, m2, n_agents), err, m1, m2]


def binder(m2: float, m4: float) -> float | None:
    """G = 1 - m4 / (3 m2^2); None when m2 = 0 (x identically 0)."""
    return 1.0 - m4 / (3.0 * m2 * m2) if m2 > 0 else None


def susceptibility(m1: float, m2: float, n_agents: int) -> float:
    """chi = N (m2 - m1^2)."""
    return n_agents * (m2 - m1 * m1)


def replica_stats(values: Sequence[float | None]) -> Stats:
    """(mean, sd, sem, count) over the replicas that have a finite value; sd is the
    sample standard deviation (ddof 1), None below two values, sem = sd / sqrt(count)."""
    x = _finite(values)
    n = len(x)
    if n == 0:
        return None, None, None, 0
    mean = float(x.mean())
    if n < 2:
        return mean, None, None, n
    sd = float(x.std(ddof=1))
    return mean, sd, sd / math.sqrt(n), n


def combined_error(errors: Sequence[float | None]) -> float | None:
    """The error of the mean of R runs' values from each run's own (tau_int-based) error:
    sqrt(sum err_i^2) / R over the runs that have one (independent runs)."""
    e = _finite(errors)
    return float(math.sqrt(float(np.sum(e * e))) / len(e)) if len(e) else None


def pooled_stats(reduce: str, runs: Sequence[dict[str, float | None]], name: str,
                 n_agents: int) -> tuple[float | None, float | None, float | None,
                                         float | None, int]:
    """(value, sd, sem, err, count) of binder or susceptibility over a point's replicas.

    value: G or chi of the pooled moments (the replicas' m_k averaged: the estimate over
    the whole ensemble, so a point where replicas sit in different phases shows it);
    sd: the sample sd of the runs' own values; sem: the jackknife over replicas (leave
    one out, sqrt((R-1)/R sum (v_(i) - mean v_(.))^2), R >= 2); err: combined_error of
    the runs' own errors (to first order the error of the pooled value too)."""
    keys = ("_m2", "_m4") if reduce == "binder" else ("_m1", "_m2")
    rows = [r for r in runs if all(_ok(r.get(name + k)) for k in keys)]
    if not rows:
        return None, None, None, None, 0
    m = np.array([[r[name + k] for k in keys] for r in rows], dtype=np.float64)

    def estimate(moments: np.ndarray) -> float | None:
        a, b = moments.mean(axis=0)
        return binder(a, b) if reduce == "binder" else susceptibility(a, b, n_agents)

    value = estimate(m)
    _, sd, _, _ = replica_stats([r.get(name) for r in rows])
    sem = None
    n = len(rows)
    if n >= 2 and value is not None:
        loo = [estimate(np.delete(m, i, axis=0)) for i in range(n)]
        if all(v is not None for v in loo):
            arr = np.array(loo, dtype=np.float64)
            sem = float(math.sqrt((n - 1) / n * float(np.sum((arr - arr.mean()) ** 2))))
    return value, sd, sem, combined_error([r.get(name + "_err") for r in rows]), n


def _ok(v: float | None) -> bool:
    return v is not None and math.isfinite(v)


def _finite(values: Sequence[float | None]) -> np.ndarray:
    return np.array([v for v in values if _ok(v)], dtype=np.float64)
