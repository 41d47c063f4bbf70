"""The fused M4 path's observation: every observable of the per-step path (FormationKernel
.observe, props' D1-D3) of one replica's state, into one row of its buffer; in 3D also
`leader_z` and `centroid_z`. D3 in 2D is the angular-gap test, here; in 3D it is a linear
program per component (props.surrounds_3d), the host's: the row leaves it 0 and writes the
agents' positions and component labels into the snapshot buffer, from which
`FormationBatch` fills it after the launch."""

import numpy as np
import taichi as ti

from ...space.graph import find_serial, union_serial
from ...space.grid import row as row_of
from .fused_terms import (
    IP,
    P,
    attract,
    attraction_energy,
    g_over_s,
    lag_length,
    leader_state,
    pair_energy,
    target,
)

TWO_PI = 2 * np.pi
_NO_PAIR = 1e300  # nearest-pair sentinel
# Observable columns of the buffer (the step first); F1 and F2 fill their own.
OBS = ("step", "leader_x", "leader_y", "leader_speed", "centroid_x", "centroid_y",
       "centroid_distance", "speed_min", "speed_mean", "speed_max", "speed_error_max",
       "velocity_mismatch_max", "min_distance", "degree_mean", "formation_error",
       "formation_error_max", "lag", "V1", "V2", "D1", "D2", "D3", "isolated", "components",
       "leader_z", "centroid_z")
N_OBS = len(OBS)
COMMON = OBS[1:14]
COMMON_3D = ("leader_z", "centroid_z")  # after COMMON, as the per-step path orders them
F1_OBS = ("formation_error", "formation_error_max", "lag", "V1")
F2_OBS = ("V2", "D1", "D2", "D3", "isolated", "components")
SNAP_WIDTH = 4  # a snapshot row per agent (3D F2): x, y, z, its component's label




@ti.func
def observe(b, a0, n, s, h, h0, row, prm: ti.template(), iprm: ti.template(),
             chg: ti.template(), inforce: ti.template(), lead: ti.template(),
             forms: ti.template(), pos: ti.template(), deg: ti.template(),
             parent: ti.template(), ang: ti.template(), gmax: ti.template(),
             gcnt: ti.template(), obs: ti.template(), snap: ti.template(), at,
             dim: ti.template()):
    """The observables of X(s) (time index h) into obs[row]: the columns of OBS; a 3D F2
    replica's positions and labels into snap from `at` on (its D3 the host's)."""
    p, q, ma, mb, ka, kb = leader_state(b, h, h0, prm, iprm, chg, inforce, lead, dim)
    fk = iprm[b, IP.FKIND]
    fa = prm[b, P.FA]
    fb = prm[b, P.FB]
    gk = iprm[b, IP.GKIND]
    kg = prm[b, P.KG]
    d = prm[b, P.D]
    d2 = prm[b, P.D2]
    r2 = prm[b, P.R2]
    f1 = iprm[b, IP.F1] != 0
    qn = ti.sqrt(q.dot(q))
    lag = lag_length(qn, fk, fa, fb)
    a = ti.Vector.zero(float, dim)
    if qn > 0.0:
        a = (lag / qn) * q * prm[b, P.LAG_SIGN]
    tol = prm[b, P.TOL]
    for i in range(a0, a0 + n):
        parent[i] = i
    csum = ti.Vector.zero(float, dim)
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
        xi = row_of(pos, i, dim)
        rep = ti.Vector.zero(float, dim)
        k = 0
        for j in range(a0, a0 + n):
            if j != i:
                dv = row_of(pos, j, dim) - xi
                e2 = dv.dot(dv)
                near = ti.min(near, e2)
                if e2 < r2:
                    k += 1
                    if e2 > 0.0:
                        sd = ti.sqrt(e2)
                        rep += g_over_s(sd, gk, kg, d, d2) * dv
                        gsum += pair_energy(sd, gk, kg, d, d2)
                    if j > i and not f1:
                        union_serial(parent, i, j)
        deg[i] = k
        dsum += k
        li = target(b, i, a0, n, p, ma, mb, ka, kb, iprm, forms, dim)
        v = attract(li - xi, fk, fa, fb) + rep
        sp = ti.sqrt(v.dot(v))
        smin = ti.min(smin, sp)
        smax = ti.max(smax, sp)
        ssum += sp
        serr = ti.max(serr, ti.abs(sp - qn))
        vm = v - q
        vmis = ti.max(vmis, ti.sqrt(vm.dot(vm)))
        csum += xi
        if f1:
            err = xi - (li + a)
            e = ti.sqrt(err.dot(err))
            esum += e
            emax = ti.max(emax, e)
            fsum += attraction_energy(e, fk, fa, fb)
        else:
            rel = xi - p
            e = ti.sqrt(rel.dot(rel))
            fsum += attraction_energy(e, fk, fa, fb)
            if ti.static(dim == 2):
                ang[i] = ti.atan2(rel[1], rel[0])
            if e < lead_d:
                lead_d = e
                lead_k = i
            gmax[i] = -1.0  # no far agent in i's component (yet)
            gcnt[i] = 0
    c = csum / n
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
    obs[row, 13] = ti.cast(dsum, float) / n
    if ti.static(dim == 3):
        obs[row, 24] = p[2]
        obs[row, 25] = c[2]
    if f1:
        obs[row, 14] = esum / n
        obs[row, 15] = emax
        obs[row, 16] = lag
        obs[row, 17] = fsum + 0.5 * gsum
    else:
        obs[row, 18] = fsum + 0.5 * gsum
        obs[row, 19] = ti.cast(ti.sqrt(near) >= prm[b, P.COLLIDE], float)  # D1
        if lead_d > tol:
            lead_k = -1
        iso = 0
        comps = 0
        for i in range(a0, a0 + n):
            if deg[i] == 0 and i != lead_k:
                iso += 1
            if find_serial(parent, i) == i:
                comps += 1
        obs[row, 20] = ti.cast(iso == 0, float)  # D2
        obs[row, 22] = iso
        obs[row, 23] = comps
        if ti.static(dim == 2):
            obs[row, 21] = surrounds_2d(a0, n, p, tol, pos, parent, ang, gmax, gcnt)
        elif iprm[b, IP.SNAP] != 0:
            snapshot(a0, n, at, pos, parent, snap)


