"""M1 on the small-N path: many steps of many replicas in one kernel launch.

The rule is the one `kernels/models/vicsek/step.py` documents (paper 001, eq. 1-2, 17-18,
22; Vicsek et al. 1995); only the schedule differs. At small N a step costs microseconds of
arithmetic but milliseconds of launches and host round trips, so here one launch advances every
replica of a batch through a whole window of steps: replicas run in parallel (one per
CPU task), each replica's steps and agents serially inside, the state never leaves the
kernel's arrays, and the observables go into a per-replica buffer row by row. The host
comes back only at frame, progress and cancellation points, which never changes a bit:
a replica computes the same numbers alone, in a batch, or cut into any windows.

Per replica and step s (state X(s) in agent-id order):
  1. a cell list of X(s): cells of side >= r (a hair wider), counted, scanned and filled
     in id order (so every neighbour sum has one fixed order); the periodic box uses
     floor(L / r) cells across, the plane a grid over the bounding box; fewer than three
     cells across, or N <= ALL_PAIRS_N, visits all pairs instead;
  2. the closed-neighbourhood sums of the rule over the 3x3 (3D: 3x3x3) block (minimum
     image), the new heading with its noise (2D: xi = eta (u - 1/2), u = hash(seed, step,
     id); 3D: the turn into the spherical cap of `kernel.cap_turn`, streams 0 and 1), and
     the move; on an observation step the same visit gives the degrees and the components;
  3. commit X(s+1). A non-finite value stops the replica and records the step.
The dimension is a compile-time parameter: 2D compiles to the code it was before 3D.
"""


from functools import cache
from typing import Any

import numpy as np
import taichi as ti

from flocklab.schemas import PeriodicBox, Scenario, VicsekParams

from ... import runtime
from ...replicas import FusedBatch, host_array
from ...space import rng
from ...space.cells import SPREAD
from ...space.graph import find, link, union_serial
from ...space.grid import widen
from ...space.observables import make_circular_spread
from ...space.params import Slots
from ...space.replica_cells import G_NX, G_NY, G_NZ, G_O, G_W, make_replica_cells
from ...space.replica_loop import cell_offsets, observation_rows, offsets
from .law import RULES, agent_step

nd = ti.types.ndarray()
ALL_PAIRS_N = 48  # at or below this N every pair is tested (fewer operations than cells)

# Per-replica parameter slots: prm (f64) and iprm (i32).
P = Slots("R2", "V0DT", "ETA", "G", "L", "THETA0", "RADIUS", "CAP")
IP = Slots("STEPS", "EVERY", "TRACK", "NOBS", "BAD", "LINKED", "LONGEST", "OPEN", "CAUSE",
           "MOVE_NEW", "WANT_COMPONENTS", "WANT_SPREAD")
# Why a replica stopped (iprm[IP.CAUSE]), as the per-step path words it.
CAUSES = (
    ("heading/position",
     "non-finite input (v0 * dt or the initial state too large for float64)"),
    ("position", "the swarm spans over 2^30 neighbour radii (2^14 in float32; agents "
                 "escaping: dt too large or forces unbounded), or a position became "
                 "non-finite"),
)
# Observable columns, in the order the per-step path reports them.
OBS = ("step", "polarization", "heading_spread", "leader_error", "components",
       "degree_mean", "degree_min", "degree_max", "isolated", "linked_intervals")
N_OBS = len(OBS)
# The batch's arrays, in the kernels' argument order.
ARRAYS = ("aoff", "coff", "ooff", "prm", "iprm", "kseed", "pos", "ew", "theta", "ps", "cell",
          "cstart", "cidx", "parent", "parent_u", "deg", "arc_lo", "arc_hi", "obs")
# How a visit joins the graph's edges into the union-find forests: not at all, serially
# (one thread a replica: the fused schedule) or atomically (the batched one).
NO_LINKS, SERIAL, ATOMIC = 0, 1, 2


@ti.func
def _key(kseed, step):
    """rng.step_key(seed, stream, step), with the (seed, stream) part precomputed on the
    host."""
    return rng._mix(kseed ^ rng._mix(ti.cast(step, ti.u32)))



@ti.func
def union_atomic(parent: ti.template(), u, v):
    """Join the trees of u and v while other threads join other edges of the forest."""
    ru = find(parent, u)
    rv = find(parent, v)
    if ru != rv:
        link(parent, ru, rv)


def _tracks(scenario: Scenario) -> bool:
    """Whether the run tracks Theorem 2's linked intervals (`tracks_linked`)."""
    return scenario.model.tracks_linked(  # type: ignore[union-attr]
        scenario.n_agents, scenario.recording.observables)
def _vec(dim: int):
    """`vec(x)`: the dim-vector (x, ..., x)."""

    @ti.func
    def vec(x):
        """The dim-vector (x, ..., x), typed when the kernel compiles: a vector type made
        here would keep the float width of the runtime that first called this factory
        (a float32 run's, cached for every later float64 one)."""
        return ti.Vector([x for _ in ti.static(range(dim))])

    return vec


