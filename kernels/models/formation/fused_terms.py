"""The fused M4 path's per-replica parameter slots and its Taichi terms, all pairs:
f, g, F, G and the lag with runtime gains (forces has them compile-time), the
leader and F1's schedule at a time index, l_i, rdot_i, and the per-step grid's runaway
check. Positions, p(t), q(t) and b_i(t) are dim-vectors and the schedule's weights dim x dim
matrices, dim (2 or 3) a compile-time parameter: 2D compiles to the arithmetic it had
before 3D, term for term."""

import taichi as ti

from ...space.grid import max_cells_across
from ...space.grid import row as row_of
from ...space.params import Slots
from .forces import F_KINDS, G_KINDS

# Per-replica parameter slots: prm (f64) and iprm (i32).
# A straight path's start S, velocity Q and end E take 3 slots each (2D uses the first two).
P = Slots("R2", "D", "D2", "KG", "FA", "FB", "DT", "TSTEP", "T_ARR", "COLLIDE", "TOL",
          "LAG_SIGN", "CELL", "EXTENT", S=3, Q=3, E=3)
# SNAP: whether the replica's observations are snapshot for the host's D3 (F2 in 3D), SNAP0
# its observation count when the current launch began (the snapshot buffer's row 0).
IP = Slots("STEPS", "EVERY", "BAD", "CAUSE", "NOBS", "FKIND", "GKIND", "F1", "SPLINE", "C0", "NC",
          "I0", "F0", "SNAP", "SNAP0")


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
    v = ti.Vector.zero(float, z.n)
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
def slot_vector(prm: ti.template(), b, first, dim: ti.template()):
    """The dim-vector in prm[b, first:first + dim]."""
    v = ti.Vector.zero(float, dim)
    for c in ti.static(range(dim)):
        v[c] = prm[b, first + c]
    return v


@ti.func
def stored_weights(inforce: ti.template(), k, dim: ti.template()):
    """The dim x dim matrix M of in-force row k (row-major after its formation index)."""
    m = ti.Matrix.zero(float, dim, dim)
    for r in ti.static(range(dim)):
        for c in ti.static(range(dim)):
            m[r, c] = inforce[k, 1 + dim * r + c]
    return m


