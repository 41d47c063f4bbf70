"""The Olfati-Saber law (IEEE TAC 51(3), 2006, Algorithms 1-3), written once for every
schedule (the per-step kernels of step.py, the fused one of fused.py) as functions of
values; how an agent's partners are gathered (the grid's 3x3 cells, all pairs) is the
schedule's.

For agent i at q_i with velocity p_i, d_ij = q_j - q_i, w = sqrt(1 + eps |d_ij|^2):
  z = |d_ij|_s = (w - 1) / eps                               (eq. 8)
  rho = rho_h(z / r_a)                                        (eq. 10; a_ij, eq. 11)
  alpha_i = sum_{|d_ij| < r} c1a rho phi(z - d_a) d_ij / w + c2a rho (p_j - p_i)
                                                              (eqs. 15, 23: n_ij = d_ij / w)
  beta_i = sum_k [|q^_ik - q_i| < r'] c1b phi_beta(z_k) n^_ik + c2b b_ik (p^_ik - p_i)
                                                              (eq. 59, Lemma 4)
  gamma_i = -c1g (q_i - q_r) - c2g (p_i - p_r)                (Algorithm 2, eq. 24)
          = -c1g s1(q_i - q_r) - c2g (p_i - p_r)              (Algorithm 3, eq. 59)
  u_i = alpha_i + beta_i + gamma_i; q_r(t) = q_r(0) + t p_r.
  semi-implicit Euler: p_i' = p_i + dt u_i, q_i' = q_i + dt p_i'.
The agent itself is among its candidates: its d = 0 and p_j - p_i = 0 make its term 0.
The pair term is odd in (d_ij, p_j - p_i): agent j's term is agent i's negated
(`mutual_term`), so Algorithm 1 conserves sum_i p_i.

Obstacles: rows of OBST_WIDTH floats (kind 0 sphere / 1 wall, y_k, R_k, a_k), y and a
padded to 3 coordinates, a normalised on the host.
"""

import math

import numpy as np
import taichi as ti

from ...space.grid import within
from ...space.params import Slots

# The divisions of the pair term by constants are multiplications by their reciprocals,
# computed once here: 1/eps, 1/r_a, pi/(1 - h) (a third of the pair's divisions).
P = Slots("EPS", "INV_EPS", "R2", "INV_RA", "DA", "HA", "KA", "PHI_S", "PHI_O", "PHI_C",
          "C1A", "C2A", "C1B", "C2B", "C1G", "C2G", "INV_DB", "DB", "RB2", "HB", "KB", "D",
          "DT", QR=3, PR=3)
OBST_WIDTH = 8  # kind, y (3), R, a (3)
DIVERGED_CAUSE = "dt too large for the lattice's stiffness and the gains"


def sigma_norm(z: float, eps: float) -> float:
    """|z|_s of a length z (host side)."""
    return (math.sqrt(1.0 + eps * z * z) - 1.0) / eps


def parameters(p, dt: float) -> np.ndarray:
    """The runtime parameter vector of model block `p`."""
    eps = p.epsilon
    qr = np.zeros(3)
    pr = np.zeros(3)
    if p.leader is not None:
        qr[:len(p.leader.position)] = p.leader.position
        pr[:len(p.leader.velocity)] = p.leader.velocity
    db = sigma_norm(p.d_obstacle, eps)
    prm = P.pack(EPS=eps, INV_EPS=1.0 / eps, R2=p.r * p.r, INV_RA=1.0 / sigma_norm(p.r, eps),
                 DA=sigma_norm(p.d, eps), HA=p.h_alpha, KA=math.pi / (1.0 - p.h_alpha),
                 PHI_S=(p.a + p.b) / 2, PHI_O=(p.a - p.b) / 2,
                 PHI_C=abs(p.a - p.b) / math.sqrt(4 * p.a * p.b), C1A=p.c1_alpha,
                 C2A=p.c2_alpha, C1B=p.c1_beta, C2B=p.c2_beta, C1G=p.c1_gamma,
                 C2G=p.c2_gamma, INV_DB=1.0 / db, DB=db,
                 RB2=(p.kappa_obstacle * p.d_obstacle) ** 2, HB=p.h_beta,
                 KB=math.pi / (1.0 - p.h_beta), D=p.d, DT=dt)
    prm[P.QR:P.QR + 3] = qr
    prm[P.PR:P.PR + 3] = pr
    return prm


def obstacle_rows(p) -> np.ndarray:
    """The obstacles as (K, OBST_WIDTH) rows (one zero row, unused, when there are none:
    the kernels' arrays are never empty)."""
    rows = np.zeros((max(1, len(p.obstacles)), OBST_WIDTH))
    for k, o in enumerate(p.obstacles):
        if o.kind == "sphere":
            rows[k, 0] = 0.0
            rows[k, 1:1 + len(o.centre)] = o.centre
            rows[k, 4] = o.radius
        else:
            a = np.asarray(o.normal, float)
            rows[k, 0] = 1.0
            rows[k, 1:1 + len(o.point)] = o.point
            rows[k, 5:5 + len(a)] = a / np.linalg.norm(a)
    return rows


@ti.func
def load(prm: ti.template()):
    """The parameter vector q from a (P.size,) array."""
    return ti.Vector([prm[c] for c in ti.static(range(P.size))], dt=float)


@ti.func
def bump(z, h, k):
    """rho_h(z) (eq. 10): 1 on [0, h), (1 + cos(k (z - h))) / 2 on [h, 1], 0 beyond, with
    k = pi / (1 - h); z >= 0 here."""
    res = 0.0
    if z < h:
        res = 1.0
    elif z <= 1.0:
        res = 0.5 * (1.0 + ti.cos(k * (z - h)))
    return res


