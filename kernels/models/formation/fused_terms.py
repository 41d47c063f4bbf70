"""The fused M4 path's per-replica parameter slots and its Taichi terms, all pairs:
f, g, F, G and the lag with runtime gains (forces has them compile-time), the
leader and F1's schedule at a time index, l_i, rdot_i, and the per-step grid's runaway
check."""

import taichi as ti

from ...space.grid import max_cells_across
from ...space.params import Slots
from .forces import F_KINDS, G_KINDS

# Per-replica parameter slots: prm (f64) and iprm (i32).
P = Slots("R2", "D", "D2", "KG", "FA", "FB", "DT", "TSTEP", "SX", "SY", "QX", "QY", "T_ARR", "EX",
         "EY", "COLLIDE", "TOL", "LAG_SIGN", "CELL", "EXTENT")
IP = Slots("STEPS", "EVERY", "BAD", "CAUSE", "NOBS", "FKIND", "GKIND", "F1", "SPLINE", "C0", "NC",
          "I0", "F0")


@ti.func
def g_over_s(s, kind, kg, d, d2):
    """g(s) / s for 0 < s < d (forces.g_over_s with runtime gains)."""
    r = 0.0
    if kind == G_KINDS["inverse"]:
        r = -kg * (1.0 / s - 1.0 / d) / s
    else:
        r = -kg * (1.0 / (s * s) - 1.0 / d2) / s
    return r


@ti.func
def pair_energy(s, kind, kg, d, d2):
    """G(s) = int_d^s g >= 0 for 0 < s < d (forces.pair_energy)."""
    e = 0.0
    if kind == G_KINDS["inverse"]:
        e = kg * (ti.log(d / s) + s / d - 1.0)
    else:
        e = kg * (1.0 / s + s / d2 - 2.0 / d)
    return e


@ti.func
def attract(z, kind, fa, fb):
    """f(|z|) z / |z| (forces.attract with runtime gains)."""
    v = ti.math.vec2(0.0)
    if kind == F_KINDS["linear"]:
        v = fa * z
    elif kind == F_KINDS["quadratic"]:
        v = fa * (ti.sqrt(z.dot(z)) + 1.0) * z
    else:
        s = ti.sqrt(z.dot(z))
        if s > 0.0:
            v = (fb * ti.tanh(fa * s / fb) / s) * z
    return v


@ti.func
def attraction_energy(s, kind, fa, fb):
    """F(s) = int_0^s f (forces.attraction_energy)."""
    e = 0.0
    if kind == F_KINDS["linear"]:
        e = 0.5 * fa * s * s
    elif kind == F_KINDS["quadratic"]:
        e = fa * (s * s * s / 3.0 + s * s / 2.0)
    else:
        x = fa * s / fb  # v^2/k ln cosh x, written to stay finite for large x
        e = (fb * fb / fa) * (x + ti.log(1.0 + ti.exp(-2.0 * x)) - ti.log(2.0))
    return e


@ti.func
def lag_length(qn, kind, fa, fb):
    """|a| with f(|a|) = |q| (eq. 8; forces.lag_length)."""
    a = 0.0
    if kind == F_KINDS["linear"]:
        a = qn / fa
    elif kind == F_KINDS["quadratic"]:
        a = (ti.sqrt(1.0 + 4.0 * qn / fa) - 1.0) / 2.0
    else:
        x = qn / fb
        a = fb / fa * 0.5 * ti.log((1.0 + x) / (1.0 - x))  # atanh
    return a


@ti.func
def leader_state(b, h, h0, prm: ti.template(), iprm: ti.template(), chg: ti.template(),
                  inforce: ti.template(), lead: ti.template()):
    """The leader at half-step index h (t = h * TSTEP): (p, q, M_A, M_B, k_A, k_B) with
    b_i = M_A A_i + M_B B_i over the stored formations k_A, k_B (k_B = -1: none), as
    OffsetSchedule.weights and StraightLine / the host's spline table give them."""
    t = h * prm[b, P.TSTEP]
    p = ti.math.vec2(0.0)
    q = ti.math.vec2(0.0)
    if iprm[b, IP.SPLINE] != 0:
        r = h - h0
        p = ti.math.vec2(lead[b, r, 0], lead[b, r, 1])
        q = ti.math.vec2(lead[b, r, 2], lead[b, r, 3])
    elif t >= prm[b, P.T_ARR]:
        p = ti.math.vec2(prm[b, P.EX], prm[b, P.EY])
    else:
        q = ti.math.vec2(prm[b, P.QX], prm[b, P.QY])
        p = ti.math.vec2(prm[b, P.SX], prm[b, P.SY]) + q * t
    ma = ti.math.vec4(0.0)
    mb = ti.math.vec4(0.0)
    ka = 0
    kb = -1
    if iprm[b, IP.F1] != 0:
        c0 = iprm[b, IP.C0]
        i0 = iprm[b, IP.I0]
        done = 0
        found = 0
        for j in range(iprm[b, IP.NC]):
            st = chg[c0 + j, 0]
            en = chg[c0 + j, 1]
            if t < st:
                break
            if t >= en:
                done = j + 1
                continue
            u = (t - st) / (en - st)
            s = u * u * (3.0 - 2.0 * u)
            if chg[c0 + j, 3] != 0.0:
                s = u
            ka = ti.cast(inforce[i0 + j, 0], ti.i32)
            m = ti.math.vec4(inforce[i0 + j, 1], inforce[i0 + j, 2], inforce[i0 + j, 3],
                             inforce[i0 + j, 4])
            phi = chg[c0 + j, 2]
            if not ti.math.isnan(phi):  # rotate by s phi: R(s phi) M
                c = ti.cos(s * phi)
                sn = ti.sin(s * phi)
                ma = ti.math.vec4(c * m[0] - sn * m[2], c * m[1] - sn * m[3],
                                  sn * m[0] + c * m[2], sn * m[1] + c * m[3])
            else:  # morph: (1 - s) M B_c + s K'
                ma = (1.0 - s) * m
                kb = ti.cast(inforce[i0 + j + 1, 0], ti.i32)
                mb = ti.math.vec4(s, 0.0, 0.0, s)
            found = 1
            break
        if found == 0:
            ka = ti.cast(inforce[i0 + done, 0], ti.i32)
            ma = ti.math.vec4(inforce[i0 + done, 1], inforce[i0 + done, 2],
                              inforce[i0 + done, 3], inforce[i0 + done, 4])
    return p, q, ma, mb, ka, kb