@ti.func
def snapshot(a0, n, at, pos: ti.template(), parent: ti.template(), snap: ti.template()):
    """Each agent's position and component label (its root, relative to a0) from snap[at] on:
    the host's D3 in 3D (props.d3_holds_3d)."""
    for k in range(a0, a0 + n):
        base = at + (k - a0) * SNAP_WIDTH
        for c in ti.static(range(3)):
            snap[base + c] = pos[k, c]
        snap[base + 3] = ti.cast(find_serial(parent, k) - a0, float)


@ti.func
def surrounds_2d(a0, n, p, tol, pos: ti.template(), parent: ti.template(),
                 ang: ti.template(), gmax: ti.template(), gcnt: ti.template()) -> float:
    """D3 in 2D (1.0 or 0.0): every component's far agents leave no angular gap around
    r_0 = p larger than pi (props.surrounds_2d)."""
    # D3 (props.d3_holds): per component, the counter-clockwise gaps between
    # the far agents' directions from r_0, in (angle, id) order; the successor is
    # found by a scan (O(n * component size), small at these N).
    for k in range(a0, a0 + n):
        pk = pos[k, 0] - p[0]
        qk = pos[k, 1] - p[1]
        if ti.sqrt(pk * pk + qk * qk) > tol:
            root = find_serial(parent, k)
            best = ti.math.inf
            best_m = -1
            first = ti.math.inf
            first_m = -1
            for m in range(a0, a0 + n):
                pm = pos[m, 0] - p[0]
                qm = pos[m, 1] - p[1]
                if ti.sqrt(pm * pm + qm * qm) > tol and find_serial(parent, m) == root:
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
                gcnt[root] = gcnt[root] + 1
    d3 = 1.0
    for k in range(a0, a0 + n):
        if gmax[k] >= 0.0:  # a root with far agents
            inside = gmax[k] < np.pi - 1e-9
            on_line = gcnt[k] == 2 and gmax[k] <= np.pi + 1e-9
            if not (inside or on_line):
                d3 = 0.0
    return d3
