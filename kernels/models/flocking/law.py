"""M2 and M3's law: the Tanner–Jadbabaie–Pappas control of a double-integrator flock
(paper 000 eq. 1, 3, 10; paper 002 eq. 3-4 and its navigation function, p. 3).

Written once, for every schedule (the per-step kernels of forces.py and navigation.py,
the fused one of fused.py), as functions of values: how an agent's neighbours, obstacles
and parameters are gathered is the schedule's. For agent i at r_i with velocity v_i:
  u_i = sum_{j in N_i} (v_j - v_i) + sum_{j : s_ij < R_ij} (V'(s_ij) / s_ij) (r_j - r_i)
        [- grad V_i(r_i) - c_d v_i where the damping region holds]   (paper 002 only)
  fixed graph: N_i its neighbours in the graph, V never saturated (eq. 4-5);
  metric: j in N_i iff s_ij < R_ij (or <=), V saturated at s >= R_ij (eq. 10);
  v_i' = v_i + dt u_i,  r_i' = r_i + dt v_i'   (semi-implicit Euler).
V(s) = a / s^2 + ln s^2 + c (potentials.py). R_ij (RADIUS_RULES) is R (uniform), R_i
(own: paper 002 eq. 4 as printed) or min(R_i, R_j). Paper 002's adaptive radius (eq. 4):
R_i' = max(R_i / 2, floor) while agent i is stuck (|v_i| < stuck speed, V_i > V_min),
else the largest R_j of N_i ∪ {i}. Its navigation function, over obstacles o (points,
discs, spheres) within reach d of their boundary:
  beta_o = 1 - lambda e^2 / (e^2 + 1), e = delta_o - d, where delta_o^2 < d^2 (else 1),
  B = prod_o beta_o, a = |r - r_d|^2, D = a^kappa + B, V = a / D^(1/kappa).
"""

import taichi as ti

from ...space.grid import within
from . import potentials

UNIFORM, OWN, MIN = 0, 1, 2
RADIUS_RULES = {"uniform": UNIFORM, "own": OWN, "min": MIN}
NO_DAMPING, ABOVE_VMIN, BELOW_VMIN, EVERYWHERE = 0, 1, 2, 3
DAMPING = {"above_vmin": ABOVE_VMIN, "below_vmin": BELOW_VMIN, "everywhere": EVERYWHERE}
# Why a flocking step blew up, as every schedule words it.
DIVERGED_CAUSE = (
    "dt too large for the pair potential's stiffness, or two agents (or an agent and an "
    "obstacle) at the same point"
)


@ti.func
def metric_term(d, s2, r2, inclusive: ti.template(), other, vj, a):
    """Agent j's term in agent i's sums over metric neighbours, d = r_j - r_i, s2 = |d|^2,
    r2 = R_ij^2, other: j != i; `inclusive` (<=) a compile-time bool or a runtime 0/1.
    Branch-free: the term is (w v_j + f d, w), w = [j in N_i] and f = V'(s) / s below R_ij
    (0 from R_ij on, where V is saturated; the select drops f(0) = inf for i itself, and a
    coincident pair keeps it). The sums are (sum_{N_i} v_j + sum_{s < R} f d, |N_i|);
    `control` completes the alignment sum_{N_i} (v_j - v_i) as sum v_j - |N_i| v_i."""
    dim = ti.static(d.n)
    w = ti.cast(within(s2, r2, inclusive) & other, float)
    f = ti.select((s2 < r2) & other, potentials.force_factor(s2, a), 0.0)
    return ti.Vector([w * vj[c] + f * d[c] for c in ti.static(range(dim))] + [w])


@ti.func
def graph_term(u, d, vj, vi, a):
    """u plus neighbour j's term on a fixed graph: (v_j - v_i) + (V'(s) / s) d, d = r_j -
    r_i (eq. 3, V never saturated)."""
    u += vj - vi
    u += potentials.force_factor(d.dot(d), a) * d
    return u


