"""f (attraction) and g (repulsion) of the Xi–Abed designs behind one interface.

Taichi side, selected at compile time by kind (F_*, G_* below), runtime gains in `prm`:
  attract(z)   = f(|z|) z/|z|                      (eq. 3 / eq. 5 with z = r_leader - r_i)
                 linear     f(s) = k s             -> k z
                 quadratic  f(s) = c (s^2 + s)     -> c (|z| + 1) z
                 saturating f(s) = v tanh(k s / v) -> f(|z|)/|z| z (0 at z = 0)
  g_over_s(s)  = g(s)/s for 0 < s < d              (eq. 4: v_R += g(s)/s (r_j - r_i))
                 inverse        g(s) = -k_g (1/s - 1/d)
                 inverse_square g(s) = -k_g (1/s^2 - 1/d^2)
  pair_energy(s) = G(s) = int_d^s g                (the pair term of V1, eq. 10, and V2, eq. 16)
  leader(i)    = the point agent i is attracted to: p(t) (F2) or p(t) + b_i(t) (F1)
Every vector is a dim-vector (2 or 3, compile time); the 3D parameter array `P3` holds p(t)
and the formation weights as 3-vectors and 3x3 matrices.
numpy side: F(s) = int_0^s f (the leader term of V1/V2) and the steady lag |a| = f^-1(|q|)
solving eq. 8.
"""

import numpy as np
import taichi as ti

from flocklab.schemas.formation import FormationParams, LinearF, QuadraticF, SaturatingF

from ...space.params import Slots

F_KINDS = {"linear": 0, "quadratic": 1, "saturating": 2}
G_KINDS = {"inverse": 0, "inverse_square": 1}
# One time slot's leader data: p(t) and the 2x2 weights (row-major) of the two stored
# formations A and B (F1 only).
LEAD = Slots("PX", "PY", "A00", "A01", "A10", "A11", "B00", "B01", "B10", "B11")
# The parameter array of every formation kernel: the gains, then LEAD for each of the three
# time slots s (0: t, 1: t + dt/2, 2: t + dt).
P = Slots("FA", "FB", "KG", "D", "D2", "DT", LEAD=3 * LEAD.size)
# 3D: p(t) with three components and the 3x3 weights (row-major) of A and B, one block each
# (named for its first slot, as in LEAD).
LEAD3 = Slots("PX", "PY", "PZ", A00=9, B00=9)
P3 = Slots("FA", "FB", "KG", "D", "D2", "DT", LEAD=3 * LEAD3.size)  # the gains as in P


def lead_slots(dim: int) -> tuple[Slots, Slots]:
    """(P, LEAD) of a dimension."""
    return (P, LEAD) if dim == 2 else (P3, LEAD3)


def force_params(p: FormationParams, d: float, dt: float, dim: int = 2) -> np.ndarray:
    """The parameter array with the gains set (the time slots zero)."""
    f = p.attraction
    fa = f.c if isinstance(f, QuadraticF) else f.k
    fb = f.v_max if isinstance(f, SaturatingF) else 0.0
    return lead_slots(dim)[0].pack(FA=fa, FB=fb, KG=p.repulsion.k_g, D=d, D2=d * d, DT=dt)


@ti.func
def leader_3d(i, ids: ti.template(), ba: ti.template(), bb: ti.template(),
              prm: ti.template(), slot, f1: ti.template(), blend: ti.template()):
    """leader() in 3D: l_i = p(t) (F2) or p(t) + M_A A[id] + M_B B[id] (F1), M 3x3."""
    o = P3.LEAD + LEAD3.size * slot
    r = ti.math.vec3(prm[o + LEAD3.PX], prm[o + LEAD3.PY], prm[o + LEAD3.PZ])
    if ti.static(f1):
        a = ids[i]
        for row in ti.static(range(3)):
            m = o + LEAD3.A00 + 3 * row
            r[row] += prm[m] * ba[a, 0] + prm[m + 1] * ba[a, 1] + prm[m + 2] * ba[a, 2]
            if ti.static(blend):
                m = o + LEAD3.B00 + 3 * row
                r[row] += prm[m] * bb[a, 0] + prm[m + 1] * bb[a, 1] + prm[m + 2] * bb[a, 2]
    return r


