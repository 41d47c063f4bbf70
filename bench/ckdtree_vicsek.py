"""The alternative a Python user would write: numpy + scipy.spatial.cKDTree, same workload.

Vicsek rule, periodic box (cKDTree's boxsize), pairs within r (<=) from `query_pairs`,
sums by `np.bincount`, theta(t+1) = arg(sum of neighbours' unit vectors) + xi; the move
uses theta(t) (`run`, the engine benchmark's workload) or theta(t+1) (`polarization`, the
sweep benchmark's Fig. 2a protocol).
"""

import math
import time

import numpy as np
from scipy.spatial import cKDTree


def _step(pos, theta, L, r, v0, eta, rng, new_heading):
    n = len(theta)
    tree = cKDTree(pos, boxsize=L)
    pairs = tree.query_pairs(r, output_type="ndarray")
    c, s = np.cos(theta), np.sin(theta)
    i, j = pairs[:, 0], pairs[:, 1]
    sc = c + np.bincount(i, c[j], n) + np.bincount(j, c[i], n)
    ss = s + np.bincount(i, s[j], n) + np.bincount(j, s[i], n)
    theta_new = np.arctan2(ss, sc) + eta * (rng.uniform(size=n) - 0.5)
    phi = theta_new if new_heading else theta
    pos = np.mod(pos + v0 * np.stack([np.cos(phi), np.sin(phi)], axis=1), L)
    pos[pos >= L] -= L
    return pos, theta_new


def _start(n, L, seed):
    rng = np.random.default_rng(seed)
    return rng, rng.uniform(0, L, size=(n, 2)), rng.uniform(-math.pi, math.pi, size=n)


def run(n: int, steps: int, r: float = 1.0, v0: float = 0.03, eta: float = 0.5,
        seed: int = 1, observe_every: int = 10) -> float:
    """Wall seconds for `steps` steps (density 4), polarization every `observe_every`."""
    L = math.sqrt(n / 4.0)
    rng, pos, theta = _start(n, L, seed)
    t0 = time.perf_counter()
    for step in range(steps):
        pos, theta = _step(pos, theta, L, r, v0, eta, rng, new_heading=False)
        if step % observe_every == 0:
            _ = np.hypot(np.cos(theta).sum(), np.sin(theta).sum()) / n
    return time.perf_counter() - t0


def polarization(n: int, L: float, eta: float, steps: int, seed: int, r: float = 1.0,
                 v0: float = 0.03) -> np.ndarray:
    """The polarization |sum e(theta_i)| / N at every step 0 .. steps (new-heading move)."""
    rng, pos, theta = _start(n, L, seed)
    out = np.empty(steps + 1)
    out[0] = np.hypot(np.cos(theta).sum(), np.sin(theta).sum()) / n
    for step in range(steps):
        pos, theta = _step(pos, theta, L, r, v0, eta, rng, new_heading=True)
        out[step + 1] = np.hypot(np.cos(theta).sum(), np.sin(theta).sum()) / n
    return out
