"""M2 and M3 on the small-N path: many steps of many replicas in one kernel launch.

The equations are the ones `kernel.py` and `obstacles.py` of this package document
(paper 000 eq. 1, 3-5, 10; paper 002 eq. 3-5 and p. 3); only the schedule differs, as in
`kernels/models/vicsek/fused.py`: one launch advances every replica of a batch through a window
of steps, replicas in parallel (one per CPU task), each replica's steps and agents serial
inside, the state kept in the kernel's arrays and the observables written into a
per-replica buffer. A replica computes the same numbers alone, in a batch, or cut into
any windows.

Per replica and step s (state X(s) = (r, v[, R_i]) in agent-id order):
  1. switching/M3: a cell list of r(s) over its bounding box (cells of side R, the initial
     radius, which bounds every R_i, numbered x fastest, then y, then z; a stable counting
     sort, so every sum has one fixed order; hashed buckets of the same cells when the box
     needs over 4 N + 16 of them), or all pairs when `neighbour_search` says so ("auto":
     N <= 64) or the box is under three cells across every way; the slot-order copy of
     X(s) is what every visit reads (the 3x3, in 3D 3x3x3, cells around an agent);
  2. on an observation step, the observables of X(s) (one more visit: valencies, the
     union-find of the graph, the saturated potential, the closest pair);
  3. M3 at s > 0, s % radius_every == 0: the adaptive radius of eq. 4, synchronously;
  4. u_i of eq. 3 (and paper 002's -grad V_i - c_d v_i), v' = v + dt u, r' = r + dt v';
     or RK4 (kernels/space/integrate.py's stage_pair / finish_pair, the per-step path's
     sums): u at X(s), then at each stage state, for which step 1 (cells, slot copy, V_i)
     is redone at the stage positions, so neighbours are re-evaluated at every stage.
     A non-finite value stops the replica and records the step.
M2 and M3 run in 2D and 3D: the dimension `dim` is a compile-time parameter of the kernel
(the law needs only |r_ij| and the vectors r_ij, v_ij, as in forces.py; paper 002's
navigation function only |x - r_d|, |x - r_o| and their vectors, as in navigation.py), and
2D compiles to the arithmetic it had before 3D. The 3D heading spread is the per-step
path's (observe.py): twice the largest angle between a velocity's direction and the mean
direction.
The mission potential folds the point and disc (in 3D sphere) obstacles of the 3x3 (3x3x3)
cells of a per-replica obstacle grid (cells of side obstacle_range + the largest disc
radius, as kernels/models/flocking/navigation.py; numbered x fastest, then y, then z), for an
agent inside the obstacles' bounding box grown by a cell.

lambda_2 (switching, N <= lambda2_max_agents) needs an eigensolver: the kernel writes
(r, R_i) at each observation step into a snapshot buffer and the host computes lambda_2
from it after each launch, with the per-step path's own functions (a stacked dense
eigvalsh at N <= 32). A window holding more observations than the buffer is cut into
several launches, which never changes a bit.

Not on this path (`FlockingBatch.batch_key` returns None; the per-step path runs them):
M3's `radius_rule: "min"`.
"""

from functools import cache
from typing import Any

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from ... import runtime
from ...replicas import FusedBatch, Snapshots
from ...space.blocks import dense_cell, grid_row
from ...space.cells import SPREAD
from ...space.frame import point_mass_frame
from ...space.graph import find_serial, union_serial
from ...space.grid import put, runaway_cause, widen, within
from ...space.integrate import STAGES, finish_pair, nonfinite, stage_pair
from ...space.observables import TWO_PI, make_circular_spread
from ...space.params import Slots
from ...space.replica_cells import G_NX, G_NY, G_NZ, G_O, G_SPAN, G_W, bucket, make_replica_cells
from ...space.replica_loop import cell_offsets, observation_rows, offsets
from . import law, potentials
from . import observe as fo
from .law import DAMPING, DIVERGED_CAUSE
from .navigation import FAR
from .topology import build_edges, to_csr

nd = ti.types.ndarray()
NEAREST_NONE = 1e300
HIST = fo.HIST_BINS + 1  # valency histogram columns (the last one: 16 and more)
SNAP_DOUBLES = 4_000_000  # snapshot buffer for lambda_2 (32 MB), cut into launches above
MODES = {"fixed": 0, "switching": 1, "mission": 2}

# Per-replica parameter slots: prm (f64) and iprm (i32).
P = Slots("DT", "A", "C", "R", "R2", "CD", "VMIN", "STUCK2", "FLOOR", "DX", "DY", "RANGE",
         "LAMBDA", "KAPPA", "OBX0", "OBY0", "OBX1", "OBY1", "OX", "OY", "OW", "OCAP", "QC",
         "SPAN", "DZ", "OBZ0", "OBZ1", "OZ")
IP = Slots("STEPS", "EVERY", "NOBS", "BAD", "CAUSE", "CELLS", "INCL", "REVERY", "ADAPT", "DAMP",
          "ONX", "ONY", "OCOFF", "OM", "VPER", "VOFF", "HALVED", "GROWN", "SNAP", "SNAP0", "ONZ")
# M3's slots by coordinate: the destination, the obstacle grid's origin and the bounding box
# of the obstacles (grown by the cell) outside which no obstacle is within reach.
DEST = (P.DX, P.DY, P.DZ)
OORIGIN = (P.OX, P.OY, P.OZ)
OLOW = (P.OBX0, P.OBY0, P.OBZ0)
OHIGH = (P.OBX1, P.OBY1, P.OBZ1)
OCELLS = (IP.ONX, IP.ONY, IP.ONZ)
# Observable columns (energy: W or Q_reduced; q_constant: Q - Q_reduced).
OBS = ("step", "mean_velocity_x", "mean_velocity_y", "velocity_disagreement",
       "velocity_disagreement_max", "speed_min", "speed_mean", "speed_max", "heading_spread",
       "energy", "q_constant", "components", "valency_mean", "valency_min", "valency_max",
       "min_distance", "min_pair_i", "min_pair_j", "destination_distance_mean",
       "destination_distance_max", "inside_vmin_fraction", "mission_potential_max",
       "obstacle_distance_min", "radius_min", "radius_mean", "radius_max",
       "velocity_disagreement_components", "velocity_disagreement_components_max",
       "mean_velocity_z")
COL = {name: k for k, name in enumerate(OBS)}
N_OBS = len(OBS)
MISSION_KEYS = OBS[18:28]
# The batch's arrays, in the kernel's argument order.
ARRAYS = ("aoff", "coff", "ooff", "prm", "iprm", "pos", "vel", "rad", "ps", "cell", "cstart",
          "cidx", "parent", "csum", "mis", "arc_lo", "arc_hi", "ptr", "idx", "opos", "orad",
          "ostart", "obs", "val", "snap", "sbase", "rk")


def velocity_keys(dim: int) -> list[str]:
    """The velocity observables in the per-step path's order (observe.velocity_stats)."""
    means = [f"mean_velocity_{c}" for c in "xyz"[:dim]]
    return [*means, *OBS[3:9]]


def rk_columns(dim: int) -> tuple[int, int, int, int, int]:
    """rk's columns (RK4: the step's r(s), v(s), the sums of k for r and v, u at the last
    stage), dim each."""
    return 0, dim, 2 * dim, 3 * dim, 4 * dim


def columns(dim: int) -> tuple[int, int, int, int, int]:
    """ps's columns (position, velocity, R_i, hashed cell, width): r and v and the hashed
    cell take dim columns each; in 2D the layout it had before 3D."""
    return 0, dim, 2 * dim, 2 * dim + 1, 3 * dim + 1


# Vectors of the runtime's float type: built at compile time (`float` is Taichi's
# default_fp then), where a module-level ti.types.vector would fix the type at import.
@ti.func
def Acc5(a, b, c, d, e):
    return ti.Vector([a, b, c, d, e], dt=float)


