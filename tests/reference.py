"""Independent brute-force numpy references: O(N^2) neighbour sets and model steps.

They share nothing with the engine but the counter-based noise (kernels.space.rng.uniform_np),
which must be replayed to compare noisy runs step by step.
"""

from __future__ import annotations

import numpy as np


def displacements(pos: np.ndarray, L: float | None) -> np.ndarray:
    """d[i, j] = r_j - r_i, minimum image in a periodic box of side L."""
    d = pos[None, :, :] - pos[:, None, :]
    if L is not None:
        d -= L * np.round(d / L)
    return d


def adjacency(pos: np.ndarray, r: float, L: float | None, inclusive: bool) -> np.ndarray:
    """Boolean A[i, j]: j is a neighbour of i (i != j)."""
    d = displacements(pos, L)
    d2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]
    if pos.shape[1] == 3:
        d2 = d2 + d[..., 2] * d[..., 2]
    a = d2 <= r * r if inclusive else d2 < r * r
    np.fill_diagonal(a, False)
    return a


def vicsek_step(pos, theta, *, rule, r, L, inclusive, v0dt, eta=0.0, g=None, theta0=0.0,
                noise=None, move_new=False, graph=None):
    """One synchronous M1 step for every rule (the equations: kernels/models/vicsek/step.py).
    graph: the adjacency A[i, j] to use (e.g. `knn_adjacency`); default the metric one."""
    a = adjacency(pos, r, L, inclusive) if graph is None else graph
    closed = a | np.eye(len(pos), dtype=bool)
    cnt = closed.sum(axis=1)
    if rule == "vicsek":
        new = np.arctan2(closed @ np.sin(theta), closed @ np.cos(theta))
    elif rule == "laplacian":
        lap = np.diag(a.sum(axis=1)) - a  # L = D - A  (eq. 17)
        new = theta - lap @ theta / g  # eq. 18
    else:  # average and leader: (I + D)^-1 (A + I) theta  (eq. 1-2, 22)
        new = (closed @ theta) / cnt
    if eta > 0:
        new = new + eta * (noise - 0.5)
    if rule == "leader":
        new[0] = theta0
    phi = new if move_new else theta
    x = pos + v0dt * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    if L is not None:
        x = np.mod(x, L)
    return x, new


def cap_turn(m: np.ndarray, u1: np.ndarray, u2: np.ndarray, eta: float) -> np.ndarray:
    """Rows of m (unit 3-vectors) turned to directions uniform in the spherical cap of
    half-angle eta/2: 1 - cos t = u1 (1 - cos(eta/2)), azimuth 2 pi u2 measured from
    b1 = the unit part of e_x (e_y where |m_x| > 1/2) normal to m, towards b2 = m x b1."""
    h = u1 * (1.0 - np.cos(eta / 2))
    ct, st = 1.0 - h, np.sqrt(np.maximum(0.0, h * (2.0 - h)))
    axis = np.zeros_like(m)
    axis[np.abs(m[:, 0]) > 0.5, 1] = 1.0
    axis[np.abs(m[:, 0]) <= 0.5, 0] = 1.0
    b1 = axis - (axis * m).sum(axis=1, keepdims=True) * m
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    b2 = np.cross(m, b1)
    phi = 2 * np.pi * u2
    return ct[:, None] * m + st[:, None] * (np.cos(phi)[:, None] * b1
                                            + np.sin(phi)[:, None] * b2)


def vicsek_step_3d(pos, e, *, r, L, inclusive, v0dt, eta=0.0, u1=None, u2=None,
                   move_new=False, graph=None):
    """One synchronous 3D Vicsek step: e_i' = the closed neighbourhood's mean direction,
    turned into the spherical cap of half-angle eta/2 (uniforms u1, u2 per agent)."""
    a = adjacency(pos, r, L, inclusive) if graph is None else graph
    closed = a | np.eye(len(pos), dtype=bool)
    s = closed.astype(np.float64) @ e
    norm = np.linalg.norm(s, axis=1)
    m = np.zeros_like(s)
    m[:, 0] = 1.0  # a zero sum keeps the x axis (as atan2(0, 0) = 0 in 2D)
    m[norm > 0] = s[norm > 0] / norm[norm > 0, None]
    new = cap_turn(m, u1, u2, eta) if eta > 0 else m
    x = pos + v0dt * (new if move_new else e)
    if L is not None:
        x = np.mod(x, L)
    return x, new


def degrees(pos: np.ndarray, r: float, L: float | None, inclusive: bool) -> np.ndarray:
    """|N_i| of every agent in the metric graph (minimum image in a periodic box, which
    for r > L/2 counts each other agent once, at its nearest image)."""
    return adjacency(pos, r, L, inclusive).sum(axis=1)


def degrees_per_agent_radius(pos: np.ndarray, radii: np.ndarray, rule: str,
                             inclusive: bool) -> np.ndarray:
    """|N_i| on the plane with per-agent radii (paper 002): N_i = {j != i : |r_ij| <= R_ij}
    (or <), R_ij = R_i (rule "own") or min(R_i, R_j) (rule "min")."""
    d = displacements(pos, None)
    d2 = (d * d).sum(axis=-1)
    r = radii[:, None] if rule == "own" else np.minimum(radii[:, None], radii[None, :])
    r2 = np.broadcast_to(r * r, d2.shape)
    a = d2 <= r2 if inclusive else d2 < r2
    np.fill_diagonal(a, False)
    return a.sum(axis=1)


