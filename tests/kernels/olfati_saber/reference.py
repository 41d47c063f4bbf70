"""An independent numpy reference of Olfati-Saber 2006 (Algorithms 1-3): O(N^2) pair
matrices, the functions written from the paper's equations, sharing no code with the
engine; the potential V (the integral of phi_alpha) by quadrature for the Hamiltonian."""

from __future__ import annotations

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components


def snorm(z2: np.ndarray, eps: float) -> np.ndarray:
    """|z|_sigma from |z|^2 (eq. 8)."""
    return (np.sqrt(1 + eps * z2) - 1) / eps


def rho(z: np.ndarray, h: float) -> np.ndarray:
    """The bump rho_h (eq. 10)."""
    z = np.asarray(z, float)
    mid = 0.5 * (1 + np.cos(np.pi * (z - h) / (1 - h)))
    return np.where(z < h, 1.0, np.where(z <= 1, mid, 0.0))


def sig1(z):
    return z / np.sqrt(1 + z * z)


def phi_alpha(z, m):
    """phi_alpha(z) = rho_h(z / r_a) phi(z - d_a) (eqs. 15-16)."""
    eps, a, b = m.epsilon, m.a, m.b
    ra, da = snorm(m.r**2, eps), snorm(m.d**2, eps)
    c = abs(a - b) / np.sqrt(4 * a * b)
    phi = ((a + b) * sig1(z - da + c) + (a - b)) / 2
    return rho(z / ra, m.h_alpha) * phi


def beta_agents(q: np.ndarray, p: np.ndarray, o) -> tuple[np.ndarray, np.ndarray]:
    """(q^, p^) of every agent on obstacle o (Lemma 4: sphere or wall)."""
    if o.kind == "sphere":
        y = np.asarray(o.centre)
        e = q - y
        n = np.linalg.norm(e, axis=1, keepdims=True)
        mu, a = o.radius / n, e / n
        ph = mu * (p - (a * p).sum(axis=1, keepdims=True) * a)
        return mu * q + (1 - mu) * y, ph
    a = np.asarray(o.normal, float)
    a = a / np.linalg.norm(a)
    Pm = np.eye(len(a)) - np.outer(a, a)
    y = np.asarray(o.point)
    return q @ Pm.T + (np.outer(a, a) @ y)[None, :], p @ Pm.T


def accel(q: np.ndarray, p: np.ndarray, t: float, m) -> np.ndarray:
    """u_i of Algorithm m.algorithm at time t."""
    eps = m.epsilon
    dq = q[None, :, :] - q[:, None, :]  # [i, j] = q_j - q_i
    r2 = (dq**2).sum(axis=-1)
    z = snorm(r2, eps)
    near = (r2 < m.r**2) & ~np.eye(len(q), dtype=bool)
    n_ij = dq / np.sqrt(1 + eps * r2)[..., None]
    aij = np.where(near, rho(z / snorm(m.r**2, eps), m.h_alpha), 0.0)
    grad = np.where(near, phi_alpha(z, m), 0.0)
    u = m.c1_alpha * (grad[..., None] * n_ij).sum(axis=1)
    u += m.c2_alpha * (aij[..., None] * (p[None, :, :] - p[:, None, :])).sum(axis=1)
    if m.algorithm >= 2:
        qr = np.asarray(m.leader.position) + t * np.asarray(m.leader.velocity)
        e = q - qr
        if m.algorithm == 3:
            e = e / np.sqrt(1 + (e**2).sum(axis=1, keepdims=True))
        u += -m.c1_gamma * e - m.c2_gamma * (p - np.asarray(m.leader.velocity))
    if m.algorithm == 3:
        db = snorm(m.d_obstacle**2, eps)
        for o in m.obstacles:
            qh, ph = beta_agents(q, p, o)
            d = qh - q
            z2 = (d**2).sum(axis=1)
            zb = snorm(z2, eps)
            inside = z2 < (m.kappa_obstacle * m.d_obstacle) ** 2
            bump = np.where(inside, rho(zb / db, m.h_beta), 0.0)
            nb = d / np.sqrt(1 + eps * z2)[:, None]
            u += m.c1_beta * (bump * (sig1(zb - db) - 1))[:, None] * nb
            u += m.c2_beta * bump[:, None] * (ph - p)
    return u


def step(q, p, t, dt, m):
    """Semi-implicit Euler."""
    p1 = p + dt * accel(q, p, t, m)
    return q + dt * p1, p1


def measures(q: np.ndarray, p: np.ndarray, t: float, m) -> dict[str, float]:
    """The quality measures of section VIII, from the pair matrix."""
    n = len(q)
    dist = np.sqrt(((q[None] - q[:, None]) ** 2).sum(axis=-1))
    iu = np.triu_indices(n, 1)
    edge = dist[iu] < m.r
    E = int(edge.sum())
    dev = float(((dist[iu][edge] - m.d) ** 2).sum() / (m.d**2 * (E + 1)))
    adj = csr_matrix((np.ones(E), (iu[0][edge], iu[1][edge])), shape=(n, n))
    comps = connected_components(adj, directed=False)[0]
    L = np.diag(np.asarray((adj + adj.T).sum(axis=1)).ravel()) - (adj + adj.T).toarray()
    out = {"deviation_energy": dev,
           "relative_connectivity": np.linalg.matrix_rank(L) / (n - 1),
           "components": comps,
           "velocity_mismatch": 0.5 * float(((p - p.mean(axis=0)) ** 2).sum()),
           "cohesion_radius": float(np.linalg.norm(q - q.mean(axis=0), axis=1).max())}
    if m.obstacles:
        gaps = []
        for o in m.obstacles:
            if o.kind == "sphere":
                gaps.append(np.linalg.norm(q - np.asarray(o.centre), axis=1) - o.radius)
            else:
                a = np.asarray(o.normal, float) / np.linalg.norm(o.normal)
                gaps.append((q - np.asarray(o.point)) @ a)
        out["min_obstacle_distance"] = float(np.min(gaps))
    if m.algorithm >= 2:
        qr = np.asarray(m.leader.position) + t * np.asarray(m.leader.velocity)
        out["leader_distance"] = float(np.linalg.norm(q.mean(axis=0) - qr))
    return out


def hamiltonian(q: np.ndarray, p: np.ndarray, m) -> float:
    """H = V(q) + sum_i |p_i|^2 / 2, V = sum over pairs of psi_alpha(|q_ij|_s), psi_alpha
    the integral of phi_alpha from d_a (eq. 15), tabulated by the trapezoid rule on 2 10^5
    points of [0, r_a] (constant from r_a on: phi_alpha = 0 there)."""
    eps = m.epsilon
    ra, da = snorm(m.r**2, eps), snorm(m.d**2, eps)
    zs = np.linspace(0.0, ra, 200_001)
    table = cumulative_trapezoid(phi_alpha(zs, m), zs, initial=0.0)
    table -= np.interp(da, zs, table)
    iu = np.triu_indices(len(q), 1)
    r2 = ((q[None] - q[:, None]) ** 2).sum(axis=-1)[iu]
    V = float(np.interp(np.minimum(snorm(r2, eps), ra), zs, table).sum())
    return V + 0.5 * float((p**2).sum())