@ti.func
def _full(x, dim: ti.template()):
    """The dim-vector (x, ..., x) of the float type."""
    return ti.Vector([x for _ in ti.static(range(dim))], dt=float)


@ti.func
def _row(a: ti.template(), i, c0: ti.template(), dim: ti.template()):
    """Columns c0 .. c0 + dim of row i of a, as a dim-vector of the float type."""
    return ti.Vector([a[i, c0 + c] for c in ti.static(range(dim))], dt=float)


@ti.func
def put_at(a: ti.template(), i, c0: ti.template(), x):
    """Columns c0 .. c0 + x.n of row i of a = the vector x (_row's inverse)."""
    for c in ti.static(range(x.n)):
        a[i, c0 + c] = x[c]


# The replica cell lists (kernels/space/replica_cells.py) of the state (hashed buckets past
# the cell budget) and of the closest-pair search (cells widened instead).
_cells = {(dim, h): make_replica_cells(dim, may_hash=h) for dim in (2, 3) for h in (True, False)}


def make_visit(pair, dim: int, by_id: bool = False):
    """visit(k, ...) folding acc = pair(k, m, d, acc, q, ps, S) over slot k's candidates,
    d = r_m - r_k: every slot of the replica (cells across = 0), the 3x3 (3x3x3) cells
    around slot k read as rows of slots contiguous along x, z outermost, or (hashed,
    ny < 0) the buckets of those cells, each slot checked against its exact cell (ps's
    hashed-cell columns). by_id: ps in id order (rows cidx[k]), and pair gets the rows."""
    X, _, _, HC, _ = columns(dim)
    rows = 3 ** (dim - 1)  # of the 3x3 (3x3x3) cells around slot k's

    @ti.func
    def at(k, cidx: ti.template()):
        r = k
        if ti.static(by_id):
            r = cidx[k]
        return r

    @ti.func
    def visit(k, a0, n, c0, nx, ny, nz, acc, q, ps: ti.template(), cell: ti.template(),
              cstart: ti.template(), cidx: ti.template(), S: ti.template()):
        ik = at(k, cidx)
        xk = _row(ps, ik, X, dim)
        if nx == 0:
            for m in range(a0, a0 + n):
                j = at(m, cidx)
                acc = pair(ik, j, _row(ps, j, X, dim) - xk, acc, q, ps, S)
        elif ny < 0:
            hc = _row(ps, ik, HC, dim)
            for t in range(3**dim):  # a runtime loop, not unrolled: less to compile
                off = ti.Vector([t % 3 - 1, t // 3 % 3 - 1, t // 9 - 1])
                c = ti.Vector([ti.cast(hc[a], ti.i32) + off[a] for a in ti.static(range(dim))])
                bk = c0 + bucket(c, nx)
                for m in range(a0 + cstart[bk], a0 + cstart[bk + 1]):
                    j = at(m, cidx)
                    same = True
                    for a in ti.static(range(dim)):
                        same = same and ps[j, HC + a] == hc[a] + off[a]
                    if same:
                        acc = pair(ik, j, _row(ps, j, X, dim) - xk, acc, q, ps, S)
        else:
            shape = ti.Vector([nx, ny, nz])
            c = dense_cell(cell[cidx[k]], shape, dim)
            xlo = ti.max(c[0] - 1, 0)
            xhi = ti.min(c[0] + 1, nx - 1)
            for r in range(rows):  # z outermost, then y
                rk = grid_row(cstart, c0, c, r % 3 - 1, r // 3 - 1, xlo, xhi, shape, dim)
                for m in range(a0 + rk[0], a0 + rk[1]):
                    j = at(m, cidx)
                    acc = pair(ik, j, _row(ps, j, X, dim) - xk, acc, q, ps, S)
        return acc

    return visit


@ti.func
def _in_obstacle_box(b, x, prm: ti.template()):
    """x lies in the obstacles' bounding box grown by a cell (outside it none is in reach)."""
    inside = True
    for c in ti.static(range(x.n)):
        inside = inside & (prm[b, OLOW[c]] <= x[c]) & (x[c] <= prm[b, OHIGH[c]])
    return inside


@ti.func
def _fold_obstacles(b, x, acc, prm: ti.template(), iprm: ti.template(), opos: ti.template(),
                    orad: ti.template(), ostart: ti.template()):
    """acc folded over the obstacles of the 3x3 (3x3x3) cells around x in replica b's
    obstacle grid (cells numbered x fastest, then y, then z), rows contiguous along x."""
    dim = ti.static(x.n)
    w = prm[b, P.OW]
    c = ti.Vector([ti.cast(ti.floor((x[a] - prm[b, OORIGIN[a]]) / w), ti.i32)
                   for a in ti.static(range(dim))])
    shape = ti.Vector([iprm[b, IP.ONX], iprm[b, IP.ONY], iprm[b, IP.ONZ]])
    xlo = ti.max(c[0] - 1, 0)
    xhi = ti.min(c[0] + 1, shape[0] - 1)
    rng = prm[b, P.RANGE]
    lam = prm[b, P.LAMBDA]
    for r in range(3 ** (dim - 1)):  # z outermost, then y
        rk = grid_row(ostart, iprm[b, IP.OCOFF], c, r % 3 - 1, r // 3 - 1, xlo, xhi, shape,
                      dim)
        for o in range(rk[0], rk[1]):
            acc = law.fold_obstacle(acc, _row(opos, o, 0, dim) - x, orad[o], rng, lam)
    return acc


@ti.func
def navigation(b, x, prm: ti.template(), iprm: ti.template(), opos: ti.template(),
               orad: ti.template(), ostart: ti.template()):
    """(V_i, grad V_i, min boundary distance) at x (dim + 2 values) for replica b: paper
    002's navigation function (see kernels/models/flocking/navigation.py) over point and
    disc (sphere) obstacles, folded by the product rule."""
    dim = ti.static(x.n)
    acc = ti.Vector([1.0] + [0.0 for _ in ti.static(range(dim))] + [FAR], dt=float)
    if iprm[b, IP.OM] > 0:
        if _in_obstacle_box(b, x, prm):
            acc = _fold_obstacles(b, x, acc, prm, iprm, opos, orad, ostart)
    bsum = acc[0]
    gb = ti.Vector([acc[1 + c] for c in ti.static(range(dim))], dt=float)
    y = x - ti.Vector([prm[b, DEST[c]] for c in ti.static(range(dim))], dt=float)
    v = 0.0
    g = _full(0.0, dim)
    kappa = prm[b, P.KAPPA]
    if kappa == 1.0:  # a replica's kappa is a runtime value: both forms compiled
        v, g = law.navigation_value(y, bsum, gb, kappa, True)
    else:
        v, g = law.navigation_value(y, bsum, gb, kappa, False)
    return ti.Vector([v] + [g[c] for c in ti.static(range(dim))] + [acc[dim + 1]], dt=float)


@ti.func
def _velocity_angle(k, S: ti.template()):
    """atan2(v) of slot k (2D: the velocity in ps's columns 2 and 3)."""
    ps = ti.static(S[0])
    return ti.atan2(ps[k, 3], ps[k, 2])


# The shortest arc holding every heading atan2(v) (kernels/space/observables.py).
heading_spread = make_circular_spread(_velocity_angle)


@ti.func
def _direction(v):
    """v over its length; a zero velocity counts as the x axis (observe._unit)."""
    sp = ti.sqrt(v.dot(v))
    e = ti.Vector.unit(3, 0, float)
    if sp > 0.0:
        e = v / sp
    return e


@ti.func
def heading_spread_3d(a0, n, ps: ti.template()):
    """Twice the largest angle between a velocity's direction and the mean direction (the
    normalised sum of the directions), 2 pi when that sum is zero (observe.velocity_stats:
    3D headings have no circular order)."""
    V = ti.static(columns(3)[1])
    s = ti.Vector.zero(float, 3)
    for k in range(a0, a0 + n):
        s += _direction(_row(ps, k, V, 3))
    norm = ti.sqrt(s.dot(s))
    res = TWO_PI
    if norm > 0.0:
        axis = s / norm
        cmin = ti.math.inf
        for k in range(a0, a0 + n):
            cmin = ti.min(cmin, _direction(_row(ps, k, V, 3)).dot(axis))
        res = 2.0 * ti.acos(ti.max(ti.min(cmin, 1.0), -1.0))
    return res


@ti.func
def velocity_stats(row, a0, n, ps: ti.template(), lo: ti.template(), hi: ti.template(),
                   obs: ti.template(), dim: ti.template()):
    """The columns of velocity_keys(dim) for the state in ps (velocity in columns dim ..
    2 dim); returns the kinetic energy 1/2 sum |v|^2."""
    V = ti.static(columns(dim)[1])
    m = _full(0.0, dim)
    for k in range(a0, a0 + n):
        m += _row(ps, k, V, dim)
    m /= n
    dev = 0.0
    dmax = 0.0
    smin = ti.math.inf
    smax = 0.0
    ssum = 0.0
    kin = 0.0
    for k in range(a0, a0 + n):
        v = _row(ps, k, V, dim)
        e = v - m
        d2 = e.dot(e)
        dev += d2
        dmax = ti.max(dmax, d2)
        v2 = v.dot(v)
        kin += v2
        sp = ti.sqrt(v2)
        smin = ti.min(smin, sp)
        smax = ti.max(smax, sp)
        ssum += sp
    for c in ti.static(range(dim)):
        obs[row, ti.static(COL["mean_velocity_" + "xyz"[c]])] = m[c]
    obs[row, COL["velocity_disagreement"]] = dev
    obs[row, COL["velocity_disagreement_max"]] = ti.sqrt(dmax)
    obs[row, COL["speed_min"]] = smin
    obs[row, COL["speed_mean"]] = ssum / n
    obs[row, COL["speed_max"]] = smax
    if ti.static(dim == 3):
        obs[row, COL["heading_spread"]] = heading_spread_3d(a0, n, ps)
    else:
        obs[row, COL["heading_spread"]] = heading_spread(a0, n, lo, hi, ti.static((ps,)))
    return 0.5 * kin


# The arrays of a window, as one compile-time tuple (its order: ARRAYS).
(AOFF, COFF, OOFF, PRM, IPRM, POS, VEL, RADII, PS, CELL, CSTART, CIDX, PARENT, CSUM, MIS,
 ARC_LO, ARC_HI, PTR, IDX, OPOS, ORAD, OSTART, OBS_ROWS, VAL, SNAP, SBASE, RKS) = range(
    len(ARRAYS))


@ti.func
def cells_across(g):
    return ti.math.ivec3(ti.cast(g[G_NX], ti.i32), ti.cast(g[G_NY], ti.i32),
                         ti.cast(g[G_NZ], ti.i32))


@ti.func
def mission_observables(b, a0, n, row, q, prm: ti.template(), ps: ti.template(),
                        parent: ti.template(), csum: ti.template(), mis: ti.template(),
                        obs: ti.template(), dim: ti.template()):
    """M3's observables of X(s) (ps in slot order, V_i in mis, the metric graph's
    union-find forest in parent) into obs[row]: the mission potential, destination and
    obstacle distances, the radii, Q's constant part and the per-component velocity
    disagreement; returns sum_i V_i (eq. 5's mission part of Q)."""
    X, V, RAD = ti.static(columns(dim)[0], columns(dim)[1], columns(dim)[2])
    msum = 0.0
    inside = 0
    mmax = -ti.math.inf
    omin = prm[b, P.OCAP]  # exact below the obstacle grid's cell; capped there
    dmean = 0.0
    dfar = 0.0
    rmin = ti.math.inf
    rmax = 0.0
    rsum = 0.0
    qc = 0.0
    dest = ti.Vector([prm[b, DEST[c]] for c in ti.static(range(dim))], dt=float)
    for k in range(a0, a0 + n):
        vk = mis[k, 0]
        msum += vk
        if vk <= prm[b, P.VMIN]:
            inside += 1
        mmax = ti.max(mmax, vk)
        omin = ti.min(omin, mis[k, dim + 1])
        y = _row(ps, k, X, dim) - dest
        dd = ti.sqrt(y.dot(y))
        dmean += dd
        dfar = ti.max(dfar, dd)
        r = ps[k, RAD]
        rmin = ti.min(rmin, r)
        rmax = ti.max(rmax, r)
        rsum += r
        qc += potentials.value(r * r, q[2], q[3])
        for c in ti.static(range(dim + 1)):
            csum[k, c] = 0.0
    obs[row, COL["q_constant"]] = 0.5 * (n - 1) * qc
    obs[row, COL["destination_distance_mean"]] = dmean / n
    obs[row, COL["destination_distance_max"]] = dfar
    obs[row, COL["inside_vmin_fraction"]] = ti.cast(inside, float) / n
    obs[row, COL["mission_potential_max"]] = mmax
    obs[row, COL["obstacle_distance_min"]] = omin
    obs[row, COL["radius_min"]] = rmin
    obs[row, COL["radius_mean"]] = rsum / n
    obs[row, COL["radius_max"]] = rmax
    # Paper 002: each component synchronises on its own (csum: the velocity sum
    # and member count of each component, at its root).
    for k in range(a0, a0 + n):
        root = find_serial(parent, k)
        for c in ti.static(range(dim)):
            csum[root, c] = csum[root, c] + ps[k, V + c]
        csum[root, dim] = csum[root, dim] + 1.0
    dev = 0.0
    dev_max = 0.0
    for k in range(a0, a0 + n):
        root = find_serial(parent, k)
        cnt = csum[root, dim]
        e = _row(ps, k, V, dim) - _row(csum, root, 0, dim) / cnt
        d2 = e.dot(e)
        dev += d2
        dev_max = ti.max(dev_max, d2)
    obs[row, COL["velocity_disagreement_components"]] = dev
    obs[row, COL["velocity_disagreement_components_max"]] = ti.sqrt(dev_max)
    return msum


def _pair_visits(mode: int, dim: int):
    """The pair terms of a window (the law's, over slot k's candidates m, d = r_m - r_k)
    and their visits: (pair_radius2, visit_force, visit_radius, visit_observe,
    visit_closest)."""
    mission = mode == MODES["mission"]
    V, RAD = columns(dim)[1], columns(dim)[2]

    @ti.func
    def pair_radius2(k, q, ps: ti.template()):
        r2 = q[0]
        if ti.static(mission):  # paper 002 eq. 4 as printed: R_ij = R_i ("own")
            r2 = ps[k, RAD] * ps[k, RAD]
        return r2

    @ti.func
    def force_pair(k, m, d, acc, q, ps: ti.template(), S: ti.template()):
        """Slot m's term in slot k's sums, by the law (q: (R^2, inclusive, a, c))."""
        return acc + law.metric_term(d, d.dot(d), pair_radius2(k, q, ps), ti.cast(q[1], ti.i32),
                                     m != k, _row(ps, m, V, dim), q[2])

    @ti.func
    def radius_pair(k, m, d, acc, q, ps: ti.template(), S: ti.template()):
        if m != k and within(d.dot(d), pair_radius2(k, q, ps), ti.cast(q[1], ti.i32)):
            acc = ti.max(acc, ps[m, RAD])
        return acc

    @ti.func
    def observe_pair(k, m, d, acc, q, ps: ti.template(), S: ti.template()):
        """acc = (valency, nearest d^2, nearest slot, sum V below R, pairs below R)."""
        parent = ti.static(S[0])
        if m != k:
            s2 = d.dot(d)
            if s2 < acc[1]:
                acc[1] = s2
                acc[2] = ti.cast(m, float)
            r2 = pair_radius2(k, q, ps)
            if within(s2, r2, ti.cast(q[1], ti.i32)):
                acc[0] += 1.0
                # own: j in N_i need not imply i in N_j, so every edge is joined from i.
                if ti.static(mission) or m > k:
                    union_serial(parent, k, m)
            if s2 < r2:
                acc[3] += potentials.value(s2, q[2], q[3])
                acc[4] += 1.0
        return acc

    @ti.func
    def closest_pair(k, m, d, acc, q, ps: ti.template(), S: ti.template()):
        """acc = (d^2, row, row) of the closest pair so far."""
        if m != k:
            s2 = d.dot(d)
            if s2 < acc[0]:
                acc = ti.math.vec3(s2, k, m)
        return acc

    visit_force = make_visit(force_pair, dim)
    visit_radius = make_visit(radius_pair, dim)
    visit_observe = make_visit(observe_pair, dim)
    visit_closest = make_visit(closest_pair, dim, by_id=True)
    return pair_radius2, visit_force, visit_radius, visit_observe, visit_closest


def _closest_search(dim: int, visit_closest):
    """The closest pair's search of a window: (closest_all_pairs, closest_cells,
    write_closest)."""
    X = columns(dim)[0]
    closest_grid = _cells[dim, False]

    @ti.func
    def closest_all_pairs(a0, n, ps: ti.template()):
        """(d^2, slot, slot) of the closest pair, every pair tested."""
        best = ti.math.vec3(NEAREST_NONE, a0, a0)
        for k in range(a0, a0 + n):
            for m in range(k + 1, a0 + n):
                d = _row(ps, m, X, dim) - _row(ps, k, X, dim)
                s2 = d.dot(d)
                if s2 < best[0]:
                    best = ti.math.vec3(s2, k, m)
        return best

    @ti.func
    def closest_cells(a0, n, c0, cap, ps: ti.template(), cell: ti.template(),
                      cstart: ti.template(), cidx: ti.template()):
        """(d^2, id row, id row) of the closest pair of ps (id order): a cell list of
        side about the mean spacing, doubled until the pair found lies closer than a cell
        side (then no closer pair can sit outside the 3x3 (3x3x3) cells)."""
        lo = _full(ti.math.inf, dim)
        hi = _full(-ti.math.inf, dim)
        for i in range(a0, a0 + n):
            lo = ti.min(lo, _row(ps, i, X, dim))
            hi = ti.max(hi, _row(ps, i, X, dim))
        ext = hi - lo
        span = ti.max(ext[0], ext[1])
        w = 0.0
        if ti.static(dim == 3):
            w = ti.max(span, ext[2]) / ti.pow(ti.cast(n, float), 1.0 / 3.0)
        else:
            w = span / ti.sqrt(ti.cast(n, float))
        if not (w > 0.0):
            w = 1.0
        best = ti.math.vec3(NEAREST_NONE, a0, a0)
        done = False
        while not done:
            g = closest_grid(a0, n, c0, cap, w, 0.0, ps, cell, cstart, cidx, ())
            nx = ti.cast(g[G_NX], ti.i32)
            best = ti.math.vec3(NEAREST_NONE, a0, a0)
            if nx <= 0:
                best = closest_all_pairs(a0, n, ps)
                done = True
            else:
                for k in range(a0, a0 + n):
                    best = visit_closest(k, a0, n, c0, nx, ti.cast(g[G_NY], ti.i32),
                                         ti.cast(g[G_NZ], ti.i32), best, ti.math.vec4(0.0),
                                         ps, cell, cstart, cidx, ())
                w = g[G_W]
                if best[0] < w * w:
                    done = True
                else:
                    w *= 2.0
        return best

    @ti.func
    def write_closest(row, a0, best, ids_of_slots: ti.template(), cidx: ti.template(),
                      obs: ti.template()):
        i = ti.cast(best[1], ti.i32)
        j = ti.cast(best[2], ti.i32)
        if ti.static(ids_of_slots):
            i = cidx[i]
            j = cidx[j]
        obs[row, COL["min_distance"]] = ti.sqrt(best[0])
        obs[row, COL["min_pair_i"]] = ti.min(i, j) - a0
        obs[row, COL["min_pair_j"]] = ti.max(i, j) - a0

    return closest_all_pairs, closest_cells, write_closest


def _observers(mode: int, dim: int, pair_radius2, visit_observe, closest):
    """The observation passes of a window: (observe_fixed, observe_metric)."""
    mission = mode == MODES["mission"]
    X, RAD = columns(dim)[0], columns(dim)[2]
    closest_all_pairs, closest_cells, write_closest = closest

    @ti.func
    def observe_fixed(b, a0, n, c0, cap, row, prm: ti.template(), ps: ti.template(),
                      ptr: ti.template(), idx: ti.template(), cell: ti.template(),
                      cstart: ti.template(), cidx: ti.template(), lo: ti.template(),
                      hi: ti.template(), obs: ti.template()):
        """W of eq. 5 and the closest pair (the graph's own observables are constants)."""
        kin = velocity_stats(row, a0, n, ps, lo, hi, obs, dim)
        pot = 0.0
        for i in range(a0, a0 + n):
            for e in range(ptr[i], ptr[i + 1]):
                j = idx[e]
                d = _row(ps, j, X, dim) - _row(ps, i, X, dim)
                pot += potentials.value(d.dot(d), prm[b, P.A], prm[b, P.C])
        obs[row, COL["energy"]] = 0.5 * pot + kin
        best = closest_cells(a0, n, c0, cap, ps, cell, cstart, cidx)
        write_closest(row, a0, best, False, cidx, obs)

    @ti.func
    def observe_metric(b, a0, n, c0, nx, ny, nz, w, row, nrow, q, prm: ti.template(),
                       iprm: ti.template(), ps: ti.template(), cell: ti.template(),
                       cstart: ti.template(), cidx: ti.template(), parent: ti.template(),
                       csum: ti.template(), lo: ti.template(), hi: ti.template(),
                       mis: ti.template(), obs: ti.template(), val: ti.template(),
                       snap: ti.template(), sbase: ti.template()):
        """The switching observables of X(s) (ps in slot order) into obs[row], the
        valencies of observation `nrow` into val, and (for lambda_2) the snapshot of
        (r, R_i) in id order."""
        kin = velocity_stats(row, a0, n, ps, lo, hi, obs, dim)
        for k in range(a0, a0 + n):
            parent[k] = k
        vper = iprm[b, IP.VPER]
        vbase = iprm[b, IP.VOFF] + nrow * ti.select(vper != 0, n, HIST)
        dsum = 0.0
        dmin = 2.0**30
        dmax = 0.0
        pot = 0.0
        best = ti.math.vec3(NEAREST_NONE, a0, a0)
        for k in range(a0, a0 + n):
            acc = Acc5(0.0, NEAREST_NONE, ti.cast(k, float), 0.0, 0.0)
            acc = visit_observe(k, a0, n, c0, nx, ny, nz, acc, q, ps, cell, cstart, cidx,
                                ti.static((parent,)))
            deg = acc[0]
            dsum += deg
            dmin = ti.min(dmin, deg)
            dmax = ti.max(dmax, deg)
            # V(R_i) once per agent: R_i is R (M2) or agent i's own radius (M3).
            pot += acc[3] - acc[4] * potentials.value(pair_radius2(k, q, ps), q[2], q[3])
            if acc[1] < best[0]:
                best = ti.math.vec3(acc[1], k, acc[2])
            ideg = ti.cast(deg, ti.i32)
            if vper != 0:
                val[vbase + cidx[k] - a0] = ideg
            else:
                h = vbase + ti.min(ideg, HIST - 1)
                val[h] = val[h] + 1
        obs[row, COL["valency_mean"]] = dsum / n
        obs[row, COL["valency_min"]] = dmin
        obs[row, COL["valency_max"]] = dmax
        if not (nx == 0 or best[0] < w * w):  # nothing within a cell: look everywhere
            best = closest_all_pairs(a0, n, ps)
        write_closest(row, a0, best, True, cidx, obs)
        roots = 0
        for k in range(a0, a0 + n):
            if parent[k] == k:
                roots += 1
        obs[row, COL["components"]] = roots
        energy = 0.5 * pot + kin
        if ti.static(mission):
            energy += mission_observables(b, a0, n, row, q, prm, ps, parent, csum, mis, obs,
                                          dim)  # eq. 5: + sum_i V_i
        else:
            obs[row, COL["q_constant"]] = prm[b, P.QC]
        obs[row, COL["energy"]] = energy
        if iprm[b, IP.SNAP] != 0:
            base = sbase[b] + (nrow - iprm[b, IP.SNAP0]) * n * (dim + 1)
            for k in range(a0, a0 + n):
                at = base + (cidx[k] - a0) * (dim + 1)
                for c in ti.static(range(dim)):
                    snap[at + c] = ps[k, X + c]
                if ti.static(mission):
                    snap[at + dim] = ps[k, RAD]

    return observe_fixed, observe_metric


def _motion(mode: int, dim: int, visit_force, visit_radius, load):
    """The motion passes of a window: (adapt, move, move_rk4); `load` brings a stage
    state into slot order as it does X(s)."""
    fixed = mode == MODES["fixed"]
    mission = mode == MODES["mission"]
    X, V, RAD = columns(dim)[:3]
    R0, V0, RK, VK, U = rk_columns(dim)

    @ti.func
    def adapt(b, a0, n, c0, g, q, A: ti.template()):
        """M3's radius, paper 002 eq. 4 by the law, synchronously (reads the slot copy,
        writes rad in id order, then the copy)."""
        prm, iprm, rad, ps, cidx = ti.static(A[PRM], A[IPRM], A[RADII], A[PS], A[CIDX])
        nc = cells_across(g)
        halved = 0
        grown = 0
        for k in range(a0, a0 + n):
            r = ps[k, RAD]
            new = r
            if law.stuck(_row(ps, k, V, dim), A[MIS][k, 0], prm[b, P.STUCK2], prm[b, P.VMIN]):
                new = law.halved(r, prm[b, P.FLOOR])
                if new < r:
                    halved += 1
            else:
                new = visit_radius(k, a0, n, c0, nc[0], nc[1], nc[2], r, q, ps, A[CELL],
                                   A[CSTART], cidx, ti.static((A[PARENT],)))
                if new > r:
                    grown += 1
            rad[cidx[k]] = new
        for k in range(a0, a0 + n):
            ps[k, RAD] = rad[cidx[k]]
        iprm[b, IP.HALVED] = iprm[b, IP.HALVED] + halved
        iprm[b, IP.GROWN] = iprm[b, IP.GROWN] + grown

    @ti.func
    def control(b, k, a0, n, c0, nc, q, A: ti.template()):
        """(i, r_i, v_i, u_i) of slot k by the law (u_i of eq. 3 [and paper 002's mission
        terms]) from the slot-order copy ps (a fixed graph keeps id order: i = k)."""
        iprm, ps, cidx, mis = ti.static(A[IPRM], A[PS], A[CIDX], A[MIS])
        ptr, idx = ti.static(A[PTR], A[IDX])
        i = k
        if ti.static(not fixed):
            i = cidx[k]
        xi = _row(ps, k, X, dim)
        vi = _row(ps, k, V, dim)
        u = _full(0.0, dim)
        if ti.static(fixed):
            for e in range(ptr[i], ptr[i + 1]):
                j = idx[e]
                u = law.graph_term(u, _row(ps, j, X, dim) - xi, _row(ps, j, V, dim), vi, q[2])
        else:
            acc = visit_force(k, a0, n, c0, nc[0], nc[1], nc[2], _full(0.0, dim + 1), q,
                              ps, A[CELL], A[CSTART], cidx, ti.static((A[PARENT],)))
            u = law.control(acc, vi)
        if ti.static(mission):
            u = law.mission_control(u, vi, _row(mis, k, 1, dim), mis[k, 0],
                                    iprm[b, IP.DAMP], A[PRM][b, P.VMIN], A[PRM][b, P.CD])
        return i, xi, vi, u

    @ti.func
    def move(b, a0, n, c0, g, q, A: ti.template()):
        """X(s + 1) by semi-implicit Euler, written in id order as we go: the visits read
        only the slot-order copy, so the update stays synchronous. Returns 1 if a new state
        is not finite."""
        nc = cells_across(g)
        dt = A[PRM][b, P.DT]
        bad = 0
        for k in range(a0, a0 + n):
            i, xi, vi, u = control(b, k, a0, n, c0, nc, q, A)
            x, v = law.euler(xi, vi, u, dt)
            put(A[POS], i, x)
            put(A[VEL], i, v)
            bad |= nonfinite(x, v)
        return bad

    @ti.func
    def forces(b, a0, n, c0, g, q, A: ti.template()):
        """u_i at the state in ps into rk's U columns, in id order."""
        nc = cells_across(g)
        for k in range(a0, a0 + n):
            i, _xi, _vi, u = control(b, k, a0, n, c0, nc, q, A)
            put_at(A[RKS], i, U, u)

    @ti.func
    def move_rk4(b, s, a0, n, c0, cap, g, q, A: ti.template()):
        """X(s + 1) by RK4 (integrate.py's stage_pair / finish_pair over STAGES), the
        neighbours, cells and (M3) V_i re-evaluated at every stage: pos and vel hold the
        stage state, which `load` brings into slot order as it does X(s); r(s), v(s), the
        sums and u in rk (M3's R_i stays the step's, as on the per-step path). The four
        evaluations of u are one runtime loop (one copy of the visits to compile). Returns
        (bad, live): bad 1 if a stage or the new state is not finite; live 0 if a stage's
        swarm ran away (recorded by `load`)."""
        pos, vel, rk = ti.static(A[POS], A[VEL], A[RKS])
        h = A[PRM][b, P.DT]
        for i in range(a0, a0 + n):
            put_at(rk, i, R0, _row(pos, i, 0, dim))
            put_at(rk, i, V0, _row(vel, i, 0, dim))
            put_at(rk, i, RK, _full(0.0, dim))
            put_at(rk, i, VK, _full(0.0, dim))
        bad = 0
        live = 1
        gs = g
        for t in range(4):  # u at X(s), then at the stages after STAGES[t - 1]
            if t > 0 and bad == 0 and live == 1:
                w = ti.select(t == 1, STAGES[0][0], STAGES[1][0])
                c = h * ti.select(t == 3, STAGES[2][1], STAGES[0][1])
                for i in range(a0, a0 + n):
                    xs, vs, xk, vk = stage_pair(_row(rk, i, R0, dim), _row(rk, i, V0, dim),
                                                _row(vel, i, 0, dim), _row(rk, i, U, dim),
                                                _row(rk, i, RK, dim), _row(rk, i, VK, dim),
                                                w, c)
                    put(pos, i, xs)
                    put(vel, i, vs)
                    put_at(rk, i, RK, xk)
                    put_at(rk, i, VK, vk)
                    bad |= nonfinite(xs, vs)
                if bad == 0:
                    live, gs = load(b, s, a0, n, c0, cap, A)
            if bad == 0 and live == 1:
                forces(b, a0, n, c0, gs, q, A)
        if bad == 0 and live == 1:
            for i in range(a0, a0 + n):
                x, v = finish_pair(_row(rk, i, R0, dim), _row(rk, i, V0, dim),
                                   _row(vel, i, 0, dim), _row(rk, i, U, dim),
                                   _row(rk, i, RK, dim), _row(rk, i, VK, dim), h / 6)
                put(pos, i, x)
                put(vel, i, v)
                bad |= nonfinite(x, v)
        return bad, live

    return adapt, move, move_rk4


@cache
def advance_kernel(mode: int, dim: int = 2, rk4: bool = False):
    """The window kernel for one mode (fixed graph, switching (M2) or mission (M3)),
    dimension (2 or 3) and integrator (semi-implicit Euler or RK4)."""
    fixed = mode == MODES["fixed"]
    mission = mode == MODES["mission"]
    X, V, RAD, HC, _ = columns(dim)
    pair_radius2, visit_force, visit_radius, visit_observe, visit_closest = _pair_visits(
        mode, dim)
    observe_fixed, observe_metric = _observers(
        mode, dim, pair_radius2, visit_observe, _closest_search(dim, visit_closest))
    state_grid = _cells[dim, True]

    @ti.func
    def load(b, s, a0, n, c0, cap, A: ti.template()):
        """Replica b's prologue of step s: (live, g). The cell list of r(s) (switching, M3;
        g: replica_cells' grid vector, all pairs without one), X(s) copied into slot
        order (every visit reads it) and V_i at r(s) (M3). live 0: the swarm ran away
        (recorded here)."""
        prm, iprm, pos, vel, rad = ti.static(A[PRM], A[IPRM], A[POS], A[VEL], A[RADII])
        ps, cell, cstart, cidx = ti.static(A[PS], A[CELL], A[CSTART], A[CIDX])
        live = 1
        g = ti.Vector([0.0, 0.0, 1.0, 0.0, 0.0] + [0.0 for _ in ti.static(range(dim))],
                      dt=float)  # all pairs
        gridded = False
        if ti.static(not fixed):
            gridded = iprm[b, IP.CELLS] != 0
        if gridded:
            w0 = prm[b, P.R] * ti.static(widen())
            g = state_grid(a0, n, c0, cap, w0, 0.0, pos, cell, cstart, cidx, ())
            if g[G_NX] < 0:
                iprm[b, IP.BAD] = s
                iprm[b, IP.CAUSE] = 1
                prm[b, P.SPAN] = g[G_SPAN]
                live = 0
        else:
            for k in range(n):
                cidx[a0 + k] = a0 + k
        if live:
            hashed = g[G_NY] < 0
            w = g[G_W]
            for k in range(a0, a0 + n):
                i = cidx[k]
                for c in ti.static(range(dim)):
                    ps[k, X + c] = pos[i, c]
                    ps[k, V + c] = vel[i, c]
                if ti.static(mission):
                    ps[k, RAD] = rad[i]
                if hashed:  # each slot's exact cell
                    for c in ti.static(range(dim)):
                        ps[k, HC + c] = ti.floor((pos[i, c] - g[G_O + c]) / w)
            if ti.static(mission):  # V_i at r(s): read by all three passes of the step
                for k in range(a0, a0 + n):
                    put(A[MIS], k, navigation(b, _row(ps, k, X, dim), prm, iprm, A[OPOS],
                                              A[ORAD], A[OSTART]))
        return live, g

    @ti.func
    def observation(b, s, a0, n, c0, cap, g, q, A: ti.template()):
        """The observables of X(s) into the replica's next row of obs."""
        iprm = ti.static(A[IPRM])
        row = A[OOFF][b] + iprm[b, IP.NOBS]
        A[OBS_ROWS][row, 0] = s
        if ti.static(fixed):
            observe_fixed(b, a0, n, c0, cap, row, A[PRM], A[PS], A[PTR], A[IDX], A[CELL],
                          A[CSTART], A[CIDX], A[ARC_LO], A[ARC_HI], A[OBS_ROWS])
        else:
            nc = cells_across(g)
            observe_metric(b, a0, n, c0, nc[0], nc[1], nc[2], g[G_W], row, iprm[b, IP.NOBS],
                           q, A[PRM], iprm, A[PS], A[CELL], A[CSTART], A[CIDX], A[PARENT],
                           A[CSUM], A[ARC_LO], A[ARC_HI], A[MIS], A[OBS_ROWS], A[VAL], A[SNAP],
                           A[SBASE])
        iprm[b, IP.NOBS] = iprm[b, IP.NOBS] + 1

    adapt, move, move_rk4 = _motion(mode, dim, visit_force, visit_radius, load)

    @ti.func
    def replica(b, s0, s1, A: ti.template()):
        """Replica b from step s0 towards s1 (serially: its steps, then its agents)."""
        aoff, coff, prm, iprm = ti.static(A[AOFF], A[COFF], A[PRM], A[IPRM])
        a0 = aoff[b]
        n = aoff[b + 1] - a0
        c0 = coff[b]
        cap = coff[b + 1] - c0 - 1
        every = iprm[b, IP.EVERY]
        # (uniform R^2, inclusive, a, c) of the pair terms
        q = ti.math.vec4(prm[b, P.R2], iprm[b, IP.INCL], prm[b, P.A], prm[b, P.C])
        iprm[b, IP.SNAP0] = iprm[b, IP.NOBS]
        s = s0
        while s < s1 and s <= iprm[b, IP.STEPS] and iprm[b, IP.BAD] < 0:
            steps = iprm[b, IP.STEPS]
            live, g = load(b, s, a0, n, c0, cap, A)
            if live == 0:
                break
            if s % every == 0 or s == steps:  # an observation step
                observation(b, s, a0, n, c0, cap, g, q, A)
            if s < steps:
                if ti.static(mission):
                    # Eq. 4 at its cadence, before the step's motion.
                    if iprm[b, IP.ADAPT] and s > 0 and s % iprm[b, IP.REVERY] == 0:
                        adapt(b, a0, n, c0, g, q, A)
                if ti.static(rk4):
                    bad, live = move_rk4(b, s, a0, n, c0, cap, g, q, A)
                    if live == 0:
                        break
                    if bad != 0:
                        iprm[b, IP.BAD] = s
                elif move(b, a0, n, c0, g, q, A) != 0:
                    iprm[b, IP.BAD] = s
            s += 1

    @ti.kernel
    def advance(s0: ti.i32, s1: ti.i32, aoff: nd, coff: nd, ooff: nd, prm: nd, iprm: nd,
                pos: nd, vel: nd, rad: nd, ps: nd, cell: nd, cstart: nd, cidx: nd,
                parent: nd, csum: nd, mis: nd, arc_lo: nd, arc_hi: nd, ptr: nd, idx: nd,
                opos: nd, orad: nd, ostart: nd, obs: nd, val: nd, snap: nd, sbase: nd,
                rk: nd):
        A = ti.static((aoff, coff, ooff, prm, iprm, pos, vel, rad, ps, cell, cstart, cidx,
                       parent, csum, mis, arc_lo, arc_hi, ptr, idx, opos, orad, ostart, obs,
                       val, snap, sbase, rk))
        for t in range((aoff.shape[0] - 1) * SPREAD):
            if t % SPREAD == 0:  # one replica per CPU task
                replica(t // SPREAD, s0, s1, A)

    return advance


def _obstacle_grid(p, dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """M3's obstacles in the cells (x fastest, then y, then z) of a dense grid over their
    bounding box (cells of side obstacle_range + the largest disc radius, widened until at
    most 4 M + 16 cells): (centres, radii, cell starts, geometry) in cell order; geometry:
    the cell side w, the cell reach cap, and per dimension the origin, the cells across and
    the bounding box grown by cap (low, high)."""
    centers = np.array([*p.obstacles, *(d.center for d in p.discs)],
                       dtype=np.float64).reshape(-1, dim)
    radii = np.array([0.0] * len(p.obstacles) + [d.radius for d in p.discs])
    m = len(centers)
    cap = p.obstacle_range + (float(radii.max()) if m else 0.0)
    if m == 0:  # an empty box: no agent is ever inside
        geo = dict(origin=[0.0] * dim, w=1.0, cells=[1] * dim, low=[0.0] * dim,
                   high=[-1.0] * dim, cap=cap)
        return centers, radii, np.zeros(2, dtype=np.int64), geo
    lo, hi = centers.min(axis=0), centers.max(axis=0)
    w = cap * widen()
    while (np.floor((hi - lo) / w) + 1).prod() > 4 * m + 16:
        w *= 2.0
    cells = [int(k) for k in np.floor((hi - lo) / w) + 1]
    key = np.zeros(m, dtype=np.int64)
    for c in reversed(range(dim)):
        at = np.minimum(np.floor((centers[:, c] - lo[c]) / w).astype(np.int64), cells[c] - 1)
        key = key * cells[c] + at
    order = np.argsort(key, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=int(np.prod(cells))))])
    geo = dict(origin=list(lo), w=w, cells=cells, low=list(lo - cap), high=list(hi + cap),
               cap=cap)
    return centers[order], radii[order], start, geo


def lambda2_rows(pos: np.ndarray, radii: np.ndarray | float, own: bool, inclusive: bool,
                 components: np.ndarray, max_agents: int) -> np.ndarray:
    """lambda_2 of the proximity graph of each snapshot (rows, N, dim), as the per-step path
    computes it (`observe.algebraic_connectivity`): 0 when disconnected; at
    N <= 32 the same dense eigvalsh, stacked over the rows."""
    rows, n = pos.shape[:2]
    out = np.zeros(rows)
    if n < 2 or rows == 0:
        return out
    if n > fo.DENSE_EIG_MAX:
        for t in range(rows):
            if components[t] > 1:
                continue
            r = radii[t] if own else radii
            u, v = fo.proximity_edges(pos[t], r, "own" if own else "min", inclusive)
            out[t] = fo.algebraic_connectivity(fo.graph_matrix(n, u, v), int(components[t]),
                                               max_agents)
        return out
    d = pos[:, None, :, :] - pos[:, :, None, :]
    s2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]
    if pos.shape[2] == 3:
        s2 = s2 + d[..., 2] * d[..., 2]
    if own:
        r2 = np.maximum(radii[:, :, None], radii[:, None, :]) ** 2
    else:
        r2 = float(radii) ** 2
    adj = (s2 <= r2) if inclusive else (s2 < r2)
    adj &= ~np.eye(n, dtype=bool)
    lap = np.eye(n) * adj.sum(axis=2)[:, :, None] - adj
    lam = np.maximum(np.linalg.eigvalsh(lap)[:, 1], 0.0)
    return np.where(components > 1, 0.0, lam)


class FlockingBatch(FusedBatch):
    """The state of a batch of M2 or M3 replicas (any N, graph, radius, obstacles, steps
    each; one mode: fixed graph, switching, or M3; one dimension: 2 or 3),
    advanced window by window by `advance_kernel`."""

    dimensions = (2, 3)

    def __init__(self, scenarios: list[Scenario]):
        from ...space.initial import initial_state

        self.scenarios = scenarios
        first = scenarios[0]
        self.kind = first.model.kind
        self.mode = ("mission" if self.kind == "flocking_obstacles"
                     else first.model.topology)
        fixed, mission = self.mode == "fixed", self.mode == "mission"
        self.dim = dim = first.dimension
        rk4 = first.model.integrator == "rk4"
        self.kernel = advance_kernel(MODES[self.mode], dim, rk4)
        B = len(scenarios)
        ns = [s.n_agents for s in scenarios]
        rows = observation_rows(scenarios)
        self.aoff, self.ooff = offsets(ns), offsets(rows)
        self.coff = cell_offsets(ns, 4)
        total = int(self.aoff[-1])
        prm = np.zeros((B, P.size))
        iprm = np.zeros((B, IP.size), dtype=np.int32)
        pos, vel = np.zeros((total, dim)), np.zeros((total, dim))
        rad = np.zeros(total)
        ptr, idx = [np.zeros(1, dtype=np.int64)], []
        opos, orad, ostart = [], [], []
        n_obst, n_ocell = 0, 0
        self.vper, self.vwidth, voff = [], [], 0
        self.graph_info, self.graph_obs = [], []
        self.snap = []
        for b, sc in enumerate(scenarios):
            p = sc.model
            n = ns[b]
            a0 = int(self.aoff[b])
            init = initial_state(sc)
            pos[a0:a0 + n], vel[a0:a0 + n] = init.positions, init.velocities
            a, c = p.potential.coefficients()
            radius = sc.neighbours.radius if not fixed else 0.0
            rad[a0:a0 + n] = radius
            prm[b, [P.DT, P.A, P.C, P.R, P.R2]] = [sc.time.dt, a, c, radius, radius * radius]
            vper = n <= p.valency_per_agent_max
            self.vper.append(vper)
            self.vwidth.append(n if vper else HIST)
            iprm[b, [IP.STEPS, IP.EVERY, IP.BAD, IP.CELLS, IP.INCL, IP.VPER, IP.VOFF]] = [
                sc.time.steps, sc.recording.observables_every, -1,
                int(not fixed and not p.uses_all_pairs(n)),
                int(sc.inclusive) if not fixed else 0, int(vper), voff]
            if not fixed:
                voff += rows[b] * self.vwidth[b]
            # lambda_2 from snapshots, when N allows it and the scenario asks for it.
            snap = not fixed and n <= p.lambda2_max_agents and sc.recording.wants("lambda2")
            self.snap.append(snap)
            iprm[b, IP.SNAP] = int(snap)
            if fixed:
                u, v = build_edges(p.graph, n, sc.seed)
                indptr, indices = to_csr(n, u, v)
                e0 = int(ptr[-1][-1])
                ptr.append(e0 + indptr[1:].astype(np.int64))
                idx.append(a0 + indices.astype(np.int64))
                adj = fo.graph_matrix(n, u, v)
                n_comp = fo.components(adj)
                lam = fo.algebraic_connectivity(adj, n_comp, p.lambda2_max_agents)
                self.graph_info.append({"edges": len(u), "components": n_comp,
                                        "lambda2": lam})
                self.graph_obs.append({"components": float(n_comp), "lambda2": lam,
                                       **fo.valency_stats(np.diff(indptr),
                                                          p.valency_per_agent_max)})
            elif not mission:
                # 1/2 sum_i sum_{j != i} V(R), the constant part of Q (eq. 10)
                prm[b, P.QC] = 0.5 * n * (n - 1) * p.potential.value(radius)
            if mission:
                cen, orr, start, geo = _obstacle_grid(p, dim)
                prm[b, [P.CD, P.VMIN, P.STUCK2, P.FLOOR]] = [
                    p.c_d, p.V_min, p.stuck_speed**2, p.radius_floor]
                lam_nav = (p.obstacle_range**2 + 1.0) / p.obstacle_range**2
                prm[b, [P.RANGE, P.LAMBDA, P.KAPPA, P.OW, P.OCAP]] = [
                    p.obstacle_range, lam_nav, p.kappa, geo["w"], geo["cap"]]
                for slots, values in ((DEST, p.destination), (OORIGIN, geo["origin"]),
                                      (OLOW, geo["low"]), (OHIGH, geo["high"])):
                    prm[b, list(slots[:dim])] = values
                iprm[b, IP.ONZ] = 1  # 2D: one plane
                iprm[b, list(OCELLS[:dim])] = geo["cells"]
                iprm[b, [IP.REVERY, IP.ADAPT, IP.DAMP, IP.OCOFF, IP.OM]] = [
                    p.radius_every, int(p.adaptive_radius), DAMPING[p.damping_region],
                    n_ocell, len(cen)]
                opos.append(cen)
                orad.append(orr)
                ostart.append(n_obst + start)
                n_obst += len(cen)
                n_ocell += len(start)
        self.B, self.total, self.rows = B, total, rows
        # lambda_2 snapshots of (r, R_i).
        self.snaps = Snapshots(ns, rows, self.snap,
                               [s.recording.observables_every for s in scenarios], dim + 1,
                               SNAP_DOUBLES)
        self.lam = [np.zeros(r) for r in rows]

        def arr(a: np.ndarray, dtype=float) -> ti.Ndarray:
            a = runtime.as_real(a) if dtype is float else np.ascontiguousarray(a)
            out = ti.ndarray(dtype, shape=a.shape)
            out.from_numpy(a)
            return out

        def scratch(shape, dtype=float) -> ti.Ndarray:
            return ti.ndarray(dtype, shape=shape)

        i32 = ti.i32

        def cat(parts, shape, dtype):
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype)

        ptr_all = np.concatenate(ptr) if fixed else np.zeros(1)
        self.args = dict(
            aoff=arr(self.aoff, i32), coff=arr(self.coff, i32), ooff=arr(self.ooff, i32),
            prm=arr(prm), iprm=arr(iprm, i32), pos=arr(pos), vel=arr(vel), rad=arr(rad),
            ps=scratch((total, columns(dim)[-1])), cell=scratch(total, i32),
            cstart=scratch(int(self.coff[-1]), i32), cidx=scratch(total, i32),
            parent=scratch(total, i32), csum=scratch((total, dim + 1)),
            mis=scratch((total if mission else 1, dim + 2)), arc_lo=scratch(total),
            arc_hi=scratch(total), ptr=arr(ptr_all.astype(np.int32), i32),
            idx=arr(cat(idx, 1, np.int32), i32),
            opos=arr(np.concatenate(opos) if n_obst else np.zeros((1, dim))),
            orad=arr(np.concatenate(orad) if n_obst else np.zeros(1)),
            ostart=arr(cat(ostart, 1, np.int32), i32),
            obs=arr(np.zeros((int(self.ooff[-1]), N_OBS))),
            val=arr(np.zeros(max(voff, 1), dtype=np.int32), i32),
            snap=scratch(max(int(self.snaps.base[-1]), 1)), sbase=arr(self.snaps.base, i32),
            rk=scratch((total if rk4 else 1, 5 * dim)),
        )
        assert tuple(self.args) == ARRAYS

    CHECKPOINTS = True  # `args` and lambda_2's rows (`save_host`) are the whole state

    def save_host(self) -> dict[str, np.ndarray]:
        return {f"lambda2/{b}": lam.copy() for b, lam in enumerate(self.lam)}

    def load_host(self, state) -> None:
        self.lam = [state[f"lambda2/{b}"].copy() for b in range(self.B)]

    def advance(self, s0: int, s1: int) -> None:
        """Advance every replica from step s0 towards s1 (each stops at its own end), in
        launches of at most `chunk` steps while lambda_2 snapshots are taken."""
        self.invalidate()
        for a, z in self.snaps.launches(s0, s1):
            self.kernel(a, z, *(self.args[k] for k in ARRAYS))
            if self.snaps.chunk is not None:
                self._lambda2()

    def _lambda2(self) -> None:
        """lambda_2 of the observations the last launch took (rows SNAP0 .. NOBS)."""
        iprm = self.status()
        snap = self.args["snap"].to_numpy()
        obs = self.args["obs"].to_numpy()
        for b, r0, r1, s in self.snaps.taken(snap, iprm[:, IP.SNAP0], iprm[:, IP.NOBS]):
            sc = self.scenarios[b]
            comps = obs[self.ooff[b] + r0:self.ooff[b] + r1, COL["components"]]
            own = self.mode == "mission"
            radii = s[:, :, self.dim] if own else sc.neighbours.radius
            self.lam[b][r0:r1] = lambda2_rows(s[:, :, :self.dim], radii, own, sc.inclusive,
                                              comps, sc.model.lambda2_max_agents)

    def observables(self, b: int, iprm: np.ndarray) -> dict[str, np.ndarray]:
        """The per-step path's series, in its order (kernel.py, obstacles.py), of the
        observables replica b's recording.observables names."""
        wants = self.scenarios[b].recording.wants
        return {k: v for k, v in self._series(b, iprm).items() if k == "step" or wants(k)}

    def _series(self, b: int, iprm: np.ndarray) -> dict[str, np.ndarray]:
        """Every observable of replica b (observations taken so far)."""
        nobs = int(iprm[b, IP.NOBS])
        o0 = self.ooff[b]
        rows = self.host("obs")[o0:o0 + nobs]
        col = {k: rows[:, COL[k]] for k in OBS}
        out = {"step": col["step"], **{k: col[k] for k in velocity_keys(self.dim)}}
        closest = {k: col[k] for k in ("min_distance", "min_pair_i", "min_pair_j")}
        if self.mode == "fixed":
            out["W"] = col["energy"]
            g = self.graph_obs[b]
            out.update({k: np.full(nobs, v) for k, v in g.items()})
            out.update(closest)
            return out
        out["Q_reduced"] = col["energy"]
        out["Q"] = col["energy"] + col["q_constant"]
        out["components"] = col["components"]
        out.update({k: col[k] for k in ("valency_mean", "valency_min", "valency_max")})
        n, w = self.scenarios[b].n_agents, self.vwidth[b]
        v0 = int(iprm[b, IP.VOFF])
        val = self.host("val")[v0:v0 + nobs * w].reshape(nobs, w)
        val = val.astype(np.float64)
        if self.vper[b]:
            out.update({f"valency_{i}": val[:, i] for i in range(n)})
        else:
            out.update({f"valency_hist_{k}": val[:, k] for k in range(fo.HIST_BINS)})
            out[f"valency_hist_{fo.HIST_BINS}plus"] = val[:, fo.HIST_BINS]
        out.update(closest)
        out["lambda2"] = (self.lam[b][:nobs] if self.snap[b]
                          else np.full(nobs, fo.NOT_COMPUTED))
        if self.mode == "mission":
            out.update({k: col[k] for k in MISSION_KEYS})
        return out

    def frame(self, b: int, arrays: list[str], step: int) -> dict[str, np.ndarray]:
        a0, a1 = self.aoff[b], self.aoff[b + 1]
        return point_mass_frame(lambda: self.host("pos")[a0:a1],
                                lambda: self.host("vel")[a0:a1], arrays, self.dim)

    def convergence_keys(self) -> list[str]:
        return (["velocity_disagreement_components"] if self.mode == "mission"
                else ["velocity_disagreement"])

    def extra(self, b: int, iprm: np.ndarray) -> dict[str, Any]:
        """closest_approach (the first closest observation), the fixed graph, and M3's
        radius halvings and increases, as the per-step path reports them."""
        obs = self._series(b, iprm)
        closest: dict[str, Any] = {}
        if len(obs["step"]):
            t = int(np.argmin(obs["min_distance"]))
            closest = {"distance": float(obs["min_distance"][t]),
                       "pair": [int(obs["min_pair_i"][t]), int(obs["min_pair_j"][t])],
                       "time": float(obs["step"][t]) * self.scenarios[b].time.dt}
        out: dict[str, Any] = {"closest_approach": closest}
        if self.mode == "fixed":
            out["graph"] = self.graph_info[b]
        if self.mode == "mission":
            out["adaptive_radius"] = {"halvings": int(iprm[b, IP.HALVED]),
                                      "increases": int(iprm[b, IP.GROWN])}
        return out

    def divergence(self, b: int, iprm: np.ndarray) -> tuple[int, str, str] | None:
        """(step, quantity, cause) in the per-step path's words, or None."""
        step = int(iprm[b, IP.BAD])
        if step < 0:
            return None
        if iprm[b, IP.CAUSE] == 0:
            return step, "position/velocity", DIVERGED_CAUSE
        span = float(self.args["prm"].to_numpy()[b, P.SPAN])
        if not np.isfinite(span):
            return step, "position", "a position became non-finite"
        return step, "position", runaway_cause(span, self.dim)

    @staticmethod
    def batch_key(scenario: Scenario) -> tuple | None:
        """Scenarios with the same key share a launch; None (the per-step path) for M3's
        radius_rule "min"."""
        p = scenario.model
        if p.kind == "flocking_obstacles":
            own = p.radius_rule == "own"
            return ("flocking_obstacles", scenario.dimension, p.integrator) if own else None
        return ("flocking", p.topology, scenario.dimension, p.integrator)