def _slots(rule: int, dim: int):
    """(place, reach): an agent's state into its slot as the cell list lands it, and the
    neighbour cells a slot can reach."""
    vicsek = rule == RULES["vicsek"]
    W = 2 * dim  # ps's stride: slot k's state at k * W .. k * W + W - 1

    @ti.func
    def load(k, i, pos: ti.template(), ew: ti.template(), theta: ti.template(),
             ps: ti.template(), parent: ti.template()):
        """Agent i's state X(s) into slot k of ps: (x, y, e_x, e_y) (3D: (x, y, z, e_x, e_y,
        e_z)), or (x, y, theta, 0) for the JLM rules; and i as its own root of the
        components."""
        for c in ti.static(range(dim)):
            ps[k * W + c] = pos[i, c]
        if ti.static(vicsek):
            for c in ti.static(range(dim)):
                ps[k * W + dim + c] = ew[i, c]
        else:
            ps[k * W + 2] = theta[i]
            ps[k * W + 3] = 0.0
        parent[i] = i

    @ti.func
    def place(k, i, S: ti.template()):
        pos, ew, theta, ps, parent = ti.static(S[0], S[1], S[2], S[3], S[4])
        load(k, i, pos, ew, theta, ps, parent)

    @ti.func
    def reach(k, cc, grid, far, ps: ti.template()):
        """(lo, hi): the neighbour cells' offsets along each axis that slot k (in cell cc)
        can reach, -1 .. 1 but 0 on a side whose cells lie all farther than `far` (> r)
        from it. Dropping them drops only zero terms from the sums, so the bits stay
        those of the whole 3x3 (3x3x3) block, with 13-25% fewer pairs tested at the
        sweeps' densities (cells 1.11-1.25 r wide)."""
        lo = ti.math.ivec3(0)
        hi = ti.math.ivec3(0)
        w = grid[G_W]
        for c in ti.static(range(dim)):
            u = ps[k * W + c] - grid[G_O + c] - cc[c] * w  # offset in its cell (NaN: keep all)
            lo[c] = ti.select(u > far, 0, -1)
            hi[c] = ti.select(w - u > far, 0, 1)
        return lo, hi

    return place, reach


def _sums(periodic: bool, dim: int):
    """`sums`: a slot's closed-neighbourhood sums over its block of cells (or every slot),
    the graph's edges joined on the way when asked."""
    W = 2 * dim
    vec = _vec(dim)

    @ti.func
    def add(k, m, d, a, r2, links: ti.template(), ps: ti.template(), cidx: ti.template(),
            parent: ti.template(), parent_u: ti.template(), graph, track):
        """Slot m's term in slot k's closed-neighbourhood sum when |d| is within r. Sums
        stay in registers: a store per pair (a symmetric half visit) cost 8x more, and
        the visit without links has no store at all (a store in the loop makes every
        array access reload its base and shape)."""
        # r2 is the strict threshold: r^2 itself for "<", the next double above it for
        # "<=" (no double lies between), so one compiled test serves both.
        w = ti.cast(d.dot(d) < r2, float)  # branch-free: 1 or 0
        if ti.static(links != NO_LINKS):
            if w > 0.0 and m > k:  # each edge once
                if ti.static(links == SERIAL):
                    if graph:
                        union_serial(parent, cidx[k], cidx[m])
                    if track:
                        union_serial(parent_u, cidx[k], cidx[m])
                else:  # other threads join other edges of the same forests meanwhile
                    if graph:
                        union_atomic(parent, cidx[k], cidx[m])
                    if track:
                        union_atomic(parent_u, cidx[k], cidx[m])
        # (e_m, 1) for the vicsek rule, (theta_m, 0, 1) for the JLM rules (2D).
        return a + w * ti.Vector([ps[m * W + dim + c] for c in ti.static(range(dim))] + [1.0])

    @ti.func
    def run(k, lo, hi, sh, a, r2, links: ti.template(), ps: ti.template(),
            cidx: ti.template(), parent: ti.template(), parent_u: ti.template(), graph,
            track):
        """Slots lo .. hi, whose periodic image beside slot k is r_m + sh:
        d = r_m - (r_k - sh)."""
        xs = vec(0.0)
        for c in ti.static(range(dim)):
            xs[c] = ps[k * W + c] - sh[c]
        for m in range(lo, hi):
            d = vec(0.0)
            for c in ti.static(range(dim)):
                d[c] = ps[m * W + c] - xs[c]
            a = add(k, m, d, a, r2, links, ps, cidx, parent, parent_u, graph, track)
        return a

    @ti.func
    def sums(k, cc, lo, hi, a0, n, c0, nc, Lb, r2, links: ti.template(), graph, track,
             ps: ti.template(), cstart: ti.template(), cidx: ti.template(),
             parent: ti.template(), parent_u: ti.template()):
        """(sum of the terms, count) over slot k's closed neighbourhood (k in cell cc of
        the nc cells across): every slot (minimum image) without a grid, else the 3x3
        (3x3x3) block of cells around it, offsets lo .. hi along each axis (`reach`);
        periodic images are shifted by +-L per run of slots, never tested per pair."""
        a = ti.Vector.zero(float, dim + 1)
        cx, cy, cz = cc[0], cc[1], cc[2]
        nx, ny, nz = nc[0], nc[1], nc[2]
        if nx == 0:
            for m in range(a0, a0 + n):
                d = vec(0.0)
                for c in ti.static(range(dim)):
                    d[c] = ps[m * W + c] - ps[k * W + c]
                if ti.static(periodic):
                    d -= Lb * ti.round(d / Lb)
                a = add(k, m, d, a, r2, links, ps, cidx, parent, parent_u, graph, track)
        else:
            # Each row of the 3x3 block is one contiguous run of slots (cells cx-1 .. cx+1,
            # clipped to the row) plus, across a periodic seam, the wrapped cell's run,
            # shifted by -+L. A runtime loop over the rows keeps the inlined code small:
            # Taichi re-reads a kernel's Python AST at every process start.
            lo_c = ti.max(cx + lo[0], 0)
            hi_c = ti.min(cx + hi[0], nx - 1)
            wc = 0
            sx = 0.0
            wrapped = 0
            if ti.static(periodic):
                if cx == 0 and lo[0] < 0:
                    wc, sx, wrapped = nx - 1, -Lb, 1
                elif cx == nx - 1 and hi[0] > 0:
                    wc, sx, wrapped = 0, Lb, 1
            # 2D: one plane (dz = 0); 3D: the planes cz - 1 .. cz + 1, wrapped alike.
            for dz in range(lo[2], hi[2] + 1):
                qz = cz + dz
                sz = 0.0
                plane_ok = 1
                if ti.static(dim == 3):
                    if ti.static(periodic):
                        if qz < 0:
                            qz += nz
                            sz = -Lb
                        elif qz >= nz:
                            qz -= nz
                            sz = Lb
                    else:
                        plane_ok = ti.cast(qz >= 0 and qz < nz, ti.i32)
                for dy in range(lo[1], hi[1] + 1):
                    qy = cy + dy
                    sy = 0.0
                    row_ok = plane_ok
                    if ti.static(periodic):
                        if qy < 0:
                            qy += ny
                            sy = -Lb
                        elif qy >= ny:
                            qy -= ny
                            sy = Lb
                    else:
                        row_ok = ti.cast(plane_ok != 0 and qy >= 0 and qy < ny, ti.i32)
                    if row_ok:
                        row = c0 + nx * qy
                        sh = vec(0.0)
                        sh[1] = sy
                        if ti.static(dim == 3):
                            row += nx * ny * qz
                            sh[2] = sz
                        a = run(k, a0 + cstart[row + lo_c], a0 + cstart[row + hi_c + 1], sh,
                                a, r2, links, ps, cidx, parent, parent_u, graph, track)
                        if wrapped:
                            sh[0] = sx
                            a = run(k, a0 + cstart[row + wc], a0 + cstart[row + wc + 1], sh,
                                    a, r2, links, ps, cidx, parent, parent_u, graph, track)
        return a

    return sums


