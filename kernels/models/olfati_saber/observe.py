"""numpy-side quality measures of the Olfati-Saber model (section VIII of the paper), at
observation steps only, from device arrays read a block of rows at a time
(kernels/space/stream.py): no N-sized host copy.

  deviation_energy       E~ = sum_{(i,j) in E} (|q_j - q_i| - d)^2 / (d^2 (|E| + 1)), E
                         the proximity graph's (unordered) edges |q_j - q_i| < r
  relative_connectivity  C = rank(L) / (n - 1) = (n - components) / (n - 1): the rank of
                         a graph Laplacian is n minus its number of connected components,
                         so no matrix is formed; the components come from the union-find
                         of every edge on the grid (step.py's `observe`) at any N
  velocity_mismatch      K = (1/2) sum_i |p_i - mean p|^2
  cohesion_radius        max_i |q_i - mean q|
  min_obstacle_distance  min_{i,k} of q_i's distance to obstacle k's surface (Algorithm 3)
  leader_distance        |mean q - q_r(t)| (Algorithms 2 and 3)
  mean_velocity_*        (1/N) sum_i p_i (conserved by Algorithm 1)
"""

from __future__ import annotations

import numpy as np

from ...space.stream import PairwiseSum, Rows, RowSum, blocks


def relative_connectivity(n: int, components: int) -> float:
    """rank(L) / (n - 1) from the number of components (1 for a single agent)."""
    return 1.0 if n < 2 else (n - components) / (n - 1)


def deviation_energy(total: float, edges: float, d: float) -> float:
    """E~ from the sum of (|q_ij| - d)^2 over the edges and their number."""
    return total / (d * d * (edges + 1.0))


def observe(pos, vel, share, gap, components: int, d: float, leader: np.ndarray | None,
            obstacles: bool) -> dict[str, float]:
    """Every observable of the state (pos, vel: (N, dim) device arrays, any order; share
    (N, >=2) each agent's (sum_j (|q_ij| - d)^2, |N_i|), every edge counted from both
    ends; gap[:, 0] each agent's distance to the nearest obstacle)."""
    n, dim = vel.shape
    vrows, prow = Rows(vel), Rows(pos)
    vsum, psum = RowSum(), RowSum()
    for lo, hi in blocks(n):
        vsum.add(vrows.wide(lo, hi))
        psum.add(prow.wide(lo, hi))
    vmean, pmean = vsum.total() / n, psum.total() / n
    spread = PairwiseSum(n)
    radius = 0.0
    for lo, hi in blocks(n):
        dv = vrows.wide(lo, hi) - vmean
        spread.add(np.einsum("ak,ak->a", dv, dv))
        dq = prow.wide(lo, hi) - pmean
        radius = max(radius, float(np.einsum("ak,ak->a", dq, dq).max()))
    srows = Rows(share)
    energy, degree = PairwiseSum(n), PairwiseSum(n)
    for lo, hi in blocks(n):
        s = srows.wide(lo, hi)
        energy.add(s[:, 0].copy())
        degree.add(s[:, 1].copy())
    out = {"deviation_energy": deviation_energy(energy.total() / 2, degree.total() / 2, d),
           "relative_connectivity": relative_connectivity(n, components),
           "velocity_mismatch": 0.5 * spread.total(),
           "cohesion_radius": float(np.sqrt(radius))}
    if obstacles:
        grows = Rows(gap)
        out["min_obstacle_distance"] = min(float(grows.wide(lo, hi)[:, 0].min())
                                           for lo, hi in blocks(n))
    if leader is not None:
        out["leader_distance"] = float(np.linalg.norm(pmean - leader))
    for c, axis in enumerate("xyz"[:dim]):
        out[f"mean_velocity_{axis}"] = float(vmean[c])
    return out
