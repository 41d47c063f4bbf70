"""M4 on the small-N path: many steps of many replicas in one kernel launch.

The equations are the ones `kernels/formation.py` documents (paper 003, eq. 1-6, 12):
  rdot_i = f(|l_i - r_i|) (l_i - r_i)/|l_i - r_i| + sum_{|r_ij| < d} g(|r_ji|) r_ji/|r_ji|,
  l_i = p(t) + b_i(t) (F1) or p(t) (F2), explicit Euler or classical RK4;
only the schedule differs. One launch advances every replica of a batch through a window
of steps: replicas in parallel (one per CPU task), each replica's steps and agents
serially inside, all pairs visited (N is small here), the state kept in the kernel's
arrays and the observables written into a per-replica buffer. The host comes back only at
frame, progress and cancellation points, which never changes a bit: a replica computes
the same numbers alone, in a batch, or cut into any windows.

The leader is evaluated inside the kernel at every step (and RK4 half step): a straight
path as p0 + q t until the arrival time, F1's schedule (rotations, morphs, smoothstep or
linear) from the stored formations and their 2x2 weights. A spline path's arc-length
timing is the host's (`formation_path.SplineTable`, the per-step path's arc-length
inversion vectorised over t): p(t), and q(t) at observation steps, are tabulated for each
window (about 0.1 ms per step on the host, the fused path's largest cost for a spline).

Not on this path (`FormationBatch.batch_key` returns None, the per-step path runs them):
a run whose Euler step could enter the dense regime (9 N > `max_exact_candidates`: the
per-step path coarse-grains there), N above `MAX_N` (all pairs would cost more than the
per-step path's grid), and N = 1 (no pair for the minimum distance).
"""

from functools import cache
from typing import Any

import numpy as np
import taichi as ti

from schemas import Scenario
from schemas.formation import FormationParams, QuadraticF, SaturatingF, SplinePath

from .formation_forces import F_KINDS, G_KINDS
from .formation_path import SplineTable, make_path
from .formation_schedule import OffsetSchedule
from .grid import _WIDEN as GRID_WIDEN
from .initial import initial_state

nd = ti.types.ndarray()
MAX_N = 512  # all pairs up to here: at N = 1000 a fused F2 step cost as much CPU as a
# per-step one (4.3 vs 4.2 ms, the per-step path on 2 threads), at N = 500 1.3 vs 2.2 ms
SPREAD = 512  # the CPU backend cuts a parallel loop into tasks of 512 iterations
TWO_PI = 2 * np.pi
_NO_PAIR = 1e300

# Per-replica parameter slots: prm (f64) and iprm (i32).
(R2, D, D2, KG, FA, FB, DT, TSTEP, SX, SY, QX, QY, T_ARR, EX, EY, COLLIDE, TOL,
 LAG_SIGN, CELL, EXTENT) = range(20)
N_PRM = 20
(STEPS, EVERY, BAD, CAUSE, NOBS, FKIND, GKIND, F1, SPLINE, C0, NC, I0, F0) = range(13)
N_IPRM = 13
# Why a replica stopped (iprm[CAUSE]), as the per-step path words it: its step check
# (0, 1), or its grid's check of the positions it buckets (2, 3; kernels/grid.py), which
# runs first at every step and RK4 stage. Cause 3 is formatted with prm[EXTENT].
CAUSES = (
    "two agents at the same position, where g is singular (dt too large lets agents jump "
    "onto each other)",
    "non-finite position (dt too large for the repulsion's stiffness at close range)",
    "a position became non-finite",
    "the swarm spans {:.3g} length units, over 2^30 neighbour radii (agents escaping: dt "
    "too large or forces unbounded)",
)
MAX_CELLS_ACROSS = 2.0**30  # as kernels/grid.py
# Observable columns of the buffer (the step first); F1 and F2 fill their own.
OBS = ("step", "leader_x", "leader_y", "leader_speed", "centroid_x", "centroid_y",
       "centroid_distance", "speed_min", "speed_mean", "speed_max", "speed_error_max",
       "velocity_mismatch_max", "min_distance", "degree_mean", "formation_error",
       "formation_error_max", "lag", "V1", "V2", "D1", "D2", "D3", "isolated", "components")