def formation_rates(x, targets, *, f, g, d):
    """Xi-Abed's right-hand side in any dimension (paper 003 eq. 1-5): rdot_i =
    f(|l_i - r_i|) (l_i - r_i)/|l_i - r_i| + sum_{0 < |r_ji| < d} g(|r_ji|) r_ji/|r_ji|,
    with l_i the rows of `targets`; f and g as the schema dicts ({"kind": ..., gains})."""
    z = targets - x
    s = np.linalg.norm(z, axis=1)[:, None]
    safe = np.where(s > 0, s, 1.0)
    if f["kind"] == "linear":
        v = f["k"] * z
    elif f["kind"] == "quadratic":
        v = f["c"] * (s * s + s) * z / safe
    else:
        v = f["v_max"] * np.tanh(f["k"] * s / f["v_max"]) * z / safe
    diff = displacements(x, None)  # [i, j] = r_j - r_i
    dist = np.linalg.norm(diff, axis=2)
    near = (dist < d) & ~np.eye(len(x), dtype=bool)
    r = np.where(near, dist, 1.0)
    if g["kind"] == "inverse":
        mag = -g["k_g"] * (1.0 / r - 1.0 / d)
    else:
        mag = -g["k_g"] * (1.0 / r**2 - 1.0 / d**2)
    w = np.where(near, mag / r, 0.0)
    return v + (w[..., None] * diff).sum(axis=1)


def formation_step(x, t, dt, targets_at, *, f, g, d, integrator="euler"):
    """One explicit Euler or classical RK4 step of `formation_rates`, with the attraction
    points `targets_at(t)` ((N, dim)) re-evaluated at each stage's time."""
    def rates(y, s):
        return formation_rates(y, targets_at(s), f=f, g=g, d=d)

    if integrator == "euler":
        return x + dt * rates(x, t)
    k1 = rates(x, t)
    k2 = rates(x + 0.5 * dt * k1, t + 0.5 * dt)
    k3 = rates(x + 0.5 * dt * k2, t + 0.5 * dt)
    k4 = rates(x + dt * k3, t + dt)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def vicsek_step_vectorial(pos, e, *, r, L, inclusive, v0dt, eta, u1, u2, move_new=False,
                          graph=None):
    """One synchronous Vicsek step with vectorial noise (Grégoire & Chaté 2004), 2D or 3D:
    e_i' = w / |w|, w = sum over the closed neighbourhood of e_j + eta n_i u_i, u_i the
    random unit vector of the uniforms (u1, u2): 2D at angle 2 pi u1, 3D z = 2 u1 - 1 and
    azimuth 2 pi u2. A zero w keeps the x axis. `graph`: a given adjacency (topological
    neighbours) in place of the metric one."""
    a = adjacency(pos, r, L, inclusive) if graph is None else graph
    closed = a | np.eye(len(pos), dtype=bool)
    n = closed.sum(axis=1).astype(np.float64)
    if pos.shape[1] == 2:
        u = np.stack([np.cos(2 * np.pi * u1), np.sin(2 * np.pi * u1)], axis=1)
    else:
        z = 2 * u1 - 1
        rho = np.sqrt(np.maximum(0.0, 1 - z * z))
        u = np.stack([rho * np.cos(2 * np.pi * u2), rho * np.sin(2 * np.pi * u2), z], axis=1)
    w = closed.astype(np.float64) @ e + eta * n[:, None] * u
    norm = np.linalg.norm(w, axis=1)
    new = np.zeros_like(w)
    new[:, 0] = 1.0
    new[norm > 0] = w[norm > 0] / norm[norm > 0, None]
    x = pos + v0dt * (new if move_new else e)
    if L is not None:
        x = np.mod(x, L)
    return x, new


def knn_lists(pos: np.ndarray, k: int, L: float | None, radius: float | None = None,
              inclusive: bool = True) -> list[list[int]]:
    """Each agent's k nearest other agents, nearest first, by sorting all N - 1 distances
    (minimum image in a periodic box): equal distances in agent-id order; with a radius,
    only those within it (|r_ij| <= r, or < r)."""
    n = len(pos)
    d = displacements(pos, L)
    d2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]
    if pos.shape[1] == 3:
        d2 = d2 + d[..., 2] * d[..., 2]
    out = []
    for i in range(n):
        order = np.lexsort((np.arange(n), d2[i]))
        order = order[order != i]
        if radius is not None:
            near = d2[i, order] <= radius * radius if inclusive else (
                d2[i, order] < radius * radius)
            order = order[near]
        out.append([int(j) for j in order[:k]])
    return out


def knn_adjacency(pos: np.ndarray, k: int, L: float | None, radius: float | None = None,
                  inclusive: bool = True, symmetric: bool = False) -> np.ndarray:
    """Boolean A[i, j]: j is among i's k nearest (`knn_lists`); symmetric: or i among j's."""
    n = len(pos)
    a = np.zeros((n, n), dtype=bool)
    for i, js in enumerate(knn_lists(pos, k, L, radius, inclusive)):
        a[i, js] = True
    return a | a.T if symmetric else a
