"""numpy-side observables of the flocking models, evaluated only at observation steps.

All values are finite floats (summary.json refuses NaN): quantities that are not computed
report -1 (lambda2 above its agent limit).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, laplacian
from scipy.sparse.linalg import ArpackNoConvergence, eigsh
from scipy.spatial import cKDTree

from ...space.observables import circular_spread

HIST_BINS = 16  # valency_hist_0 .. valency_hist_15, then valency_hist_16plus
DENSE_EIG_MAX = 32  # dense eigvalsh up to this N; sparse shift-invert (faster) above
NOT_COMPUTED = -1.0


def velocity_stats(vel: np.ndarray) -> dict[str, float]:
    """Mean velocity, disagreement sum_i |v_i - mean|^2 and max_i |v_i - mean|, speeds, and
    the circular spread of the headings."""
    mean = vel.mean(axis=0)
    dev2 = ((vel - mean) ** 2).sum(axis=1)
    if vel.shape[1] == 3:
        return velocity_stats_3d(vel, mean, dev2)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    return {
        "mean_velocity_x": float(mean[0]),
        "mean_velocity_y": float(mean[1]),
        "velocity_disagreement": float(dev2.sum()),
        "velocity_disagreement_max": float(np.sqrt(dev2.max())),
        "speed_min": float(speed.min()),
        "speed_mean": float(speed.mean()),
        "speed_max": float(speed.max()),
        "heading_spread": circular_spread(np.arctan2(vel[:, 1], vel[:, 0])),
    }


def velocity_stats_3d(vel: np.ndarray, mean: np.ndarray, dev2: np.ndarray
                      ) -> dict[str, float]:
    """`velocity_stats` in 3D: mean_velocity_z joins _x and _y; the heading spread is twice
    the largest angle between a velocity's direction and the mean direction (2 pi when the
    mean is zero; zero velocities count as the x axis)."""
    speed = np.linalg.norm(vel, axis=1)
    e = np.zeros_like(vel)
    e[:, 0] = 1.0
    moving = speed > 0
    e[moving] = vel[moving] / speed[moving, None]
    s = e.sum(axis=0)
    norm = float(np.linalg.norm(s))
    spread = 2 * np.pi
    if norm > 0:
        spread = float(2 * np.arccos(np.clip((e @ (s / norm)).min(), -1.0, 1.0)))
    return {
        "mean_velocity_x": float(mean[0]),
        "mean_velocity_y": float(mean[1]),
        "mean_velocity_z": float(mean[2]),
        "velocity_disagreement": float(dev2.sum()),
        "velocity_disagreement_max": float(np.sqrt(dev2.max())),
        "speed_min": float(speed.min()),
        "speed_mean": float(speed.mean()),
        "speed_max": float(speed.max()),
        "heading_spread": spread,
    }


def component_disagreement(vel: np.ndarray, labels: np.ndarray) -> dict[str, float]:
    """Velocity disagreement within each connected component (paper 002: each component
    synchronises on its own): the sum over components and the largest |v_i - mean_k|.
    labels[i] in [0, N) names agent i's component."""
    # labels are slots of the component roots, in [0, N): bincount needs no relabelling.
    cnt = np.maximum(np.bincount(labels, minlength=len(labels)), 1).astype(np.float64)
    mean = np.stack([np.bincount(labels, vel[:, c], len(labels)) / cnt
                     for c in range(vel.shape[1])], axis=1)
    dev2 = ((vel - mean[labels]) ** 2).sum(axis=1)
    return {
        "velocity_disagreement_components": float(dev2.sum()),
        "velocity_disagreement_components_max": float(np.sqrt(dev2.max())),
    }


def valency_stats(deg: np.ndarray, per_agent_max: int) -> dict[str, float]:
    """Summary of the valencies |N_i| (deg in agent-id order); each agent's own valency
    (Fig. 6 of paper 000) at N <= per_agent_max, else a fixed-bin histogram."""
    out = {
        "valency_mean": float(deg.mean()),
        "valency_min": float(deg.min()),
        "valency_max": float(deg.max()),
    }
    if len(deg) <= per_agent_max:
        out.update({f"valency_{i}": float(k) for i, k in enumerate(deg)})
    else:
        hist = np.bincount(np.minimum(deg, HIST_BINS), minlength=HIST_BINS + 1)
        out.update({f"valency_hist_{k}": float(hist[k]) for k in range(HIST_BINS)})
        out[f"valency_hist_{HIST_BINS}plus"] = float(hist[HIST_BINS])
    return out


def graph_matrix(n: int, u: np.ndarray, v: np.ndarray) -> sp.csr_matrix:
    """Symmetric 0-1 adjacency of the undirected edges (u, v)."""
    w = np.ones(len(u))
    a = sp.coo_matrix((w, (u, v)), shape=(n, n)).tocsr()
    a = a + a.T
    a.data[:] = 1.0
    return a


def components(adj: sp.csr_matrix) -> int:
    return int(connected_components(adj, directed=False)[0])


def algebraic_connectivity(adj: sp.csr_matrix, n_components: int, max_agents: int) -> float:
    """lambda_2 of the Laplacian: 0 for a disconnected graph; dense eigvalsh for small N,
    sparse shift-invert (sigma < 0, so L - sigma I is definite) up to max_agents; -1 above
    the limit or when the solver does not converge."""
    n = adj.shape[0]
    if n > max_agents:
        return NOT_COMPUTED
    if n < 2 or n_components > 1:
        return 0.0
    lap = laplacian(adj)
    if n <= DENSE_EIG_MAX:
        return float(max(np.linalg.eigvalsh(lap.toarray())[1], 0.0))
    try:
        # A fixed start vector: ARPACK's own random one advances with every call, so the
        # same graph gave different last bits depending on what ran before it.
        v0 = np.random.default_rng(0).uniform(-1.0, 1.0, n)
        vals = eigsh(lap.tocsc(), k=2, sigma=-1e-3, which="LM", return_eigenvectors=False,
                     maxiter=10 * n, v0=v0)
    except ArpackNoConvergence:
        return NOT_COMPUTED
    return float(max(np.sort(vals)[1], 0.0))


def proximity_edges(pos: np.ndarray, radii: np.ndarray | float, rule: str,
                    inclusive: bool) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges of the proximity graph: i ~ j when j in N_i or i in N_j, with
    N_i = {j : |r_ij| < R_ij} (or <=), R_ij = R, R_i (own) or min(R_i, R_j)."""
    r = np.broadcast_to(np.asarray(radii, dtype=np.float64), (len(pos),))
    pairs = cKDTree(pos).query_pairs(float(r.max()) * (1 + 1e-9), output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    d = pos[j] - pos[i]
    s2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
    if pos.shape[1] == 3:
        s2 = s2 + d[:, 2] * d[:, 2]
    if rule == "own":
        r2 = np.maximum(r[i], r[j]) ** 2  # j in N_i (R_i) or i in N_j (R_j)
    else:
        r2 = np.minimum(r[i], r[j]) ** 2
    keep = s2 <= r2 if inclusive else s2 < r2
    return i[keep], j[keep]


def closest_pair(pos: np.ndarray) -> tuple[float, int, int]:
    """The closest pair of agents by k-d tree: (distance, i, j) with i < j."""
    dist, idx = cKDTree(pos).query(pos, k=2)
    i = int(np.argmin(dist[:, 1]))
    j = int(idx[i, 1])
    return float(dist[i, 1]), min(i, j), max(i, j)