N_OBS = len(OBS)
COMMON = OBS[1:14]
F1_OBS = ("formation_error", "formation_error_max", "lag", "V1")
F2_OBS = ("V2", "D1", "D2", "D3", "isolated", "components")


@ti.func
def _find(parent: ti.template(), x):
    while parent[x] != x:
        parent[x] = parent[parent[x]]  # path halving
        x = parent[x]
    return x


@ti.func
def _g_over_s(s, kind, kg, d, d2):
    """g(s) / s for 0 < s < d (formation_forces.g_over_s with runtime gains)."""
    r = 0.0
    if kind == G_KINDS["inverse"]:
        r = -kg * (1.0 / s - 1.0 / d) / s
    else:
        r = -kg * (1.0 / (s * s) - 1.0 / d2) / s
    return r


@ti.func
def _pair_energy(s, kind, kg, d, d2):
    """G(s) = int_d^s g >= 0 for 0 < s < d (formation_forces.pair_energy)."""
    e = 0.0
    if kind == G_KINDS["inverse"]:
        e = kg * (ti.log(d / s) + s / d - 1.0)
    else:
        e = kg * (1.0 / s + s / d2 - 2.0 / d)
    return e


@ti.func
def _attract(z, kind, fa, fb):
    """f(|z|) z / |z| (formation_forces.attract with runtime gains)."""
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
def _attraction_energy(s, kind, fa, fb):
    """F(s) = int_0^s f (formation_forces.attraction_energy)."""
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
def _lag(qn, kind, fa, fb):
    """|a| with f(|a|) = |q| (eq. 8; formation_forces.lag_length)."""
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
def _leader_state(b, h, h0, prm: ti.template(), iprm: ti.template(), chg: ti.template(),
                  inforce: ti.template(), lead: ti.template()):
    """The leader at half-step index h (t = h * TSTEP): (p, q, M_A, M_B, k_A, k_B) with
    b_i = M_A A_i + M_B B_i over the stored formations k_A, k_B (k_B = -1: none), as
    OffsetSchedule.weights and StraightLine / the host's spline table give them."""
    t = h * prm[b, TSTEP]
    p = ti.math.vec2(0.0)
    q = ti.math.vec2(0.0)
    if iprm[b, SPLINE] != 0:
        r = h - h0
        p = ti.math.vec2(lead[b, r, 0], lead[b, r, 1])
        q = ti.math.vec2(lead[b, r, 2], lead[b, r, 3])
    elif t >= prm[b, T_ARR]:
        p = ti.math.vec2(prm[b, EX], prm[b, EY])
    else:
        q = ti.math.vec2(prm[b, QX], prm[b, QY])
        p = ti.math.vec2(prm[b, SX], prm[b, SY]) + q * t
    ma = ti.math.vec4(0.0)
    mb = ti.math.vec4(0.0)
    ka = 0
    kb = -1
    if iprm[b, F1] != 0:
        c0 = iprm[b, C0]
        i0 = iprm[b, I0]
        done = 0
        found = 0
        for j in range(iprm[b, NC]):
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
def _target(b, i, a0, n, p, ma, mb, ka, kb, iprm: ti.template(), forms: ti.template()):
    """l_i: p (F2) or p + M_A A_i + M_B B_i (F1)."""
    r = p
    if iprm[b, F1] != 0:
        f = iprm[b, F0] + ka * n + i - a0
        r += ti.math.vec2(ma[0] * forms[f, 0] + ma[1] * forms[f, 1],
                          ma[2] * forms[f, 0] + ma[3] * forms[f, 1])
        if kb >= 0:
            g = iprm[b, F0] + kb * n + i - a0
            r += ti.math.vec2(mb[0] * forms[g, 0] + mb[1] * forms[g, 1],
                              mb[2] * forms[g, 0] + mb[3] * forms[g, 1])
    return r