@ti.func
def rotated(angle, m, chg: ti.template(), j, dim: ti.template()):
    """R(angle) M: in the plane, or about change j's unit axis u (chg[j, 4:7]) in 3D by
    Rodrigues' formula R = I + sin K + (1 - cos) K^2, K = [u]_x (shapes.rotation3)."""
    c = ti.cos(angle)
    sn = ti.sin(angle)
    out = ti.Matrix.zero(float, dim, dim)
    if ti.static(dim == 2):  # written out: the bits of 2D runs predate 3D
        out = ti.Matrix([[c * m[0, 0] - sn * m[1, 0], c * m[0, 1] - sn * m[1, 1]],
                         [sn * m[0, 0] + c * m[1, 0], sn * m[0, 1] + c * m[1, 1]]])
    else:
        u = ti.math.vec3(chg[j, 4], chg[j, 5], chg[j, 6])
        k = ti.Matrix([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
        r = ti.Matrix.identity(float, 3) + sn * k + (1.0 - c) * (k @ k)
        out = r @ m
    return out


@ti.func
def leader_state(b, h, h0, prm: ti.template(), iprm: ti.template(), chg: ti.template(),
                  inforce: ti.template(), lead: ti.template(), dim: ti.template()):
    """The leader at half-step index h (t = h * TSTEP): (p, q, M_A, M_B, k_A, k_B) with
    b_i = M_A A_i + M_B B_i over the stored formations k_A, k_B (k_B = -1: none; M dim x
    dim), as OffsetSchedule.weights and StraightLine / the host's spline table (p in its
    first dim columns, q in the next dim) give them."""
    t = h * prm[b, P.TSTEP]
    p = ti.Vector.zero(float, dim)
    q = ti.Vector.zero(float, dim)
    if iprm[b, IP.SPLINE] != 0:
        r = h - h0
        for c in ti.static(range(dim)):
            p[c] = lead[b, r, c]
            q[c] = lead[b, r, dim + c]
    elif t >= prm[b, P.T_ARR]:
        p = slot_vector(prm, b, P.E, dim)
    else:
        q = slot_vector(prm, b, P.Q, dim)
        p = slot_vector(prm, b, P.S, dim) + q * t
    ma = ti.Matrix.zero(float, dim, dim)
    mb = ti.Matrix.zero(float, dim, dim)
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
            m = stored_weights(inforce, i0 + j, dim)
            phi = chg[c0 + j, 2]
            if not ti.math.isnan(phi):  # rotate by s phi: R(s phi) M
                ma = rotated(s * phi, m, chg, c0 + j, dim)
            else:  # morph: (1 - s) M B_c + s K'
                ma = (1.0 - s) * m
                kb = ti.cast(inforce[i0 + j + 1, 0], ti.i32)
                mb = s * ti.Matrix.identity(float, dim)
            found = 1
            break
        if found == 0:
            ka = ti.cast(inforce[i0 + done, 0], ti.i32)
            ma = stored_weights(inforce, i0 + done, dim)
    return p, q, ma, mb, ka, kb


@ti.func
def weighted(m, forms: ti.template(), f, dim: ti.template()):
    """M K[f], each row's terms summed left to right."""
    v = ti.Vector.zero(float, dim)
    for r in ti.static(range(dim)):
        x = m[r, 0] * forms[f, 0]
        for c in ti.static(range(1, dim)):
            x += m[r, c] * forms[f, c]
        v[r] = x
    return v


@ti.func
def target(b, i, a0, n, p, ma, mb, ka, kb, iprm: ti.template(), forms: ti.template(),
           dim: ti.template()):
    """l_i: p (F2) or p + M_A A_i + M_B B_i (F1)."""
    r = p
    if iprm[b, IP.F1] != 0:
        r += weighted(ma, forms, iprm[b, IP.F0] + ka * n + i - a0, dim)
        if kb >= 0:
            r += weighted(mb, forms, iprm[b, IP.F0] + kb * n + i - a0, dim)
    return r


@ti.func
def rate(b, i, a0, n, src: ti.template(), lp, ma, mb, ka, kb, prm: ti.template(),
          iprm: ti.template(), forms: ti.template(), dim: ti.template()):
    """(rdot_i, coincident neighbours) of agent i at the positions `src`: a
    (dim + 1)-vector."""
    xi = row_of(src, i, dim)
    r2 = prm[b, P.R2]
    gk = iprm[b, IP.GKIND]
    kg = prm[b, P.KG]
    d = prm[b, P.D]
    d2 = prm[b, P.D2]
    acc = ti.Vector.zero(float, dim + 1)
    for j in range(a0, a0 + n):
        dv = row_of(src, j, dim) - xi
        e2 = dv.dot(dv)
        # r2 is the strict threshold: d^2 for "<", the next double above it for "<="
        if j != i and e2 < r2:
            if e2 > 0.0:
                w = g_over_s(ti.sqrt(e2), gk, kg, d, d2)
                for c in ti.static(range(dim)):
                    acc[c] += w * dv[c]
            else:
                acc[dim] += 1.0
    v = attract(target(b, i, a0, n, lp, ma, mb, ka, kb, iprm, forms, dim) - xi,
                iprm[b, IP.FKIND], prm[b, P.FA], prm[b, P.FB])
    out = ti.Vector.zero(float, dim + 1)
    for c in ti.static(range(dim)):
        out[c] = v[c] + acc[c]
    out[dim] = acc[dim]
    return out


@ti.func
def is_nonfinite(x, dim: ti.template()):
    """Whether one of x's first dim components is NaN or infinite (a rate's last, the
    coincident count, is not a coordinate)."""
    s = x[0]  # NaN if any is NaN or infinite
    for c in ti.static(range(1, dim)):
        s += x[c]
    return ti.math.isnan(s) or ti.math.isinf(s)


@ti.func
def runaway(b, a0, n, src: ti.template(), prm: ti.template(), iprm: ti.template(),
            dim: ti.template()):
    """The per-step grid's check of the positions it is about to bucket: 1 (and the
    replica stopped with cause 2 or 3) if one is non-finite or the swarm spans over
    max_cells_across(dim) cells of side d."""
    lo = ti.Vector([ti.math.inf] * dim)
    hi = ti.Vector([-ti.math.inf] * dim)
    bad = 0
    for i in range(a0, a0 + n):
        x = row_of(src, i, dim)
        bad |= ti.cast(is_nonfinite(x, dim), ti.i32)
        lo = ti.min(lo, x)
        hi = ti.max(hi, x)
    extent = hi[0] - lo[0]
    for c in ti.static(range(1, dim)):
        extent = ti.max(extent, hi[c] - lo[c])
    cause = -1
    if bad != 0:
        cause = 2
    elif extent / prm[b, P.CELL] > ti.static(max_cells_across(dim)):
        cause = 3
        prm[b, P.EXTENT] = extent
    if cause >= 0:
        iprm[b, IP.CAUSE] = cause
    return ti.cast(cause >= 0, ti.i32)