def _observation(rule: int, full: bool, dim: int):
    """(observe, close_linked): a replica's observables of X(s), and Theorem 2's
    intervals."""
    vicsek = rule == RULES["vicsek"]
    W = 2 * dim
    vec = _vec(dim)

    @ti.func
    def heading_vector(ps: ti.template(), k):
        """e(theta) of slot k: stored (vicsek rule) or from the angle (JLM rules)."""
        e = vec(0.0)
        if ti.static(vicsek):
            for c in ti.static(range(dim)):
                e[c] = ps[k * W + dim + c]
        else:
            e = ti.math.vec2(ti.cos(ps[k * W + 2]), ti.sin(ps[k * W + 2]))
        return e

    @ti.func
    def sphere_spread(a0, n, sm, ps: ti.template()):
        """3D: twice the largest angle between a heading and the mean heading sm / |sm| (0
        when all are aligned; 2 pi when the headings cancel), as the per-step path."""
        res = 2.0 * ti.math.pi
        nrm = sm.norm()
        if nrm > 0.0:
            least = ti.math.inf
            for k in range(a0, a0 + n):
                least = ti.min(least, heading_vector(ps, k).dot(sm / nrm))
            res = 2.0 * ti.acos(ti.min(1.0, ti.max(-1.0, least)))
        return res

    @ti.func
    def heading_angle(k, S: ti.template()):
        """theta of slot k from its unit vector (the vicsek rule, 2D)."""
        ps = ti.static(S[0])
        return ti.atan2(ps[k * W + 3], ps[k * W + 2])

    # 2 pi minus the largest gap between the headings (kernels/space/observables.py).
    circular_spread = make_circular_spread(heading_angle)

    @ti.func
    def observe(b, a0, n, s, row, ps: ti.template(), parent: ti.template(),
                deg: ti.template(), arc_lo: ti.template(),
                arc_hi: ti.template(), prm: ti.template(), iprm: ti.template(),
                obs: ti.template()):
        """Observables of X(s) (ps: slot order) into obs[row]: the columns of OBS."""
        sm = vec(0.0)
        for k in range(a0, a0 + n):
            sm += heading_vector(ps, k)
        nrm2 = sm[0] * sm[0] + sm[1] * sm[1]
        if ti.static(dim == 3):
            nrm2 += sm[2] * sm[2]
        obs[row, 0] = s
        obs[row, 1] = ti.sqrt(nrm2) / n
        spread = ti.math.nan  # not asked for (recording.observables)
        if ti.static(full):
            if iprm[b, IP.WANT_SPREAD] == 0:
                pass
            elif ti.static(dim == 3):
                spread = sphere_spread(a0, n, sm, ps)
            elif ti.static(vicsek):
                spread = circular_spread(a0, n, arc_lo, arc_hi, ti.static((ps,)))
            else:
                lo = ti.math.inf
                hi = -ti.math.inf
                for k in range(a0, a0 + n):
                    lo = ti.min(lo, ps[k * W + 2])
                    hi = ti.max(hi, ps[k * W + 2])
                spread = hi - lo
        obs[row, 2] = spread
        if ti.static(rule == RULES["leader"]):
            err = 0.0
            for k in range(a0, a0 + n):
                err = ti.max(err, ti.abs(ps[k * W + 2] - prm[b, P.THETA0]))
            obs[row, 3] = err
        roots = 0
        dsum = 0
        dmin = 2**30
        dmax = 0
        iso = 0
        for k in range(a0, a0 + n):
            if parent[k] == k:  # parent is indexed by agent, deg by slot: both whole sets
                roots += 1
            dsum += deg[k]
            dmin = ti.min(dmin, deg[k])
            dmax = ti.max(dmax, deg[k])
            if deg[k] == 0:
                iso += 1
        obs[row, 4] = roots
        obs[row, 5] = ti.cast(dsum, float) / n
        obs[row, 6] = dmin
        obs[row, 7] = dmax
        obs[row, 8] = iso
        obs[row, 9] = iprm[b, IP.LINKED]

    @ti.func
    def close_linked(b, a0, n, s, parent_u: ti.template(), iprm: ti.template()):
        """Theorem 2: once the union of G(open) .. G(s) is connected, an interval of
        "linked together" graphs closes at s + 1 and the next one opens there."""
        roots = 0
        for i in range(a0, a0 + n):
            if parent_u[i] == i:
                roots += 1
        if roots == 1:
            iprm[b, IP.LINKED] = iprm[b, IP.LINKED] + 1
            iprm[b, IP.LONGEST] = ti.max(iprm[b, IP.LONGEST], s + 1 - iprm[b, IP.OPEN])
            iprm[b, IP.OPEN] = s + 1
            for i in range(a0, a0 + n):
                parent_u[i] = i

    return observe, close_linked