@ti.func
def _rate(b, i, a0, n, src: ti.template(), lp, ma, mb, ka, kb, prm: ti.template(),
          iprm: ti.template(), forms: ti.template()):
    """(rdot_x, rdot_y, coincident neighbours) of agent i at the positions `src`."""
    xi = ti.math.vec2(src[i, 0], src[i, 1])
    r2 = prm[b, R2]
    gk = iprm[b, GKIND]
    kg = prm[b, KG]
    d = prm[b, D]
    d2 = prm[b, D2]
    acc = ti.math.vec3(0.0)
    for j in range(a0, a0 + n):
        dv = ti.math.vec2(src[j, 0] - xi[0], src[j, 1] - xi[1])
        e2 = dv.dot(dv)
        # r2 is the strict threshold: d^2 for "<", the next double above it for "<="
        if j != i and e2 < r2:
            if e2 > 0.0:
                w = _g_over_s(ti.sqrt(e2), gk, kg, d, d2)
                acc += ti.math.vec3(w * dv[0], w * dv[1], 0.0)
            else:
                acc[2] += 1.0
    v = _attract(_target(b, i, a0, n, lp, ma, mb, ka, kb, iprm, forms) - xi, iprm[b, FKIND],
                 prm[b, FA], prm[b, FB])
    return ti.math.vec3(v[0] + acc[0], v[1] + acc[1], acc[2])


@ti.func
def _nonfinite(x, y):
    s = x + y  # NaN if either is NaN or infinite
    return ti.math.isnan(s) or ti.math.isinf(s)


@ti.func
def _runaway(b, a0, n, src: ti.template(), prm: ti.template(), iprm: ti.template()):
    """The per-step grid's check of the positions it is about to bucket: 1 (and the
    replica stopped with cause 2 or 3) if one is non-finite or the swarm spans over 2^30
    cells of side d."""
    lo = ti.math.vec2(ti.math.inf)
    hi = ti.math.vec2(-ti.math.inf)
    bad = 0
    for i in range(a0, a0 + n):
        x = ti.math.vec2(src[i, 0], src[i, 1])
        bad |= ti.cast(_nonfinite(x[0], x[1]), ti.i32)
        lo = ti.min(lo, x)
        hi = ti.max(hi, x)
    extent = ti.max(hi[0] - lo[0], hi[1] - lo[1])
    cause = -1
    if bad != 0:
        cause = 2
    elif extent / prm[b, CELL] > MAX_CELLS_ACROSS:
        cause = 3
        prm[b, EXTENT] = extent
    if cause >= 0:
        iprm[b, CAUSE] = cause
    return ti.cast(cause >= 0, ti.i32)


