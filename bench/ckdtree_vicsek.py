"""The alternative a Python user would write: numpy + scipy.spatial.cKDTree, same workload.

Vicsek rule, periodic box (cKDTree's boxsize), pairs within r from `query_pairs`,
sums by `np.bincount`, polarization every 10 steps.
"""

import math
import time

import numpy as np
from scipy.spatial import cKDTree


def run(n: int, steps: int, r: float = 1.0, v0: float = 0.03, eta: float = 0.5,
        seed: int = 1) -> float:
    """Wall seconds for `steps` steps."""
    L = math.sqrt(n / 4.0)
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0, L, size=(n, 2))
    theta = rng.uniform(-math.pi, math.pi, size=n)
    t0 = time.perf_counter()
    for step in range(steps):
        tree = cKDTree(pos, boxsize=L)
        pairs = tree.query_pairs(r, output_type="ndarray")
        c, s = np.cos(theta), np.sin(theta)
        sc = c + np.bincount(pairs[:, 0], c[pairs[:, 1]], n) + np.bincount(pairs[:, 1],
                                                                           c[pairs[:, 0]], n)
        ss = s + np.bincount(pairs[:, 0], s[pairs[:, 1]], n) + np.bincount(pairs[:, 1],
                                                                           s[pairs[:, 0]], n)
        pos = np.mod(pos + v0 * np.stack([c, s], axis=1), L)
        pos[pos >= L] -= L
        theta = np.arctan2(ss, sc) + eta * (rng.uniform(size=n) - 0.5)
        if step % 10 == 0:
            _ = np.hypot(np.cos(theta).sum(), np.sin(theta).sum()) / n
    return time.perf_counter() - t0