def _update(rule: int, periodic: bool, dim: int, vectorial: bool):
    """`update`: an agent from its sums to X(s + 1) by the law."""
    vicsek = rule == RULES["vicsek"]
    W = 2 * dim
    vec = _vec(dim)
    law = agent_step(rule, periodic, dim, True, vectorial)

    @ti.func
    def update(b, i, k, a0, acc, key0, key1, move_new, prm: ti.template(),
               ps: ti.template(), pos: ti.template(), ew: ti.template(), theta: ti.template()):
        """Agent i (slot k) from its closed-neighbourhood sums to X(s + 1) by the law;
        1 if the result is not finite. key0, key1: step s's keys of noise streams 0 and
        1 (made once per step, not per agent)."""
        e = vec(0.0)  # e(theta_i(s))
        xk = vec(0.0)
        for c in ti.static(range(dim)):
            e[c] = ew[i, c]
            xk[c] = ps[k * W + c]
        q = ti.Vector([prm[b, P.V0DT], prm[b, P.ETA], prm[b, P.G], prm[b, P.L],
                       prm[b, P.THETA0], prm[b, P.CAP]])
        x, e_new, new, bad = law(ps[k * W + 2], xk, e, acc, i - a0, key0, key1, q, move_new)
        for c in ti.static(range(dim)):
            pos[i, c] = x[c]
            ew[i, c] = e_new[c]
        if ti.static(not vicsek):
            theta[i] = new
        return bad

    return update