@ti.func
def _observe(b, a0, n, s, h, h0, row, prm: ti.template(), iprm: ti.template(),
             chg: ti.template(), inforce: ti.template(), lead: ti.template(),
             forms: ti.template(), pos: ti.template(), deg: ti.template(),
             parent: ti.template(), ang: ti.template(), gmax: ti.template(),
             gcnt: ti.template(), obs: ti.template()):
    """The observables of X(s) (time index h) into obs[row]: the columns of OBS."""
    p, q, ma, mb, ka, kb = _leader_state(b, h, h0, prm, iprm, chg, inforce, lead)
    fk = iprm[b, FKIND]
    fa = prm[b, FA]
    fb = prm[b, FB]
    gk = iprm[b, GKIND]
    kg = prm[b, KG]
    d = prm[b, D]
    d2 = prm[b, D2]
    r2 = prm[b, R2]
    f1 = iprm[b, F1] != 0
    qn = ti.sqrt(q.dot(q))
    lag = _lag(qn, fk, fa, fb)
    a = ti.math.vec2(0.0)
    if qn > 0.0:
        a = (lag / qn) * q * prm[b, LAG_SIGN]
    tol = prm[b, TOL]
    for i in range(a0, a0 + n):
        parent[i] = i
    cx = 0.0
    cy = 0.0
    smin = ti.math.inf
    ssum = 0.0
    smax = 0.0
    serr = 0.0
    vmis = 0.0
    near = _NO_PAIR
    dsum = 0
    gsum = 0.0
    esum = 0.0
    emax = 0.0
    fsum = 0.0
    lead_k = -1  # the agent at r_0 (F2): the nearest to p, within the tolerance
    lead_d = ti.math.inf
    for i in range(a0, a0 + n):
        xi = ti.math.vec2(pos[i, 0], pos[i, 1])
        rep = ti.math.vec2(0.0)
        k = 0
        for j in range(a0, a0 + n):
            if j != i:
                dv = ti.math.vec2(pos[j, 0] - xi[0], pos[j, 1] - xi[1])
                e2 = dv.dot(dv)
                near = ti.min(near, e2)
                if e2 < r2:
                    k += 1
                    if e2 > 0.0:
                        sd = ti.sqrt(e2)
                        rep += _g_over_s(sd, gk, kg, d, d2) * dv
                        gsum += _pair_energy(sd, gk, kg, d, d2)
                    if j > i and not f1:
                        ri = _find(parent, i)
                        rj = _find(parent, j)
                        if ri != rj:
                            parent[ti.max(ri, rj)] = ti.min(ri, rj)
        deg[i] = k
        dsum += k
        li = _target(b, i, a0, n, p, ma, mb, ka, kb, iprm, forms)
        v = _attract(li - xi, fk, fa, fb) + rep
        sp = ti.sqrt(v.dot(v))
        smin = ti.min(smin, sp)
        smax = ti.max(smax, sp)
        ssum += sp
        serr = ti.max(serr, ti.abs(sp - qn))
        vm = v - q
        vmis = ti.max(vmis, ti.sqrt(vm.dot(vm)))
        cx += xi[0]
        cy += xi[1]
        if f1:
            err = xi - (li + a)
            e = ti.sqrt(err.dot(err))
            esum += e
            emax = ti.max(emax, e)
            fsum += _attraction_energy(e, fk, fa, fb)
        else:
            rel = xi - p
            e = ti.sqrt(rel.dot(rel))
            fsum += _attraction_energy(e, fk, fa, fb)
            ang[i] = ti.atan2(rel[1], rel[0])
            if e < lead_d:
                lead_d = e
                lead_k = i
            gmax[i] = -1.0  # no far agent in i's component (yet)
            gcnt[i] = 0
    c = ti.math.vec2(cx / n, cy / n)
    obs[row, 0] = s
    obs[row, 1] = p[0]
    obs[row, 2] = p[1]
    obs[row, 3] = qn
    obs[row, 4] = c[0]
    obs[row, 5] = c[1]
    obs[row, 6] = ti.sqrt((c - p).dot(c - p))
    obs[row, 7] = smin
    obs[row, 8] = ssum / n
    obs[row, 9] = smax
    obs[row, 10] = serr
    obs[row, 11] = vmis
    obs[row, 12] = ti.sqrt(near)
    obs[row, 13] = ti.cast(dsum, ti.f64) / n
    if f1:
        obs[row, 14] = esum / n
        obs[row, 15] = emax
        obs[row, 16] = lag
        obs[row, 17] = fsum + 0.5 * gsum
    else:
        obs[row, 18] = fsum + 0.5 * gsum
        obs[row, 19] = ti.cast(ti.sqrt(near) >= prm[b, COLLIDE], ti.f64)  # D1
        if lead_d > tol:
            lead_k = -1
        iso = 0
        comps = 0
        for i in range(a0, a0 + n):
            if deg[i] == 0 and i != lead_k:
                iso += 1
            if _find(parent, i) == i:
                comps += 1
        obs[row, 20] = ti.cast(iso == 0, ti.f64)  # D2
        obs[row, 22] = iso
        obs[row, 23] = comps
        # D3 (formation_props.d3_holds): per component, the counter-clockwise gaps between
        # the far agents' directions from r_0, in (angle, id) order; the successor is
        # found by a scan (O(n * component size), small at these N).
        for k in range(a0, a0 + n):
            pk = pos[k, 0] - p[0]
            qk = pos[k, 1] - p[1]
            if ti.sqrt(pk * pk + qk * qk) > tol:
                root = _find(parent, k)
                best = ti.math.inf
                best_m = -1
                first = ti.math.inf
                first_m = -1
                for m in range(a0, a0 + n):
                    pm = pos[m, 0] - p[0]
                    qm = pos[m, 1] - p[1]
                    if ti.sqrt(pm * pm + qm * qm) > tol and _find(parent, m) == root:
                        am = ang[m]
                        if am < first or (am == first and m < first_m):
                            first = am
                            first_m = m
                        after = am > ang[k] or (am == ang[k] and m > k)
                        if after and (am < best or (am == best and m < best_m)):
                            best = am
                            best_m = m
                gap = best - ang[k]
                if best_m < 0:
                    gap = first + TWO_PI - ang[k]
                gmax[root] = ti.max(gmax[root], gap)
                if gap > np.pi - 1e-9:
                    gcnt[root] += 1
        d3 = 1.0
        for k in range(a0, a0 + n):
            if gmax[k] >= 0.0:  # a root with far agents
                inside = gmax[k] < np.pi - 1e-9
                on_line = gcnt[k] == 2 and gmax[k] <= np.pi + 1e-9
                if not (inside or on_line):
                    d3 = 0.0
        obs[row, 21] = d3


