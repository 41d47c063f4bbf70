"""numpy-side observables of the Cucker–Smale model, at observation steps only, from the
device arrays read a block of rows at a time (kernels/space/stream.py): no N-sized host
copy.

  velocity_diameter  max_ij |v_i - v_j|  (the paper's Gamma-like flocking measure: 0 when
                     every velocity agrees)
  position_diameter  max_ij |x_i - x_j|  (bounded for beta < 1/2, Theorem 1)
  mean_velocity_*    (1/N) sum_i v_i     (conserved under mean/sum normalisation)
  velocity_variance  (1/N) sum_i |v_i - mean v|^2

A diameter is attained at two vertices of the convex hull: each block's points are
reduced to the hull of (the last hull's vertices, the block) (scipy's Qhull), and the
vertices left are compared pair by pair. A degenerate set (collinear, coplanar, equal
points) is hulled in the affine subspace it spans. Up to BRUTE points are compared pair
by pair outright.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ...space.stream import BLOCK, PairwiseSum, Rows, RowSum, blocks

BRUTE = 2048  # pairwise comparison outright up to this many points
PAIR_BLOCK = 256  # rows per block of the pairwise comparison


def max_pair_distance(p: np.ndarray) -> float:
    """max_ij |p_i - p_j| by comparing every pair (blocks of PAIR_BLOCK rows)."""
    best = 0.0
    for lo in range(0, len(p), PAIR_BLOCK):
        d = p[lo:lo + PAIR_BLOCK, None, :] - p[None, :, :]
        best = max(best, float(np.einsum("abk,abk->ab", d, d).max()))
    return float(np.sqrt(best))


def hull_points(p: np.ndarray) -> np.ndarray:
    """The points of p that may end a diameter: its hull's vertices (of the affine
    subspace p spans, when p is degenerate)."""
    if len(p) <= 2 * p.shape[1] + 2:
        return p
    try:
        return p[ConvexHull(p).vertices]
    except QhullError:
        pass
    c = p.mean(axis=0)
    _, s, vt = np.linalg.svd(p - c, full_matrices=False)
    rank = int(np.sum(s > s[0] * 1e-12)) if s[0] > 0 else 0
    if rank == 0:
        return p[:1]
    y = (p - c) @ vt[:rank].T
    if rank == 1:
        return p[[int(np.argmin(y[:, 0])), int(np.argmax(y[:, 0]))]]
    try:
        return p[ConvexHull(y).vertices]
    except QhullError:  # nearly degenerate beyond Qhull's tolerance: keep every point
        return p


def diameter(rows: Rows, n: int, block: int = BLOCK) -> float:
    """max_ij |a_i - a_j| of the device array that `rows` reads (n rows, `block` at a
    time: the block size `rows` was made with)."""
    if n <= BRUTE:
        return max_pair_distance(rows.wide(0, n).copy())
    cand = None
    for lo, hi in blocks(n, block):
        block = rows.wide(lo, hi)
        pts = block if cand is None else np.concatenate([cand, block])
        cand = hull_points(pts).copy()
    return max_pair_distance(cand)


def observe(pos, vel) -> dict[str, float]:
    """Every observable of the state (pos, vel: (N, dim) device arrays, any order)."""
    n, dim = vel.shape
    vrows = Rows(vel)
    total = RowSum()
    for lo, hi in blocks(n):
        total.add(vrows.wide(lo, hi))
    mean = total.total() / n
    spread = PairwiseSum(n)
    for lo, hi in blocks(n):
        d = vrows.wide(lo, hi) - mean
        spread.add(np.einsum("ak,ak->a", d, d))
    out = {"velocity_diameter": diameter(vrows, n),
           "position_diameter": diameter(Rows(pos), n)}
    for c, axis in enumerate("xyz"[:dim]):
        out[f"mean_velocity_{axis}"] = float(mean[c])
    out["velocity_variance"] = spread.total() / n
    return out