def _steps(rule: int, periodic: bool, full: bool, dim: int, vectorial: bool):
    """(begin, slot, end, replica): a replica's step in its three parts (prologue, one
    slot, epilogue), and its steps of a window serially."""
    place, reach = _slots(rule, dim)
    build_cells = make_replica_cells(dim, periodic, min_n=ALL_PAIRS_N, reciprocal=True,
                                     place=place)
    sums = _sums(periodic, dim)
    observe, close_linked = _observation(rule, full, dim)
    update = _update(rule, periodic, dim, vectorial)

    # The arrays every step reads, as one compile-time tuple (its order: ARRAYS).
    (AOFF, COFF, OOFF, PRM, IPRM, KSEED, POS, EW, THETA, PS, CELL, CSTART, CIDX, PARENT,
     PARENT_U, DEG, ARC_LO, ARC_HI, OBS) = range(len(ARRAYS))

    @ti.func
    def begin(b, s, A: ti.template()):
        """Replica b's prologue of step s: (live, grid, far). live 0: it is past its end,
        stopped, or its swarm ran away (recorded here); grid: `build_cells`' result for
        X(s); far: the distance from a cell's side beyond which nothing is within r."""
        aoff, coff, prm, iprm = ti.static(A[AOFF], A[COFF], A[PRM], A[IPRM])
        a0 = aoff[b]
        n = aoff[b + 1] - a0
        c0 = coff[b]
        live = 0
        grid = ti.Vector.zero(float, G_O + dim)
        far = 0.0
        if s <= iprm[b, IP.STEPS] and iprm[b, IP.BAD] < 0:
            radius = prm[b, P.RADIUS]
            grid = build_cells(a0, n, c0, coff[b + 1] - c0 - 1, radius * ti.static(widen()),
                               prm[b, P.L], A[POS], A[CELL], A[CSTART], A[CIDX],
                               ti.static((A[POS], A[EW], A[THETA], A[PS], A[PARENT])))
            # Farther than this from a cell's side, no agent across it is within r,
            # whatever the rounding of cells and distances (float32 included).
            far = radius * 1.001 + 1e-5 * grid[G_W] * ti.max(grid[G_NX], grid[G_NY],
                                                              grid[G_NZ])
            for c in ti.static(range(dim)):
                far += 1e-5 * ti.abs(grid[G_O + c])
            if grid[G_NX] < 0.0:
                iprm[b, IP.BAD] = s
                iprm[b, IP.CAUSE] = 1
            else:
                live = 1
        return live, grid, far

    @ti.func
    def slot(b, s, k, cc, grid, far, union: ti.template(), A: ti.template()):
        """Slot k (in cell cc) of replica b at step s: its closed-neighbourhood sums, its
        degree, and (s before the end) its agent's X(s + 1), written over X(s) in id order:
        the visit reads only the slot-order copy, so the update stays synchronous. The
        graph's edges are joined serially (one thread a replica) or atomically (`union`).
        Returns 1 if the new state is not finite."""
        aoff, coff, prm, iprm, kseed = ti.static(A[AOFF], A[COFF], A[PRM], A[IPRM],
                                                 A[KSEED])
        ps, cstart, cidx, parent, parent_u = ti.static(A[PS], A[CSTART], A[CIDX], A[PARENT],
                                                       A[PARENT_U])
        a0 = aoff[b]
        n = aoff[b + 1] - a0
        c0 = coff[b]
        Lb = prm[b, P.L]
        r2 = prm[b, P.R2]
        steps = iprm[b, IP.STEPS]
        observing = s % iprm[b, IP.EVERY] == 0 or s == steps
        graph = observing and iprm[b, IP.WANT_COMPONENTS] != 0
        tracking = iprm[b, IP.TRACK] != 0 and s < steps
        nc = ti.math.ivec3(ti.cast(grid[0], ti.i32), ti.cast(grid[1], ti.i32),
                           ti.cast(grid[2], ti.i32))
        i = cidx[k]
        lo, hi = reach(k, cc, grid, far, ps)
        acc = ti.Vector.zero(float, dim + 1)
        if ti.static(full):
            if graph or tracking:  # the components and Theorem 2's forest
                acc = sums(k, cc, lo, hi, a0, n, c0, nc, Lb, r2, union, graph, tracking, ps,
                           cstart, cidx, parent, parent_u)
            else:
                acc = sums(k, cc, lo, hi, a0, n, c0, nc, Lb, r2, NO_LINKS, graph, tracking,
                           ps, cstart, cidx, parent, parent_u)
        else:
            acc = sums(k, cc, lo, hi, a0, n, c0, nc, Lb, r2, NO_LINKS, graph, tracking, ps,
                       cstart, cidx, parent, parent_u)
        A[DEG][k] = ti.cast(acc[dim], ti.i32) - 1  # the closed set holds i
        bad = 0
        if s < steps:
            bad = update(b, i, k, a0, acc, _key(kseed[b, 0], s), _key(kseed[b, 1], s),
                         iprm[b, IP.MOVE_NEW], prm, ps, A[POS], A[EW], A[THETA])
        return bad

    @ti.func
    def end(b, s, bad, A: ti.template()):
        """Replica b's epilogue of step s: the observation (when due), Theorem 2's
        intervals, and the divergence of a non-finite update."""
        aoff, iprm = ti.static(A[AOFF], A[IPRM])
        a0 = aoff[b]
        n = aoff[b + 1] - a0
        steps = iprm[b, IP.STEPS]
        if s % iprm[b, IP.EVERY] == 0 or s == steps:
            row = A[OOFF][b] + iprm[b, IP.NOBS]
            iprm[b, IP.NOBS] = iprm[b, IP.NOBS] + 1
            observe(b, a0, n, s, row, A[PS], A[PARENT], A[DEG], A[ARC_LO], A[ARC_HI], A[PRM],
                    iprm, A[OBS])
        if s < steps:
            if ti.static(full):
                if iprm[b, IP.TRACK] != 0:
                    close_linked(b, a0, n, s, A[PARENT_U], iprm)
            if bad != 0:
                iprm[b, IP.BAD] = s

    @ti.func
    def replica(b, s0, s1, A: ti.template()):
        """Replica b from step s0 towards s1 (serially: its steps, then its agents)."""
        aoff, coff, cstart = ti.static(A[AOFF], A[COFF], A[CSTART])
        a0 = aoff[b]
        n = aoff[b + 1] - a0
        c0 = coff[b]
        s = s0
        while s < s1:
            live, grid, far = begin(b, s, A)
            if live == 0:
                break
            nx = ti.cast(grid[0], ti.i32)
            ny = ti.cast(grid[1], ti.i32)
            bad = 0
            # Slot k's cell, followed along the slots (they are in cell order): no
            # division per agent.
            cc = ti.math.ivec3(0)
            cend = a0 + cstart[c0 + 1] if nx > 0 else a0 + n
            for k in range(a0, a0 + n):
                while k >= cend:
                    cc[0] += 1
                    if cc[0] == nx:
                        cc[0] = 0
                        cc[1] += 1
                        if ti.static(dim == 3):
                            if cc[1] == ny:
                                cc[1] = 0
                                cc[2] += 1
                    cend = a0 + cstart[c0 + cc[0] + nx * (cc[1] + ny * cc[2]) + 1]
                bad |= slot(b, s, k, cc, grid, far, SERIAL, A)
            end(b, s, bad, A)
            s += 1

    return begin, slot, end, replica