@cache
def advance_kernel(rk4: bool):
    """The window kernel and the frame-velocity kernel for one integrator."""

    @ti.kernel
    def advance(s0: ti.i32, s1: ti.i32, h0: ti.i32, aoff: nd, ooff: nd, prm: nd, iprm: nd,
                chg: nd, inforce: nd, forms: nd, lead: nd, pos: nd, ps: nd, kk: nd, y: nd,
                deg: nd, parent: nd, ang: nd, gmax: nd, gcnt: nd, obs: nd):
        for t in range((aoff.shape[0] - 1) * SPREAD):
            if t % SPREAD == 0:  # one replica per CPU task
                b = t // SPREAD
                a0 = aoff[b]
                n = aoff[b + 1] - a0
                steps = iprm[b, STEPS]
                every = iprm[b, EVERY]
                dt = prm[b, DT]
                per = ti.static(2 if rk4 else 1)
                s = s0
                while s < s1 and s <= steps and iprm[b, BAD] < 0:
                    h = s * per
                    if _runaway(b, a0, n, pos, prm, iprm) != 0:
                        iprm[b, BAD] = s
                        break
                    if s % every == 0 or s == steps:
                        row = ooff[b] + iprm[b, NOBS]
                        iprm[b, NOBS] += 1
                        _observe(b, a0, n, s, h, h0, row, prm, iprm, chg, inforce, lead,
                                 forms, pos, deg, parent, ang, gmax, gcnt, obs)
                    if s < steps:
                        coincident = 0
                        nonfinite = 0
                        lp, _q, ma, mb, ka, kb = _leader_state(b, h, h0, prm, iprm, chg,
                                                               inforce, lead)
                        if ti.static(not rk4):
                            for i in range(a0, a0 + n):
                                ps[i, 0] = pos[i, 0]
                                ps[i, 1] = pos[i, 1]
                            for i in range(a0, a0 + n):
                                r = _rate(b, i, a0, n, ps, lp, ma, mb, ka, kb, prm, iprm,
                                          forms)
                                x = ps[i, 0] + dt * r[0]
                                yy = ps[i, 1] + dt * r[1]
                                pos[i, 0] = x
                                pos[i, 1] = yy
                                coincident |= ti.cast(r[2] > 0.0, ti.i32)
                                nonfinite |= ti.cast(_nonfinite(x, yy), ti.i32)
                        else:
                            # k1 at (x, t); k2, k3 at (x + dt/2 k, t + dt/2); k4 at
                            # (x + dt k3, t + dt): y holds each stage's positions.
                            for i in range(a0, a0 + n):
                                r = _rate(b, i, a0, n, pos, lp, ma, mb, ka, kb, prm, iprm,
                                          forms)
                                kk[i, 0] = r[0]
                                kk[i, 1] = r[1]
                                coincident |= ti.cast(r[2] > 0.0, ti.i32)
                                nonfinite |= ti.cast(_nonfinite(r[0], r[1]), ti.i32)
                            stop = 0  # the stage grid's check stops the step at once
                            for stage in ti.static(range(1, 4)):
                                a = 0.5 * dt
                                if ti.static(stage == 3):
                                    a = dt
                                if stop == 0:
                                    for i in range(a0, a0 + n):
                                        for c in ti.static(range(2)):
                                            y[i, c] = pos[i, c] + a * kk[i, 2 * stage - 2 + c]
                                    stop = _runaway(b, a0, n, y, prm, iprm)
                                if stop == 0:
                                    hp = h + 1
                                    if ti.static(stage == 3):
                                        hp = h + 2
                                    lq, _q2, mq, mr, kq, kr = _leader_state(
                                        b, hp, h0, prm, iprm, chg, inforce, lead)
                                    for i in range(a0, a0 + n):
                                        r = _rate(b, i, a0, n, y, lq, mq, mr, kq, kr, prm,
                                                  iprm, forms)
                                        kk[i, 2 * stage] = r[0]
                                        kk[i, 2 * stage + 1] = r[1]
                                        coincident |= ti.cast(r[2] > 0.0, ti.i32)
                                        nonfinite |= ti.cast(_nonfinite(r[0], r[1]), ti.i32)
                            if stop != 0:
                                iprm[b, BAD] = s
                                break
                            for i in range(a0, a0 + n):
                                for c in ti.static(range(2)):
                                    pos[i, c] = pos[i, c] + dt / 6.0 * (
                                        kk[i, c] + 2.0 * kk[i, 2 + c] + 2.0 * kk[i, 4 + c]
                                        + kk[i, 6 + c])
                                nonfinite |= ti.cast(_nonfinite(pos[i, 0], pos[i, 1]),
                                                     ti.i32)
                        if coincident != 0 or nonfinite != 0:
                            iprm[b, BAD] = s
                            iprm[b, CAUSE] = ti.select(coincident != 0, 0, 1)
                    s += 1

    @ti.kernel
    def velocity(b: ti.i32, h: ti.i32, aoff: nd, prm: nd, iprm: nd, chg: nd, inforce: nd,
                 forms: nd, lead: nd, pos: nd, vel: nd):
        """rdot of replica b's agents at their current positions, time index h (a frame);
        lead's row 0 holds a spline leader's p(t)."""
        for _ in range(1):  # one serial task: the sums in the step's order
            a0 = aoff[b]
            n = aoff[b + 1] - a0
            lp, _q, ma, mb, ka, kb = _leader_state(b, h, h, prm, iprm, chg, inforce, lead)
            for i in range(a0, a0 + n):
                r = _rate(b, i, a0, n, pos, lp, ma, mb, ka, kb, prm, iprm, forms)
                vel[i, 0] = r[0]
                vel[i, 1] = r[1]

    return advance, velocity