@ti.func
def control(sums, vi):
    """u_i of eq. 3 from agent i's metric sums (sum v_j + sum f d, |N_i|)."""
    dim = ti.static(vi.n)
    u = ti.Vector.zero(float, dim)
    for c in ti.static(range(dim)):
        u[c] = sums[c]
    u -= sums[dim] * vi
    return u


@ti.func
def damped(damping: ti.template(), V, vmin):
    """Whether paper 002's damping region holds at V = V_i (`damping`, compile-time or a
    runtime value: above_vmin V > V_min, as printed; below_vmin V <= V_min; everywhere)."""
    return (damping == EVERYWHERE) | ((damping == ABOVE_VMIN) & (V > vmin)) | (
        (damping == BELOW_VMIN) & (V <= vmin))


@ti.func
def mission_control(u, vi, grad, V, damping: ti.template(), vmin, cd):
    """u_i with paper 002's mission terms (eq. 3): - grad V_i, and - c_d v_i where the
    damping region holds."""
    u -= grad
    if damped(damping, V, vmin):
        u -= cd * vi
    return u


@ti.func
def euler(xi, vi, u, dt):
    """Semi-implicit Euler (eq. 1): (r', v') = (r + dt v', v + dt u)."""
    v = vi + dt * u
    return xi + dt * v, v


@ti.func
def stuck(vi, V, stuck2, vmin):
    """Paper 002 eq. 4: agent i is stuck (slower than the stuck speed, outside V_min)."""
    return (vi.dot(vi) < stuck2) & (V > vmin)


@ti.func
def halved(r, floor):
    """A stuck agent's new radius (eq. 4): R_i / 2, never below the floor."""
    return ti.max(0.5 * r, floor)


@ti.func
def fold_obstacle(acc, d, rho, rng, lam):
    """Fold the obstacle at d = r_o - x (boundary radius rho; 0: a point) into
    acc = (B, grad B, min delta) by the product rule, (B, grad B) <- (B beta_o, beta_o
    grad B + B grad beta_o), grad_x beta_o = dbeta/ddelta (x - r_o) / |x - r_o| (an
    obstacle with beta_o = 0 needs no division)."""
    D = ti.static(d.n)
    dist = ti.sqrt(d.dot(d))
    delta = dist - rho
    acc[D + 1] = ti.min(acc[D + 1], delta)
    if delta * delta < rng * rng:  # m = 1; otherwise m = 0 and beta = 1
        e = delta - rng
        q = e * e + 1.0
        beta = 1.0 - lam * e * e / q
        dbeta = -2.0 * lam * e / (q * q)  # d beta / d delta
        g = (-dbeta / dist) * d  # grad_x beta = dbeta (x - r_o) / |x - r_o|
        b = acc[0]
        for c in ti.static(range(D)):
            acc[1 + c] = acc[1 + c] * beta + b * g[c]
        acc[0] = b * beta
    return acc


@ti.func
def navigation_value(y, b, gb, kappa, unit_kappa: ti.template()):
    """(V, grad V) of the navigation function at y = r - r_d from the folded obstacles
    (B, grad B):
      grad V = D^(-1/kappa) 2 y - (a / kappa) D^(-1/kappa - 1) grad D,
      grad D = 2 kappa a^(kappa - 1) y + grad B;
    `unit_kappa` (compile-time): kappa = 1, grad V = (2 y B - a grad B) / D^2."""
    a = y.dot(y)
    v = 0.0
    g = ti.Vector.zero(float, y.n)
    if ti.static(unit_kappa):
        dd = a + b
        v = a / dd
        g = (2.0 * b * y - a * gb) / (dd * dd)
    else:
        dd = ti.pow(a, kappa) + b
        dk = ti.pow(dd, -1.0 / kappa)
        v = a * dk
        gd = 2.0 * kappa * ti.pow(a, kappa - 1.0) * y + gb
        g = dk * 2.0 * y - (a / kappa) * (dk / dd) * gd
    return v, g