@ti.func
def target(b, i, a0, n, p, ma, mb, ka, kb, iprm: ti.template(), forms: ti.template()):
    """l_i: p (F2) or p + M_A A_i + M_B B_i (F1)."""
    r = p
    if iprm[b, IP.F1] != 0:
        f = iprm[b, IP.F0] + ka * n + i - a0
        r += ti.math.vec2(ma[0] * forms[f, 0] + ma[1] * forms[f, 1],
                          ma[2] * forms[f, 0] + ma[3] * forms[f, 1])
        if kb >= 0:
            g = iprm[b, IP.F0] + kb * n + i - a0
            r += ti.math.vec2(mb[0] * forms[g, 0] + mb[1] * forms[g, 1],
                              mb[2] * forms[g, 0] + mb[3] * forms[g, 1])
    return r


@ti.func
def rate(b, i, a0, n, src: ti.template(), lp, ma, mb, ka, kb, prm: ti.template(),
          iprm: ti.template(), forms: ti.template()):
    """(rdot_x, rdot_y, coincident neighbours) of agent i at the positions `src`."""
    xi = ti.math.vec2(src[i, 0], src[i, 1])
    r2 = prm[b, P.R2]
    gk = iprm[b, IP.GKIND]
    kg = prm[b, P.KG]
    d = prm[b, P.D]
    d2 = prm[b, P.D2]
    acc = ti.math.vec3(0.0)
    for j in range(a0, a0 + n):
        dv = ti.math.vec2(src[j, 0] - xi[0], src[j, 1] - xi[1])
        e2 = dv.dot(dv)
        # r2 is the strict threshold: d^2 for "<", the next double above it for "<="
        if j != i and e2 < r2:
            if e2 > 0.0:
                w = g_over_s(ti.sqrt(e2), gk, kg, d, d2)
                acc += ti.math.vec3(w * dv[0], w * dv[1], 0.0)
            else:
                acc[2] += 1.0
    v = attract(target(b, i, a0, n, lp, ma, mb, ka, kb, iprm, forms) - xi, iprm[b, IP.FKIND],
                 prm[b, P.FA], prm[b, P.FB])
    return ti.math.vec3(v[0] + acc[0], v[1] + acc[1], acc[2])


@ti.func
def is_nonfinite(x, y):
    s = x + y  # NaN if either is NaN or infinite
    return ti.math.isnan(s) or ti.math.isinf(s)


@ti.func
def runaway(b, a0, n, src: ti.template(), prm: ti.template(), iprm: ti.template()):
    """The per-step grid's check of the positions it is about to bucket: 1 (and the
    replica stopped with cause 2 or 3) if one is non-finite or the swarm spans over 2^30
    cells of side d."""
    lo = ti.math.vec2(ti.math.inf)
    hi = ti.math.vec2(-ti.math.inf)
    bad = 0
    for i in range(a0, a0 + n):
        x = ti.math.vec2(src[i, 0], src[i, 1])
        bad |= ti.cast(is_nonfinite(x[0], x[1]), ti.i32)
        lo = ti.min(lo, x)
        hi = ti.max(hi, x)
    extent = ti.max(hi[0] - lo[0], hi[1] - lo[1])
    cause = -1
    if bad != 0:
        cause = 2
    elif extent / prm[b, P.CELL] > ti.static(max_cells_across()):
        cause = 3
        prm[b, P.EXTENT] = extent
    if cause >= 0:
        iprm[b, IP.CAUSE] = cause
    return ti.cast(cause >= 0, ti.i32)