@cache
def advance_kernel(rule: int, periodic: bool, full: bool, dim: int, vectorial: bool):
    """The window kernel for one rule and geometry (compile-time specialised). `full`:
    some replica asks for the components, Theorem 2's intervals or the heading spread;
    without them the kernel is half the code (the visit that links the graph, the
    union-find and the spread are left out), which halves what Taichi re-reads and
    LLVM re-generates at every process start. The arithmetic of a step is the same in
    both, so a replica's bits do not depend on `full`. `dim` 3 and `vectorial` (noise): the
    vicsek rule only."""
    # ps is flat, slot k's state at k * W .. k * W + W - 1: a compile-time stride instead
    # of the array's runtime shape in every address of the visit (3% of a step).
    W = 2 * dim
    begin, slot, end, replica = _steps(rule, periodic, full, dim, vectorial)

    @ti.kernel
    def advance(s0: ti.i32, s1: ti.i32, tasks: ti.i32, queue: nd, aoff: nd, coff: nd,
                ooff: nd, prm: nd, iprm: nd, kseed: nd, pos: nd, ew: nd, theta: nd, ps: nd,
                cell: nd, cstart: nd, cidx: nd, parent: nd, parent_u: nd, deg: nd,
                arc_lo: nd, arc_hi: nd, obs: nd):
        A = ti.static((aoff, coff, ooff, prm, iprm, kseed, pos, ew, theta, ps, cell, cstart,
                       cidx, parent, parent_u, deg, arc_lo, arc_hi, obs))
        # One CPU task per worker thread; each takes the next replica from the queue
        # until none is left. Replicas tied to tasks (one per task) were dealt to the
        # threads in contiguous blocks, so a batch ordered by size (N = 400 runs, then N
        # = 100 ones) left one thread with 4x the work of the other.
        for t in range(tasks * SPREAD):
            if t % SPREAD == 0:
                b = ti.atomic_add(queue[0], 1)
                while b < aoff.shape[0] - 1:
                    replica(b, s0, s1, A)
                    b = ti.atomic_add(queue[0], 1)

    @ti.kernel
    def step_all(s: ti.i32, rep: nd, flags: nd, grids: nd, aoff: nd, coff: nd, ooff: nd,
                 prm: nd, iprm: nd, kseed: nd, pos: nd, ew: nd, theta: nd, ps: nd, cell: nd,
                 cstart: nd, cidx: nd, parent: nd, parent_u: nd, deg: nd, arc_lo: nd,
                 arc_hi: nd, obs: nd):
        """The batched schedule's step s: every replica's prologue (one per CPU task),
        then every replica's agents in one parallel loop (slot k of replica rep[k]), then
        every replica's epilogue. The same functions as `advance`, in the same order for
        each replica: the same bits."""
        A = ti.static((aoff, coff, ooff, prm, iprm, kseed, pos, ew, theta, ps, cell, cstart,
                       cidx, parent, parent_u, deg, arc_lo, arc_hi, obs))
        B = aoff.shape[0] - 1
        for t in range(B * SPREAD):
            if t % SPREAD == 0:
                b = t // SPREAD
                live, grid, far = begin(b, s, A)
                flags[b, 0] = live
                flags[b, 1] = 0
                for c in ti.static(range(G_O + dim)):
                    grids[b, c] = grid[c]
                grids[b, G_O + dim] = far
        for k in range(ps.shape[0] // W):
            b = rep[k]
            if flags[b, 0] != 0:
                grid = ti.Vector([grids[b, c] for c in ti.static(range(G_O + dim))])
                nx = ti.cast(grid[0], ti.i32)
                ny = ti.cast(grid[1], ti.i32)
                cc = ti.math.ivec3(0)
                if nx > 0:  # the cell of slot k, from its agent's (row-major) cell number
                    q = cell[cidx[k]]
                    cc[0] = q % nx
                    cc[1] = (q // nx) % ny
                    if ti.static(dim == 3):
                        cc[2] = q // (nx * ny)
                if slot(b, s, k, cc, grid, grids[b, G_O + dim], ATOMIC, A) != 0:
                    flags[b, 1] = 1
        for t in range(B * SPREAD):
            if t % SPREAD == 0:
                b = t // SPREAD
                if flags[b, 0] != 0:
                    end(b, s, flags[b, 1], A)

    return advance, step_all


class VicsekBatch(FusedBatch):
    """The state of a batch of M1 replicas (any N, L, eta, steps each; one rule, geometry
    and dimension), advanced window by window by `advance_kernel`."""

    dimensions = (2, 3)
    QUEUED = True  # `advance`'s threads take replicas from a queue
    CHECKPOINTS = True  # the whole state is in `args`

    def __init__(self, scenarios: list[Scenario]):
        from ...space.initial import initial_state

        self.scenarios = scenarios
        first = scenarios[0]
        p0: VicsekParams = first.model  # type: ignore[assignment]
        self.rule = p0.rule
        self.periodic = isinstance(first.space, PeriodicBox)
        self.dim = dim = first.dimension
        self.vectorial = p0.noise == "vectorial"
        self.kernel = advance_kernel(RULES[p0.rule], self.periodic, self.full(first), dim,
                                     self.vectorial)[0]
        ns = [s.n_agents for s in scenarios]
        rows = observation_rows(scenarios)
        self.aoff, self.ooff = offsets(ns), offsets(rows)
        self.coff = cell_offsets(ns, 2)
        total = int(self.aoff[-1])
        B = len(scenarios)
        prm = np.zeros((B, P.size))
        iprm = np.zeros((B, IP.size), dtype=np.int32)
        kseed = np.zeros((B, 2), dtype=np.uint32)  # noise streams 0 and 1 (3D: two draws)
        pos = np.zeros((total, dim))
        ew = np.zeros((total, dim))
        theta = np.zeros(total)
        self.track = []
        for b, sc in enumerate(scenarios):
            p: VicsekParams = sc.model  # type: ignore[assignment]
            r = sc.neighbours.radius
            L_ = sc.space.L if self.periodic else 0.0
            r2 = runtime.next_above(r * r) if sc.inclusive else r * r
            prm[b, [P.R2, P.V0DT, P.ETA, P.G, P.L, P.THETA0, P.RADIUS, P.CAP]] = [
                r2, p.v0 * sc.time.dt, p.eta, p.g or 1.0, L_, p.leader_heading, r,
                1.0 - np.cos(p.eta / 2)]
            track = _tracks(sc)
            self.track.append(track)
            chosen = set(sc.recording.observables or OBS)
            iprm[b, [IP.STEPS, IP.EVERY, IP.TRACK, IP.BAD, IP.MOVE_NEW, IP.WANT_COMPONENTS,
                     IP.WANT_SPREAD]] = [
                sc.time.steps, sc.recording.observables_every, int(track), -1,
                int(p.position_update == "new_heading"), int("components" in chosen),
                int("heading_spread" in chosen)]
            kseed[b] = [rng.seed_key(sc.seed, 0), rng.seed_key(sc.seed, 1)]
            init = initial_state(sc)
            th = init.headings
            if p.rule == "leader":
                th[0] = p.leader_heading
            a0, a1 = self.aoff[b], self.aoff[b + 1]
            pos[a0:a1] = init.positions
            theta[a0:a1] = th
            ew[a0:a1] = init.directions if dim == 3 else np.stack([np.cos(th), np.sin(th)],
                                                                   axis=1)

        # numpy arrays the kernel runs on in place (FusedBatch): no from/to-numpy kernels.
        def arr(a: np.ndarray, dtype: Any = float) -> np.ndarray:
            return host_array(a, runtime.real() if dtype is float else dtype)

        def scratch(shape, dtype: Any = float) -> np.ndarray:
            return arr(np.zeros(shape), dtype)

        i32 = np.int32
        self.args = dict(
            aoff=arr(self.aoff, i32), coff=arr(self.coff, i32), ooff=arr(self.ooff, i32),
            prm=arr(prm), iprm=arr(iprm, i32), kseed=arr(kseed, np.uint32),
            pos=arr(pos), ew=arr(ew), theta=arr(theta), ps=scratch(total * 2 * dim),
            cell=scratch(total, i32), cstart=scratch(int(self.coff[-1]), i32),
            cidx=scratch(total, i32), parent=scratch(total, i32),
            parent_u=arr(np.arange(total, dtype=np.int32), i32), deg=scratch(total, i32),
            arc_lo=scratch(total), arc_hi=scratch(total),
            obs=arr(np.zeros((int(self.ooff[-1]), N_OBS))),
        )
        assert tuple(self.args) == ARRAYS
        self.queue = host_array(np.zeros(1), np.int32)  # the next replica to take
        self.tasks = min(B, runtime.current().threads)

    @property
    def n_replicas(self) -> int:
        return len(self.scenarios)

    def advance(self, s0: int, s1: int) -> None:
        """Advance every replica from step s0 towards s1 (each stops at its own end)."""
        self.invalidate()
        self.queue[0] = 0
        self.kernel(s0, s1, self.tasks, self.queue, *(self.args[k] for k in ARRAYS))

    def observables(self, b: int, iprm: np.ndarray) -> dict[str, np.ndarray]:
        o0 = self.ooff[b]
        rows = self.host("obs")[o0:o0 + iprm[b, IP.NOBS]]
        keep = [c for c in OBS if c != "step"]
        if self.rule != "leader":
            keep.remove("leader_error")
        if not self.track[b]:
            keep.remove("linked_intervals")
        keep = [c for c in keep if self.scenarios[b].recording.wants(c)]
        return {"step": rows[:, 0], **{c: rows[:, OBS.index(c)] for c in keep}}

    def frame(self, b: int, arrays: list[str], step: int) -> dict[str, np.ndarray]:
        a0, a1 = self.aoff[b], self.aoff[b + 1]
        out = {}
        e = self.host("ew")[a0:a1]
        if self.dim == 3:  # headings are the unit vectors (N, 3), as on the per-step path
            if "position" in arrays:
                out["position"] = self.host("pos")[a0:a1]
            if "heading" in arrays:
                out["heading"] = e
            if "velocity" in arrays:
                out["velocity"] = self.scenarios[b].model.v0 * e
            return out
        th = (np.arctan2(e[:, 1], e[:, 0]) if self.rule == "vicsek"
              else self.host("theta")[a0:a1])
        if "position" in arrays:
            out["position"] = self.host("pos")[a0:a1]
        if "heading" in arrays:
            out["heading"] = th
        if "velocity" in arrays:
            v0 = self.scenarios[b].model.v0
            out["velocity"] = v0 * np.stack([np.cos(th), np.sin(th)], axis=1)
        return out

    def convergence_keys(self) -> list[str]:
        return ["heading_spread", "leader_error"] if self.rule == "leader" else [
            "heading_spread"]

    def extra(self, b: int, iprm: np.ndarray) -> dict[str, Any]:
        if not self.track[b]:
            return {}
        return {"linked_intervals": {
            "count": int(iprm[b, IP.LINKED]), "longest_steps": int(iprm[b, IP.LONGEST]),
            "open_since_step": int(iprm[b, IP.OPEN])}}

    def divergence(self, b: int, iprm: np.ndarray) -> tuple[int, str, str] | None:
        step = int(iprm[b, IP.BAD])
        if step < 0:
            return None
        return (step, *CAUSES[iprm[b, IP.CAUSE]])

    @staticmethod
    def full(scenario: Scenario) -> bool:
        """Whether `scenario` needs the kernel with the graph's components, Theorem 2's
        intervals and the heading spread (`advance_kernel`'s `full`)."""
        chosen = set(scenario.recording.observables or OBS)
        return bool(_tracks(scenario) or chosen & {"components", "heading_spread"})

    @classmethod
    def batch_key(cls, scenario: Scenario) -> tuple | None:
        """Scenarios with the same key share a launch; None: not for this path."""
        p: VicsekParams = scenario.model  # type: ignore[assignment]
        return ("vicsek", p.rule, isinstance(scenario.space, PeriodicBox),
                cls.full(scenario), scenario.dimension, p.noise)


class VicsekBatched(VicsekBatch):
    """M1's batched schedule: the fused batch's state, advanced one launch a step over
    every replica's agents at once (`advance_kernel`'s `step_all`: parallel over (replica,
    agent), as a GPU runs a sweep). Each replica runs the fused schedule's functions in
    the same order, so its bits are the fused schedule's."""

    QUEUED = False  # replicas are not handed to threads: their agents are

    def __init__(self, scenarios: list[Scenario]):
        super().__init__(scenarios)
        self.step_kernel = advance_kernel(RULES[self.rule], self.periodic,
                                          self.full(scenarios[0]), self.dim,
                                          self.vectorial)[1]
        B = len(scenarios)
        # On the CPU the kernel runs on the host arrays in place (measured: device arrays
        # cost more per launch there); a GPU's launches take device arrays, which a host
        # array would be copied into and out of at every launch.
        on = host_array if runtime.current().backend == "cpu" else _device
        if on is _device:
            self.args = {k: _device(v) for k, v in self.args.items()}
        self.rep = on(np.repeat(np.arange(B), np.diff(self.aoff)), np.int32)  # slot -> b
        self.flags = on(np.zeros((B, 2)), np.int32)  # live, bad (this step)
        self.grids = on(np.zeros((B, G_O + 1 + self.dim)), runtime.real())  # grid, far

    def advance(self, s0: int, s1: int) -> None:
        """Every replica from step s0 towards s1, a launch a step."""
        self.invalidate()
        args = [self.args[k] for k in ARRAYS]
        for s in range(s0, s1):
            self.step_kernel(s, self.rep, self.flags, self.grids, *args)


def _device(a: np.ndarray, dtype: Any = None) -> ti.Ndarray:
    """A device array holding `a` (as `dtype`, default its own)."""
    a = np.ascontiguousarray(a, dtype=dtype)
    out = ti.ndarray(ti.lang.util.to_taichi_type(a.dtype), shape=a.shape)
    out.from_numpy(a)
    return out
