"""An independent numpy reference of the Cucker–Smale model: O(N^2) pair matrices, its own
Euler and RK4, sharing no code with the engine."""

from __future__ import annotations

import numpy as np


def accel(x: np.ndarray, v: np.ndarray, *, K: float, sigma: float, beta: float,
          coupling: float, normalization: str, cutoff: float | None) -> np.ndarray:
    """dv_i/dt = (lambda / D_i) sum_j psi(|x_j - x_i|) (v_j - v_i), psi = K / (sigma^2 +
    r^2)^beta (0 from the cutoff on); D_i = N, 1 or sum_j psi_ij (i included)."""
    n = len(x)
    dx = x[None, :, :] - x[:, None, :]
    r2 = (dx**2).sum(axis=-1)
    psi = K / (sigma**2 + r2) ** beta
    if cutoff is not None:
        psi = np.where(r2 < cutoff**2, psi, 0.0)
    dv = v[None, :, :] - v[:, None, :]
    s = (psi[..., None] * dv).sum(axis=1)
    den = {"mean": np.full(n, float(n)), "sum": np.ones(n), "local": psi.sum(axis=1)}
    return coupling * s / den[normalization][:, None]


def step(x: np.ndarray, v: np.ndarray, dt: float, integrator: str, **p) -> tuple:
    """One step: semi-implicit Euler (v' = v + dt a(x, v), x' = x + dt v') or RK4."""
    if integrator == "semi_implicit_euler":
        v1 = v + dt * accel(x, v, **p)
        return x + dt * v1, v1
    k1x, k1v = v, accel(x, v, **p)
    k2x, k2v = v + dt / 2 * k1v, accel(x + dt / 2 * k1x, v + dt / 2 * k1v, **p)
    k3x, k3v = v + dt / 2 * k2v, accel(x + dt / 2 * k2x, v + dt / 2 * k2v, **p)
    k4x, k4v = v + dt * k3v, accel(x + dt * k3x, v + dt * k3v, **p)
    return (x + dt / 6 * (k1x + 2 * k2x + 2 * k3x + k4x),
            v + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v))


def diameter(a: np.ndarray) -> float:
    """max_ij |a_i - a_j|."""
    d = a[None, :, :] - a[:, None, :]
    return float(np.sqrt((d**2).sum(axis=-1).max()))


def sparse_accel(x: np.ndarray, v: np.ndarray, *, K: float, sigma: float, beta: float,
                 coupling: float, normalization: str, cutoff: float) -> np.ndarray:
    """`accel` with a cutoff at large N: the pairs closer than it from a k-d tree."""
    from scipy.spatial import cKDTree

    n = len(x)
    pairs = cKDTree(x).query_pairs(cutoff, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    r2 = ((x[j] - x[i]) ** 2).sum(axis=1)
    keep = r2 < cutoff**2  # query_pairs is <=; the model's test is <
    i, j, r2 = i[keep], j[keep], r2[keep]
    psi = K / (sigma**2 + r2) ** beta
    term = psi[:, None] * (v[j] - v[i])
    s = np.zeros_like(v)
    np.add.at(s, i, term)
    np.add.at(s, j, -term)
    den = {"mean": np.full(n, float(n)), "sum": np.ones(n)}.get(normalization)
    if den is None:
        den = np.full(n, K / sigma ** (2 * beta))
        np.add.at(den, i, psi)
        np.add.at(den, j, psi)
    return coupling * s / den[:, None]
