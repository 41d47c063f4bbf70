"""Time-series statistics of one run's observable: the integrated autocorrelation time
and the standard error of a time average (or of a smooth function of several averages).

Conventions (Sokal, "Monte Carlo methods in statistical mechanics: foundations and new
algorithms", Cargèse lectures 1996, §3; Madras & Sokal, J. Stat. Phys. 50, 109 (1988)):

  C(t)   = 1/(n - t) * sum_{s=0}^{n-1-t} (x_s - xbar)(x_{s+t} - xbar)   autocovariance
  rho(t) = C(t) / C(0)
  tau(W) = 1/2 + sum_{t=1}^{W} rho(t)                                    windowed tau_int
  W      = the smallest W >= 1 with W >= c * tau(W), c = SOKAL_C         automatic window
  err(tau) = tau * sqrt(2 (2W + 1) / n)                                  Madras & Sokal's variance
  sem(xbar) = sqrt(2 tau C(0) / n)                                       var(xbar) = 2 tau C(0)/n

tau is in units of the sampling interval of the series (for a run's observables, the
interval `recording.observables_every`); in this convention an uncorrelated series has
tau = 1/2 and an AR(1) series x_t = a x_{t-1} + noise has tau = (1 + a) / (2 (1 - a)).

The error of f(mean(x_1), ..., mean(x_k)) for a smooth f is the sem of the time mean of
the linearised series y_t = sum_j df/dm_j * x_{j,t} (the delta method with the series'
own tau_int: Wolff's Gamma method, Comput. Phys. Commun. 156, 143 (2004)).

The series is held in memory (the engine returns a run's observables as arrays) and C(t)
is computed for every lag at once by FFT, O(n log n).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Sokal's window factor: c ~ 4 suffices for a purely exponential autocorrelation, c ~ 6-10
# for a slower tail; 6 keeps the truncation bias e^{-c} small at a modest variance cost.
SOKAL_C = 6.0


@dataclass(frozen=True)
class IntegratedTime:
    """tau_int of a series (sampling intervals), its window W, its error, the length n
    and the variance C(0) (ddof 0)."""

    tau: float
    window: int
    err: float
    n: int
    variance: float


def autocovariance(x: np.ndarray) -> np.ndarray:
    """C(t) for t = 0 .. n-1, each lag averaged over its n - t products."""
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    d = x - x.mean()
    # Zero-padding to 2n makes the circular correlation of the FFT the linear one.
    f = np.fft.rfft(d, 2 * n)
    acf = np.fft.irfft(f * np.conj(f), 2 * n)[:n]
    return acf / np.arange(n, 0, -1)


def integrated_time(x: np.ndarray, c: float = SOKAL_C) -> IntegratedTime | None:
    """Sokal's windowed tau_int (see the module docstring); None for fewer than two values
    or a constant series (no fluctuation: rho is undefined). When no W < n satisfies the
    window rule (a series shorter than about c * tau), W = n - 1 and the estimate is
    unreliable: the caller sees window == n - 1."""
    n = len(x)
    if n < 2 or np.ptp(x) == 0:  # (a constant's mean leaves rounding residues in C(0))
        return None
    cov = autocovariance(x)
    var = float(cov[0])
    if not var > 0.0 or not math.isfinite(var):
        return None
    taus = 0.5 + np.cumsum(cov[1:] / var)  # tau(W) for W = 1 .. n-1
    windows = np.arange(1, n)
    ok = windows >= c * taus
    w = int(windows[np.argmax(ok)]) if ok.any() else n - 1
    tau = float(taus[w - 1])
    return IntegratedTime(tau, w, abs(tau) * math.sqrt(2.0 * (2 * w + 1) / n), n, var)


@dataclass(frozen=True)
class TimeMean:
    """A time average, its standard error (from tau_int) and the tau_int used (None for
    a constant series, whose sem is 0)."""

    mean: float
    sem: float
    tau: float | None


def time_mean(x: np.ndarray) -> TimeMean | None:
    """mean(x) with sem = sqrt(2 tau_int C(0) / n); None for an empty series, sem NaN for
    one value. A negative tau estimate (strong anti-correlation at lag 1, which the window
    rule does not guard against) counts as 0 in the sem."""
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    if n == 0:
        return None
    mean = float(x.mean())
    if n == 1:
        return TimeMean(mean, math.nan, None)
    it = integrated_time(x)
    if it is None:  # constant: every value equals the mean
        return TimeMean(mean, 0.0, None)
    return TimeMean(mean, math.sqrt(2.0 * max(it.tau, 0.0) * it.variance / n), it.tau)


def linearised_sem(terms: list[tuple[float, np.ndarray]]) -> float:
    """The sem of f(mean(x_1), ...) from its gradient: terms = [(df/dm_j, x_j), ...], the
    sem of the time mean of y = sum_j df/dm_j x_j (the Gamma method)."""
    y = sum(g * np.asarray(x, dtype=np.float64) for g, x in terms)
    tm = time_mean(np.asarray(y))
    return math.nan if tm is None else tm.sem
