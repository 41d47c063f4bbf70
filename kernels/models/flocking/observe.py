"""numpy-side observables of the flocking models, evaluated only at observation steps.

All values are finite floats (summary.json refuses NaN): quantities that are not computed
report -1 (lambda2 above its agent limit).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import taichi as ti
from scipy.sparse.csgraph import connected_components, laplacian
from scipy.sparse.linalg import ArpackNoConvergence, eigsh
from scipy.spatial import cKDTree

from flocklab.schemas.flocking import HIST_BINS

from ...space.observables import circular_spread
from ...space.stream import PairwiseSum, Rows, RowSum, blocks

DENSE_EIG_MAX = 32  # dense eigvalsh up to this N; sparse shift-invert (faster) above
NOT_COMPUTED = -1.0


def _unit(v: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """Each velocity over its speed; a zero velocity counts as the x axis."""
    e = np.zeros_like(v)
    e[:, 0] = 1.0
    moving = speed > 0
    e[moving] = v[moving] / speed[moving, None]
    return e


def _speed(v: np.ndarray) -> np.ndarray:
    return np.hypot(v[:, 0], v[:, 1]) if v.shape[1] == 2 else np.linalg.norm(v, axis=1)


def velocity_stats(vel: ti.Ndarray) -> tuple[dict[str, float], float]:
    """Mean velocity, disagreement sum_i |v_i - mean|^2 and max_i |v_i - mean|, speeds, the
    heading spread, and (second) the kinetic energy 1/2 sum_i |v_i|^2, from the device
    array (N, dim) read in blocks (kernels/space/stream.py: numpy's bits on the whole
    array). In 2D the spread is the circular spread of the headings; in 3D twice the
    largest angle between a velocity's direction and the mean direction (2 pi when the
    mean is zero; zero velocities count as the x axis)."""
    n, dim = vel.shape
    rows = Rows(vel)
    total, kinetic, speeds = RowSum(), PairwiseSum(n * dim), PairwiseSum(n)
    speed_min, speed_max = np.inf, -np.inf
    dirs = RowSum()
    theta = np.empty(n) if dim == 2 else None
    for lo, hi in blocks(n):
        v = rows.wide(lo, hi)
        total.add(v)
        kinetic.add(v * v)
        speed = _speed(v)
        speeds.add(speed)
        speed_min = np.minimum(speed_min, speed.min())
        speed_max = np.maximum(speed_max, speed.max())
        if theta is not None:
            theta[lo:hi] = np.arctan2(v[:, 1], v[:, 0])
        else:
            dirs.add(_unit(v, speed))
    mean = total.total() / n
    axis = None
    if theta is None:
        s = dirs.total()
        norm = float(np.linalg.norm(s))
        axis = s / norm if norm > 0 else None
    dev2_sum, dev2_max, cos_min = PairwiseSum(n), -np.inf, np.inf
    for lo, hi in blocks(n):
        v = rows.wide(lo, hi)
        dev2 = ((v - mean) ** 2).sum(axis=1)
        dev2_sum.add(dev2)
        dev2_max = np.maximum(dev2_max, dev2.max())
        if axis is not None:
            cos_min = np.minimum(cos_min, (_unit(v, _speed(v)) @ axis).min())
    if theta is not None:
        spread = circular_spread(theta, overwrite=True)
    else:
        spread = 2 * np.pi if axis is None else float(2 * np.arccos(np.clip(cos_min, -1.0, 1.0)))
    stats = {f"mean_velocity_{c}": float(mean[k]) for k, c in enumerate("xyz"[:dim])}
    stats.update({
        "velocity_disagreement": dev2_sum.total(),
        "velocity_disagreement_max": float(np.sqrt(dev2_max)),
        "speed_min": float(speed_min),
        "speed_mean": speeds.total() / n,
        "speed_max": float(speed_max),
        "heading_spread": spread,
    })
    return stats, 0.5 * kinetic.total()


def component_disagreement(vel: ti.Ndarray, labels: np.ndarray) -> dict[str, float]:
    """Velocity disagreement within each connected component (paper 002: each component
    synchronises on its own): the sum over components and the largest |v_i - mean_k|.
    labels[i] in [0, N) names the component of the agent in slot i; the velocities are
    read from the device in blocks. Each component's sum adds its members' velocities in
    slot order from zero (np.add.at: np.bincount's order), so the bits are those of
    np.bincount on whole arrays."""
    n, dim = vel.shape
    rows = Rows(vel)
    cnt = np.zeros(n)
    np.add.at(cnt, labels, 1.0)
    np.maximum(cnt, 1.0, out=cnt)
    means = [np.zeros(n) for _ in range(dim)]
    for lo, hi in blocks(n):
        v = rows.wide(lo, hi)
        for c in range(dim):
            np.add.at(means[c], labels[lo:hi], v[:, c])
    for m in means:
        m /= cnt
    del cnt
    dev2_sum, dev2_max = PairwiseSum(n), -np.inf
    for lo, hi in blocks(n):
        v = rows.wide(lo, hi)
        lab = labels[lo:hi]
        dev2 = ((v - np.stack([m[lab] for m in means], axis=1)) ** 2).sum(axis=1)
        dev2_sum.add(dev2)
        dev2_max = np.maximum(dev2_max, dev2.max())
    return {
        "velocity_disagreement_components": dev2_sum.total(),
        "velocity_disagreement_components_max": float(np.sqrt(dev2_max)),
    }


class Valencies:
    """Summary of the valencies |N_i| fed in blocks (slot order: every statistic but the
    per-agent one is order-free, and the integer sums are exact in any order); each
    agent's own valency (Fig. 6 of paper 000) at N <= per_agent_max, given in agent-id
    order to `stats`, else a fixed-bin histogram."""

    def __init__(self, n: int, per_agent_max: int):
        self.n, self.per_agent = n, n <= per_agent_max
        self.total, self.low, self.high = 0, None, None
        self.hist = np.zeros(HIST_BINS + 1, dtype=np.int64)

    def add(self, deg: np.ndarray) -> None:
        if len(deg):
            self.total += int(deg.sum(dtype=np.int64))
            lo, hi = int(deg.min()), int(deg.max())
            self.low = lo if self.low is None else min(self.low, lo)
            self.high = hi if self.high is None else max(self.high, hi)
            self.hist += np.bincount(np.minimum(deg, HIST_BINS), minlength=HIST_BINS + 1)

    def stats(self, by_id: np.ndarray | None = None) -> dict[str, float]:
        out = {
            "valency_mean": self.total / self.n,
            "valency_min": float(self.low),
            "valency_max": float(self.high),
        }
        if self.per_agent:
            out.update({f"valency_{i}": float(k) for i, k in enumerate(by_id)})
        else:
            out.update({f"valency_hist_{k}": float(self.hist[k]) for k in range(HIST_BINS)})
            out[f"valency_hist_{HIST_BINS}plus"] = float(self.hist[HIST_BINS])
        return out


def valency_stats(deg: np.ndarray, per_agent_max: int) -> dict[str, float]:
    """`Valencies` of a whole array in agent-id order."""
    v = Valencies(len(deg), per_agent_max)
    v.add(deg)
    return v.stats(deg)


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