class FormationBatch:
    """The state of a batch of M4 replicas (any N <= MAX_N, design, gains, path, schedule,
    steps each; one integrator), advanced window by window by `advance_kernel`."""

    def __init__(self, scenarios: list[Scenario]):
        self.scenarios = scenarios
        p0: FormationParams = scenarios[0].model  # type: ignore[assignment]
        self.per = 2 if p0.integrator == "rk4" else 1
        self.advance_k, self.velocity_k = advance_kernel(p0.integrator == "rk4")
        ns = [s.n_agents for s in scenarios]
        self.aoff = np.concatenate([[0], np.cumsum(ns)]).astype(np.int32)
        rows = [s.time.steps // s.recording.observables_every + 2 for s in scenarios]
        self.ooff = np.concatenate([[0], np.cumsum(rows)]).astype(np.int32)
        B, total = len(scenarios), int(self.aoff[-1])
        prm = np.zeros((B, N_PRM))
        iprm = np.zeros((B, N_IPRM), dtype=np.int32)
        pos = np.zeros((total, 2))
        chg, inforce, forms = [], [], []
        self.paths, self.f1 = [], []
        for b, sc in enumerate(scenarios):
            p: FormationParams = sc.model  # type: ignore[assignment]
            n, d, dt = sc.n_agents, sc.neighbours.radius, sc.time.dt
            init = initial_state(sc)
            path = make_path(p.path, init.positions.mean(axis=0))
            if isinstance(p.attraction, SaturatingF):  # as FormationKernel refuses it
                top = float(np.hypot(*path.velocity(0.0)))
                if top >= p.attraction.v_max:
                    raise ValueError(
                        f"leader speed {top:g} >= attraction.v_max = "
                        f"{p.attraction.v_max:g}: the agents could never keep up "
                        "(eq. 8 has no solution)")
            self.paths.append(path)
            f1 = p.design == "F1"
            self.f1.append(f1)
            a0 = int(self.aoff[b])
            pos[a0:a0 + n] = init.positions
            f = p.attraction
            spline = isinstance(p.path, SplinePath)
            straight = (np.zeros(2), np.zeros(2), 0.0, np.zeros(2)) if spline else (
                path.start, path.q, path.arrival_time, path.end)
            prm[b, :] = [
                np.nextafter(d * d, np.inf) if sc.inclusive else d * d, d, d * d,
                p.repulsion.k_g, f.c if isinstance(f, QuadraticF) else f.k,
                f.v_max if isinstance(f, SaturatingF) else 0.0, dt, dt / self.per,
                *straight[0], *straight[1], straight[2], *straight[3],
                p.collision_distance or d / 100.0, p.leader_tolerance or d / 100.0,
                -1.0 if p.lag_sign == "eq8" else 1.0, d * GRID_WIDEN, 0.0]
            iprm[b, :] = [sc.time.steps, sc.recording.observables_every, -1, 0, 0,
                          F_KINDS[f.kind], G_KINDS[p.repulsion.kind], int(f1), int(spline),
                          len(chg), len(p.schedule), len(inforce), len(forms)]
            if f1:
                sched = OffsetSchedule(p.formation, p.schedule, n, d)
                for c in p.schedule:
                    chg.append([c.start, c.end, np.nan if c.rotate is None else c.rotate,
                                float(c.relaxation == "linear")])
                inforce.extend([k, *m.ravel()] for k, m in sched.in_force)
                forms.extend(row for k in sched.stored for row in k)
        self.steps = iprm[:, STEPS].copy()

        def arr(a, shape, dtype=ti.f64) -> ti.Ndarray:
            a = np.asarray(a, dtype=np.float64 if dtype == ti.f64 else np.int32)
            out = ti.ndarray(dtype, shape=shape if not a.size else a.shape)
            if a.size:
                out.from_numpy(a)
            return out

        i32 = ti.i32
        self.args = dict(
            aoff=arr(self.aoff, None, i32), ooff=arr(self.ooff, None, i32),
            prm=arr(prm, None), iprm=arr(iprm, None, i32), chg=arr(chg, (1, 4)),
            inforce=arr(inforce, (1, 5)), forms=arr(forms, (1, 2)),
            lead0=ti.ndarray(ti.f64, shape=(B, 1, 4)), pos=arr(pos, None),
            ps=ti.ndarray(ti.f64, shape=(total, 2)),
            kk=ti.ndarray(ti.f64, shape=(total, 8) if self.per == 2 else (1, 8)),
            y=ti.ndarray(ti.f64, shape=(total, 2) if self.per == 2 else (1, 2)),
            deg=ti.ndarray(i32, shape=total), parent=ti.ndarray(i32, shape=total),
            ang=ti.ndarray(ti.f64, shape=total), gmax=ti.ndarray(ti.f64, shape=total),
            gcnt=ti.ndarray(i32, shape=total),
            obs=arr(np.zeros((int(self.ooff[-1]), N_OBS)), None),
            vel=ti.ndarray(ti.f64, shape=(total, 2)),
        )
        self.splines = [b for b, sc in enumerate(scenarios)
                        if isinstance(sc.model.path, SplinePath)]
        self.tables = {b: SplineTable(self.paths[b]) for b in self.splines}
        self.last_p: dict[int, tuple[int, np.ndarray]] = {}  # b: (h, p) of the last row
        self.now = np.zeros(B, dtype=np.int64)  # each replica's current step

    def _lead_table(self, s0: int, s1: int) -> ti.Ndarray:
        """The spline leaders' p(t) for the window's time indices (and q(t) at the
        observation steps), from half-step index s0 * per on."""
        if not self.splines:
            return self.args["lead0"]  # read by spline replicas only
        h0 = s0 * self.per
        rows = (s1 - s0) * self.per + 1
        table = np.zeros((len(self.scenarios), rows, 4))
        for b in self.splines:
            sc = self.scenarios[b]
            steps, every = int(self.steps[b]), sc.recording.observables_every
            h = np.arange(h0, min(s1, steps) * self.per + 1)
            if not len(h):  # this replica has ended
                continue
            s, rem = np.divmod(h, self.per)
            seen = (rem == 0) & ((s % every == 0) | (s == steps))  # observation steps
            table[b, : len(h)] = self.tables[b].at(h * (sc.time.dt / self.per), seen)
            self.last_p[b] = (int(h[-1]), table[b, len(h) - 1, :2].copy())
        return self._device("lead", table)

    def _device(self, name: str, a: np.ndarray) -> ti.Ndarray:
        """`a` in a reused device array (windows mostly share one shape; allocating a
        Taichi ndarray costs more than the copy)."""
        held = self.args.get(name)
        if held is None or held.shape != a.shape:
            held = self.args[name] = ti.ndarray(ti.f64, shape=a.shape)
        held.from_numpy(a)
        return held

    def advance(self, s0: int, s1: int) -> None:
        """Advance every replica from step s0 towards s1 (each stops at its own end)."""
        a = self.args
        self.advance_k(s0, s1, s0 * self.per, a["aoff"], a["ooff"], a["prm"], a["iprm"],
                       a["chg"], a["inforce"], a["forms"], self._lead_table(s0, s1),
                       a["pos"], a["ps"], a["kk"], a["y"], a["deg"], a["parent"], a["ang"],
                       a["gmax"], a["gcnt"], a["obs"])
        self.now = np.minimum(s1, self.steps)

    def end_at(self, step: int) -> None:
        """Make `step` every replica's last (cancellation): the next window observes it."""
        iprm = self.args["iprm"].to_numpy()
        iprm[:, STEPS] = np.minimum(iprm[:, STEPS], step)
        self.steps = iprm[:, STEPS].copy()
        self.args["iprm"].from_numpy(iprm)

    def status(self) -> np.ndarray:
        """Per-replica integer slots (steps, observation count, divergence step, ...)."""
        return self.args["iprm"].to_numpy()

    def observables(self, b: int, iprm: np.ndarray) -> dict[str, np.ndarray]:
        o0 = self.ooff[b]
        rows = self.args["obs"].to_numpy()[o0:o0 + iprm[b, NOBS]]
        keep = COMMON + (F1_OBS if self.f1[b] else F2_OBS)
        return {"step": rows[:, 0], **{c: rows[:, OBS.index(c)] for c in keep}}

    def frame(self, b: int, arrays: list[str]) -> dict[str, np.ndarray]:
        a0, a1 = self.aoff[b], self.aoff[b + 1]
        a = self.args
        out = {}
        if "position" in arrays:
            out["position"] = a["pos"].to_numpy()[a0:a1]
        if "velocity" in arrays:
            h = int(self.now[b]) * self.per
            table = a["lead0"]
            if b in self.splines:  # p(t) of the state: the last window's last row
                at, p = self.last_p.get(b, (-1, None))
                if at != h:
                    t = np.array([h * (self.scenarios[b].time.dt / self.per)])
                    p = self.tables[b].at(t, np.zeros(1, dtype=bool))[0, :2]
                lead = np.zeros((len(self.scenarios), 1, 4))
                lead[b, 0, :2] = p
                table = self._device("frame_lead", lead)
            self.velocity_k(b, h, a["aoff"], a["prm"], a["iprm"], a["chg"], a["inforce"],
                            a["forms"], table, a["pos"], a["vel"])
            out["velocity"] = a["vel"].to_numpy()[a0:a1]
        return out

    def convergence_keys(self) -> list[str]:
        return ["formation_error", "velocity_mismatch_max"]

    def extra(self, b: int, iprm: np.ndarray) -> dict[str, Any]:
        return {"leader_arrival_time": self.paths[b].arrival_time,
                "dense_regime": {"steps": 0, "max_reach": 1}}

    def divergence(self, b: int, iprm: np.ndarray) -> tuple[int, str, str] | None:
        step = int(iprm[b, BAD])
        if step < 0:
            return None
        cause = CAUSES[iprm[b, CAUSE]]
        if iprm[b, CAUSE] == 3:
            cause = cause.format(float(self.args["prm"].to_numpy()[b, EXTENT]))
        return step, "position", cause

    @staticmethod
    def batch_key(scenario: Scenario) -> tuple | None:
        """Scenarios with the same key share a launch; None: not for this path (see the
        module docstring)."""
        p: FormationParams = scenario.model  # type: ignore[assignment]
        n = scenario.n_agents
        cap = p.max_exact_candidates
        if n < 2 or n > MAX_N or (p.integrator == "euler" and cap is not None
                                  and 9 * n > cap):
            return None
        return ("formation", p.integrator)