@ti.func
def s1(z):
    """sigma_1(z) = z / sqrt(1 + z^2) of a scalar."""
    return z / ti.sqrt(1.0 + z * z)


@ti.func
def s1v(z):
    """sigma_1 of a vector: z / sqrt(1 + |z|^2)."""
    return z / ti.sqrt(1.0 + z.dot(z))


@ti.func
def phi(z, q):
    """phi(z) = ((a + b) s1(z + c) + (a - b)) / 2 (eq. 16)."""
    return q[P.PHI_S] * s1(z + q[P.PHI_C]) + q[P.PHI_O]


@ti.func
def mutual_term(d, vj, vi, q):
    """Agent i's term from agent j, d = q_j - q_i (zero from |d| = r on); agent j's from
    i is its negation."""
    r2 = d.dot(d)
    t = ti.Vector.zero(float, d.n)
    if within(r2, q[P.R2], False):
        w = ti.sqrt(1.0 + q[P.EPS] * r2)
        z = (w - 1.0) * q[P.INV_EPS]
        rho = bump(z * q[P.INV_RA], q[P.HA], q[P.KA])
        t = (q[P.C1A] * rho * phi(z - q[P.DA], q) / w) * d + (q[P.C2A] * rho) * (vj - vi)
    return t


@ti.func
def pair_term(acc, d, vj, vi, q):
    """acc plus agent j's alpha term on agent i."""
    return acc + mutual_term(d, vj, vi, q)


@ti.func
def vec(ob: ti.template(), k, c0, dim: ti.template()):
    """Columns c0 .. c0 + dim - 1 of obstacle row k as a dim-vector."""
    return ti.Vector([ob[k, c0 + c] for c in ti.static(range(dim))], dt=float)


@ti.func
def projection(xi, vi, ob: ti.template(), k):
    """The beta-agent (q^, p^) of agent i on obstacle k (Lemma 4) and the distance from
    q_i to the obstacle's surface (negative inside a sphere or behind a wall)."""
    dim = ti.static(xi.n)
    y = vec(ob, k, 1, dim)
    qh = xi
    ph = vi
    dist = 0.0
    if ob[k, 0] == 0.0:  # sphere: mu = R / |q - y|, a = (q - y) / |q - y|
        e = xi - y
        n = e.norm()
        mu = ob[k, 4] / n
        a = e / n
        qh = mu * xi + (1.0 - mu) * y
        ph = mu * (vi - a.dot(vi) * a)
        dist = n - ob[k, 4]
    else:  # wall: P = I - a a^T
        a = vec(ob, k, 5, dim)
        dist = a.dot(xi - y)
        qh = xi - dist * a
        ph = vi - a.dot(vi) * a
    return qh, ph, dist


@ti.func
def beta_term(xi, vi, q, ob: ti.template(), k0, k1):
    """sum over obstacles k0 .. k1 - 1 within r' of the beta-agents' terms (eq. 59)."""
    acc = ti.Vector.zero(float, xi.n)
    for k in range(k0, k1):
        qh, ph, _ = projection(xi, vi, ob, k)
        dq = qh - xi
        z2 = dq.dot(dq)
        if within(z2, q[P.RB2], False):
            w = ti.sqrt(1.0 + q[P.EPS] * z2)
            z = (w - 1.0) * q[P.INV_EPS]
            rho = bump(z * q[P.INV_DB], q[P.HB], q[P.KB])
            acc += (q[P.C1B] * rho * (s1(z - q[P.DB]) - 1.0) / w) * dq \
                + (q[P.C2B] * rho) * (ph - vi)
    return acc


@ti.func
def leader(q, t, dim: ti.template()):
    """(q_r(t), p_r): the gamma-agent at time t."""
    pr = ti.Vector([q[P.PR + c] for c in ti.static(range(dim))], dt=float)
    qr = ti.Vector([q[P.QR + c] for c in ti.static(range(dim))], dt=float) + t * pr
    return qr, pr


@ti.func
def acceleration(alpha, xi, vi, t, q, ob: ti.template(), k0, k1, alg: ti.template()):
    """u_i from agent i's alpha sum: plus the gamma term (Algorithm 2: linear; 3:
    sigma_1 of the position error) and the beta-agents' terms (Algorithm 3)."""
    u = alpha
    if ti.static(alg >= 2):
        qr, pr = leader(q, t, xi.n)
        e = xi - qr
        if ti.static(alg == 3):
            e = s1v(e)
        u += -q[P.C1G] * e - q[P.C2G] * (vi - pr)
    if ti.static(alg == 3):
        u += beta_term(xi, vi, q, ob, k0, k1)
    return u


@ti.func
def euler(xi, vi, u, dt):
    """Semi-implicit Euler: (q', p') = (q + dt p', p + dt u)."""
    v = vi + dt * u
    return xi + dt * v, v


@ti.func
def edge(d, q):
    """(|d| - d)^2 and 1 for a neighbour j != i (|d| < r), else zeros: one edge's share
    of the deviation energy and of |E| (the caller leaves out the agent itself)."""
    r2 = d.dot(d)
    res = ti.math.vec2(0.0, 0.0)
    if within(r2, q[P.R2], False):
        e = ti.sqrt(r2) - q[P.D]
        res = ti.math.vec2(e * e, 1.0)
    return res


@ti.func
def obstacle_distance(xi, vi, ob: ti.template(), k0, k1):
    """min_k of the distance from q_i to obstacle k's surface (+inf without obstacles)."""
    best = ti.math.inf
    for k in range(k0, k1):
        _, _, dist = projection(xi, vi, ob, k)
        best = ti.min(best, dist)
    return best