@ti.func
def leader(i, ids: ti.template(), ba: ti.template(), bb: ti.template(), prm: ti.template(),
           slot, f1: ti.template(), blend: ti.template()):
    """l_i = p(t) (F2) or p(t) + M_A A[id] + M_B B[id] (F1), in 2D."""
    o = P.LEAD + LEAD.size * slot
    r = ti.math.vec2(prm[o + LEAD.PX], prm[o + LEAD.PY])
    if ti.static(f1):
        a = ids[i]
        r += ti.math.vec2(prm[o + LEAD.A00] * ba[a, 0] + prm[o + LEAD.A01] * ba[a, 1],
                          prm[o + LEAD.A10] * ba[a, 0] + prm[o + LEAD.A11] * ba[a, 1])
        if ti.static(blend):
            r += ti.math.vec2(prm[o + LEAD.B00] * bb[a, 0] + prm[o + LEAD.B01] * bb[a, 1],
                              prm[o + LEAD.B10] * bb[a, 0] + prm[o + LEAD.B11] * bb[a, 1])
    return r


@ti.func
def attract(z, prm: ti.template(), fkind: ti.template()):
    """f(|z|) z / |z| (z a 2- or 3-vector)."""
    v = ti.Vector.zero(float, z.n)
    if ti.static(fkind == F_KINDS["linear"]):
        v = prm[P.FA] * z
    elif ti.static(fkind == F_KINDS["quadratic"]):
        v = prm[P.FA] * (ti.sqrt(z.dot(z)) + 1.0) * z
    else:
        s = ti.sqrt(z.dot(z))
        if s > 0.0:
            v = (prm[P.FB] * ti.tanh(prm[P.FA] * s / prm[P.FB]) / s) * z
    return v


@ti.func
def g_over_s(s, prm: ti.template(), gkind: ti.template()):
    """g(s) / s for 0 < s < d."""
    r = 0.0
    if ti.static(gkind == G_KINDS["inverse"]):
        r = -prm[P.KG] * (1.0 / s - 1.0 / prm[P.D]) / s
    else:
        r = -prm[P.KG] * (1.0 / (s * s) - 1.0 / prm[P.D2]) / s
    return r


@ti.func
def pair_energy(s, prm: ti.template(), gkind: ti.template()):
    """G(s) = int_d^s g(sigma) dsigma >= 0 for 0 < s < d."""
    d = prm[P.D]
    e = 0.0
    if ti.static(gkind == G_KINDS["inverse"]):
        e = prm[P.KG] * (ti.log(d / s) + s / d - 1.0)
    else:
        e = prm[P.KG] * (1.0 / s + s / prm[P.D2] - 2.0 / d)
    return e


def attraction_energy(p: FormationParams, s: np.ndarray) -> np.ndarray:
    """F(s) = int_0^s f(sigma) dsigma (V1's k s^2 / 2 for linear f)."""
    f = p.attraction
    if isinstance(f, LinearF):
        return 0.5 * f.k * s * s
    if isinstance(f, QuadraticF):
        return f.c * (s**3 / 3.0 + s * s / 2.0)
    x = f.k * s / f.v_max  # v^2/k ln cosh x, written to stay finite for large x
    return (f.v_max**2 / f.k) * (x + np.log1p(np.exp(-2.0 * x)) - np.log(2.0))


def lag_length(p: FormationParams, speed: float) -> float:
    """|a| with f(|a|) = |q| (eq. 8)."""
    f = p.attraction
    if isinstance(f, LinearF):
        return speed / f.k
    if isinstance(f, QuadraticF):
        return (np.sqrt(1.0 + 4.0 * speed / f.c) - 1.0) / 2.0
    return float(f.v_max / f.k * np.arctanh(speed / f.v_max))
