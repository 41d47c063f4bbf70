"""Taichi kernels of the double-integrator flocking models: the control law, one explicit
step, the graph observables and the adaptive radius.

The control law and its Euler step are law.py's (paper 000 eq. 3; paper 002 eq. 3-4);
here the per-step schedule: N_i from a fixed graph (CSR, in agent-id order), or metric
neighbours found on a grid (kernels/space/plane_grid.py) or, at small N, over all pairs,
through one visitor interface, parallel over the agents of the flock. R_ij is
  uniform  R                                     (paper 000, section 5)
  own      R_i, agent i's adaptive radius        (paper 002, eq. 4 as printed)
  min      min(R_i, R_j)                         (a symmetric variant)
`accel` kernels write u alone, for the RK4 stages (kernels/space/integrate.py).
A non-finite result increments bad[0]; the caller raises SimulationDiverged.
M2's kernels take the dimension `dim` (2 or 3) at compile time: the law needs only
|r_ij| and the vectors r_ij, v_ij, so one source serves both (2D arithmetic unchanged).
M3's navigation and adaptive radius take `dim` too.
On the dense grid the metric kernels go by cell blocks (kernels/space/blocks.py: up to four
agents of a cell share one pass over their neighbour cells, a distance test lists each
one's neighbours, and the pair runs for those), bit for bit the per-agent visit's sums.
"""

from functools import cache

import taichi as ti

from ...space.blocks import make_cell_pass, make_sieved_visitor, n_cells
from ...space.graph import find, link
from ...space.grid import put, row, within
from ...space.integrate import nonfinite
from ...space.params import Slots
from ...space.plane_grid import visitor
from . import law, potentials
from .law import MIN, OWN
from .navigation import make_navigation

nd = ti.types.ndarray()
# The force parameter array: dt, the potential's a and c, R^2 (uniform radius); M3's c_d,
# V_min, the stuck speed squared and the radius floor.
P = Slots("DT", "A", "C", "R2", "CD", "VMIN", "STUCK2", "FLOOR")
NEAREST_NONE = 1e300


@ti.func
def pair_radius2(rule: ti.template(), i, k, rad: ti.template(), prm: ti.template()):
    """R_ij^2 for the rule (uniform R from prm, else the per-agent radii)."""
    r2 = prm[P.R2]
    if ti.static(rule == OWN):
        r2 = rad[i] * rad[i]
    elif ti.static(rule == MIN):
        r = ti.min(rad[i], rad[k])
        r2 = r * r
    return r2


