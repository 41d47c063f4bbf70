"""Reductions: one run's observable series to a number, and replicas to mean/sd/sem."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from flocklab.schemas.sweep import Measure


def reduce_run(m: Measure, observables: dict[str, np.ndarray], tolerance: float) -> float | None:
    """The measure of one run over its window [from_step, to_step] (both included);
    None when the window holds no observation, or for converge_time when the value never
    settles below the tolerance. `tolerance` is the scenario's, used unless the measure
    gives its own."""
    step = observables["step"]
    lo = m.from_step if m.from_step is not None else 0
    hi = m.to_step if m.to_step is not None else math.inf
    window = (step >= lo) & (step <= hi)
    v = observables[m.observable][window]
    if len(v) == 0:
        return None
    if m.reduce == "converge_time":
        from flocklab.kernels.checks import time_to_converge  # the engine's own definition

        tol = m.tolerance if m.tolerance is not None else tolerance
        return time_to_converge(observables["time"][window], v, tol)
    value = {
        "mean": np.mean,
        "std": np.std,  # population std (ddof 0): the fluctuation within one run
        "final": lambda a: a[-1],
        "min": np.min,
        "max": np.max,
    }[m.reduce](v)
    return float(value)


def replica_stats(values: Sequence[float | None]) -> tuple[float | None, float | None,
                                                           float | None, int]:
    """(mean, sd, sem, count) over the replicas that have a finite value; sd is the
    sample standard deviation (ddof 1), None below two values, sem = sd / sqrt(count)."""
    x = np.array([v for v in values if v is not None and math.isfinite(v)], dtype=np.float64)
    n = len(x)
    if n == 0:
        return None, None, None, 0
    mean = float(x.mean())
    if n < 2:
        return mean, None, None, n
    sd = float(x.std(ddof=1))
    return mean, sd, sd / math.sqrt(n), n