@cache
def grid_kernels(rule: int, inclusive: bool, mission: bool, damping: int,
                 has_obstacles: bool, unit_kappa: bool, search: str, dim: int = 2,
                 blocks: bool = True):
    """(euler, accel) kernels over metric neighbours (`search`: all_pairs, hash, dense;
    knn, knn_symmetric: the k nearest within R, kernels/space/knn.py),
    specialised at compile time. On the dense grid they go by cell blocks unless `blocks`
    is False (the per-agent visit: the same bits, which
    tests/kernels/flocking/test_flocking_by_cell.py checks)."""
    navigation = make_navigation(has_obstacles, unit_kappa, dim)

    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        vel, rad, prm = ti.static(S[0], S[1], S[2])
        r2 = pair_radius2(rule, i, k, rad, prm)
        return acc + law.metric_term(d, d.dot(d), r2, inclusive, k != i, row(vel, k, dim),
                                     prm[P.A])

    visit = visitor(pair, search, dim)

    @ti.func
    def control(i, xi, vi, sums, prm: ti.template(), nav: ti.template(), OB: ti.template()):
        """u_i from agent i's neighbour sums (sum v_j + sum f d, |N_i|), by the law."""
        u = law.control(sums, vi)
        if ti.static(mission):
            nv = navigation(xi, nav, OB)
            u = law.mission_control(u, vi, ti.Vector([nv[1 + c] for c in ti.static(range(dim))]),
                                    nv[0], damping, prm[P.VMIN], prm[P.CD])
        return u

    @ti.func
    def euler_update(i, xi, vi, sums, OUT: ti.template(), prm: ti.template(),
                     nav: ti.template(), bad: ti.template(), OB: ti.template()):
        """Semi-implicit Euler into OUT = (pos_out, vel_out)."""
        x, v = law.euler(xi, vi, control(i, xi, vi, sums, prm, nav, OB), prm[P.DT])
        put(OUT[0], i, x)
        put(OUT[1], i, v)
        if nonfinite(x, v):
            ti.atomic_add(bad[0], 1)

    @ti.func
    def accel_update(i, xi, vi, sums, OUT: ti.template(), prm: ti.template(),
                     nav: ti.template(), bad: ti.template(), OB: ti.template()):
        """u_i into OUT = (acc_out,)."""
        u = control(i, xi, vi, sums, prm, nav, OB)
        put(OUT[0], i, u)
        if nonfinite(u, xi):
            ti.atomic_add(bad[0], 1)

    @ti.func
    def sieve(i, k, s2, S: ti.template()):
        """1 where pair's terms may be nonzero: j in N_i (the force needs s < R_ij, inside
        it); the agent itself passes (s = 0) and pair drops it."""
        rad, prm = ti.static(S[1], S[2])
        return within(s2, pair_radius2(rule, i, k, rad, prm), inclusive)

    # On the dense grid by cell blocks (kernels/space/blocks.py): every agent's sums in the
    # per-agent visit's order, so the same bits, with one pass over the rows per block and
    # the pair for the sieved neighbours alone.
    by_cells = search == "dense" and blocks
    visit_block = make_sieved_visitor(sieve, pair, dim)

    def each(update):
        """`one(j, ...)`: `update` for the agents of cell j by blocks on the dense grid, else
        for agent j alone; `extent` counts the j."""
        if by_cells:

            @ti.func
            def block_update(i, xi, sums, F: ti.template(), unused):
                vel, prm, nav, bad, OUT, OB = ti.static(F)
                update(i, xi, row(vel, i, dim), sums, OUT, prm, nav, bad, OB)

            cell_pass = make_cell_pass(visit_block, block_update, dim + 1, "dense", dim)

            @ti.func
            def one(bucket, pos: ti.template(), vel: ti.template(), rad: ti.template(),
                    prm: ti.template(), nav: ti.template(), bad: ti.template(),
                    OUT: ti.template(), G: ti.template(), OB: ti.template()):
                cell_pass(bucket, pos, G, ti.static((vel, rad, prm)),
                          ti.static((vel, prm, nav, bad, OUT, OB)), ti.Vector([0]))
        else:

            @ti.func
            def one(i, pos: ti.template(), vel: ti.template(), rad: ti.template(),
                    prm: ti.template(), nav: ti.template(), bad: ti.template(),
                    OUT: ti.template(), G: ti.template(), OB: ti.template()):
                xi = row(pos, i, dim)
                sums = visit(i, xi, ti.Vector.zero(float, dim + 1), pos, G,
                             ti.static((vel, rad, prm)), False)
                update(i, xi, row(vel, i, dim), sums, OUT, prm, nav, bad, OB)

        return one

    @ti.func
    def extent(pos: ti.template(), G: ti.template()):
        m = pos.shape[0]
        if ti.static(by_cells):
            m = n_cells(G, "dense", dim)
        return m

    euler_one, accel_one = each(euler_update), each(accel_update)

    @ti.kernel
    def euler(pos: nd, vel: nd, rad: nd, pos_out: nd, vel_out: nd, prm: nd, nav: nd, bad: nd,
              start: nd, cid: nd, gf: nd, gi: nd,
              opos: nd, orad: nd, ostart: nd, ocid: nd, ogf: nd, ogi: nd):
        G = ti.static((start, cid, gf, gi))
        for j in range(extent(pos, G)):
            euler_one(j, pos, vel, rad, prm, nav, bad, (pos_out, vel_out), G,
                      (opos, orad, ostart, ocid, ogf, ogi))

    @ti.kernel
    def accel(pos: nd, vel: nd, rad: nd, acc_out: nd, prm: nd, nav: nd, bad: nd,
              start: nd, cid: nd, gf: nd, gi: nd,
              opos: nd, orad: nd, ostart: nd, ocid: nd, ogf: nd, ogi: nd):
        G = ti.static((start, cid, gf, gi))
        for j in range(extent(pos, G)):
            accel_one(j, pos, vel, rad, prm, nav, bad, (acc_out,), G,
                      (opos, orad, ostart, ocid, ogf, ogi))

    return euler, accel


@ti.func
def _csr_control(i, xi, vi, pos: ti.template(), vel: ti.template(), indptr: ti.template(),
                 indices: ti.template(), prm: ti.template()):
    """u_i of eq. 3 over agent i's neighbours in the graph (CSR), by the law."""
    u = ti.Vector.zero(float, xi.n)
    for e in range(indptr[i], indptr[i + 1]):
        j = indices[e]
        u = law.graph_term(u, row(pos, j, xi.n) - xi, row(vel, j, xi.n), vi, prm[P.A])
    return u


@ti.kernel
def csr_euler(pos: nd, vel: nd, pos_out: nd, vel_out: nd, indptr: nd, indices: nd, prm: nd,
              bad: nd, dim: ti.template()):
    """One semi-implicit Euler step on a fixed graph (paper 000 eq. 1, 3)."""
    for i in range(pos.shape[0]):
        xi = row(pos, i, dim)
        vi = row(vel, i, dim)
        x, v = law.euler(xi, vi, _csr_control(i, xi, vi, pos, vel, indptr, indices, prm),
                         prm[P.DT])
        put(pos_out, i, x)
        put(vel_out, i, v)
        if nonfinite(x, v):
            ti.atomic_add(bad[0], 1)


@ti.kernel
def csr_accel(pos: nd, vel: nd, acc_out: nd, indptr: nd, indices: nd, prm: nd, bad: nd,
              dim: ti.template()):
    """u_i of eq. 3 on a fixed graph."""
    for i in range(pos.shape[0]):
        xi = row(pos, i, dim)
        vi = row(vel, i, dim)
        u = _csr_control(i, xi, vi, pos, vel, indptr, indices, prm)
        put(acc_out, i, u)
        if nonfinite(u, xi):
            ti.atomic_add(bad[0], 1)


@ti.kernel
def csr_potential(pos: nd, indptr: nd, indices: nd, prm: nd, pot: nd, dim: ti.template()):
    """pot[i] = V_i = sum_{j in N_i} V(|r_ij|) (eq. 4)."""
    for i in range(pos.shape[0]):
        acc = 0.0
        for e in range(indptr[i], indptr[i + 1]):
            j = indices[e]
            d = row(pos, j, dim) - row(pos, i, dim)
            acc += potentials.value(d.dot(d), prm[P.A], prm[P.C])
        pot[i] = acc


@ti.func
def Observation(a, b, c, d, e, f):
    """Six floats of the runtime's type (a module-level ti.types.vector would fix it at
    import)."""
    return ti.Vector([a, b, c, d, e, f], dt=float)
O_DEG, O_NEAR_D2, O_NEAR_K, O_VSUM, O_NSAT, O_ROOT = range(6)


@cache
def grid_observe_kernel(rule: int, inclusive: bool, search: str, dim: int = 2):
    """Kernel writing, per agent (grid order): the nearest agent among the visited
    candidates (squared distance and slot), sum_{j != i} (U_ij - V(R_ij)) (the saturated
    potential less its constant), valency |N_i|, and the union of every edge into `parent`
    (i's root found once and carried along, as in kernels/space/graph.py). The values go
    into two (N, dim) arrays of the float type, the step's spare state buffers (dead
    between an observation and the step): near[i] = (nearest d^2, potential sum),
    counts[i] = (valency, nearest slot), counts exact in the float type (as they are in
    the accumulator) up to 2^24 in float32."""

    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        rad, prm, parent = ti.static(S[0], S[1], S[2])
        if k != i:
            s2 = d.dot(d)
            if s2 < acc[O_NEAR_D2]:
                acc[O_NEAR_D2] = s2
                acc[O_NEAR_K] = ti.cast(k, float)
            r2 = pair_radius2(rule, i, k, rad, prm)
            if within(s2, r2, inclusive):
                acc[O_DEG] += 1.0
                # own, knn: j in N_i need not imply i in N_j, so every edge is joined
                # from i.
                if ti.static(rule == OWN or search.startswith("knn")) or k > i:
                    root = ti.cast(acc[O_ROOT], ti.i32)
                    rk = find(parent, k)
                    if rk != root:
                        acc[O_ROOT] = ti.cast(link(parent, root, rk), float)
            if s2 < r2:
                acc[O_VSUM] += potentials.value(s2, prm[P.A], prm[P.C])
                if ti.static(rule == MIN):  # R_ij varies with j
                    acc[O_VSUM] -= potentials.value(r2, prm[P.A], prm[P.C])
                else:
                    acc[O_NSAT] += 1.0
        return acc

    visit = visitor(pair, search, dim)

    @ti.kernel
    def observe(pos: nd, rad: nd, prm: nd, parent: nd, near: nd, counts: nd,
                start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi = row(pos, i, dim)
            acc = Observation(0.0, NEAREST_NONE, -1.0, 0.0, 0.0,
                              ti.cast(find(parent, i), float))
            acc = visit(i, xi, acc, pos, ti.static((start, cid, gf, gi)),
                        ti.static((rad, prm, parent)), False)
            # V(R_i) once per agent: R_i is R (uniform) or agent i's own radius.
            r2 = pair_radius2(rule, i, i, rad, prm)
            near[i, 0] = acc[O_NEAR_D2]
            near[i, 1] = acc[O_VSUM] - acc[O_NSAT] * potentials.value(r2, prm[P.A], prm[P.C])
            counts[i, 0] = acc[O_DEG]
            counts[i, 1] = acc[O_NEAR_K]

    return observe


@cache
def radius_kernel(rule: int, inclusive: bool, search: str, dim: int = 2):
    """Adaptive radius, paper 002 eq. 4, synchronously (reads rad, writes rad_out):
    R_i' = max(R_i / 2, floor) if |v_i| < stuck_speed and V_i > V_min,
    R_i' = max(R_i, R_j for j in N_i) otherwise. counts += (halved, increased)."""

    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        rad, prm = ti.static(S[0], S[1])
        if k != i and within(d.dot(d), pair_radius2(rule, i, k, rad, prm), inclusive):
            acc = ti.max(acc, rad[k])
        return acc

    visit = visitor(pair, search, dim)

    @ti.kernel
    def update(pos: nd, vel: nd, rad: nd, rad_out: nd, mission: nd, prm: nd, counts: nd,
               start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            r = rad[i]
            new = r
            if law.stuck(row(vel, i, dim), mission[i, 0], prm[P.STUCK2], prm[P.VMIN]):
                new = law.halved(r, prm[P.FLOOR])
                if new < r:
                    ti.atomic_add(counts[0], 1)
            else:
                new = visit(i, row(pos, i, dim), r, pos,
                            ti.static((start, cid, gf, gi)), ti.static((rad, prm)), False)
                if new > r:
                    ti.atomic_add(counts[1], 1)
            rad_out[i] = new

    return update
