"""M1's step kernels: Vicsek and the Jadbabaie–Lin–Morse heading rules (paper 001).

One step, synchronous for all agents (state at t read, state at t+1 written elsewhere):
  S_i = sums over the closed neighbourhood N_i ∪ {i}, N_i = {j : |r_ij| <= r} (eq. 2 text)
  vicsek    theta_i' = atan2(sum sin theta_j, sum cos theta_j) + xi_i; held as the unit
            vector e(theta_i') = R(xi_i) s / |s|, s = sum e(theta_j): no atan2 per step
            (3D: s / |s| turned to a direction uniform in the spherical cap of half-angle
            eta/2 around it, two counter-based draws: noise.py, docs/MODELS_3D.md)
  average   theta_i' = sum theta_j / (1 + n_i)                       (eq. 1-2, F = (I+D)^-1 (A+I))
  laplacian theta_i' = theta_i - ((1 + n_i) theta_i - sum theta_j) / g   (eq. 17-18)
  leader    as average, with agent 0 (the leader) in the sums whenever within r and its
            own heading held at theta_0 (eq. 22: its b_i theta_0 term)
  x_i' = x_i + v0 dt (cos phi_i, sin phi_i), phi = theta (old, default) or theta'.
xi_i = eta (u - 1/2), u from the counter-based hash of (seed, step, agent id).

`step_kernel` visits each agent's neighbours (any rule, geometry and dimension, and the
graph observables); `block_step_kernel` is the rule vicsek in the periodic box by cell
blocks (kernels/space/blocks.py), bit for bit the same step.
"""

from functools import cache

import taichi as ti

from ...space.blocks import BLOCK_LANES, lane, make_block_visitor, make_cell_pass, n_cells
from ...space.graph import find, link
from ...space.grid import make_visitor, row, set_row, within
from ...space.params import Slots
from .law import RULES, agent_step

nd = ti.types.ndarray()
# The parameter array: r^2, v0 dt, eta, g (laplacian), L (periodic box), theta_0 (leader),
# and 1 - cos(eta/2) (3D: the spherical cap's height).
P = Slots("R2", "V0DT", "ETA", "G", "L", "THETA0", "CAP")


@cache
def _finisher(rule: int, periodic: bool, move_new: bool, dim: int, vectorial: bool):
    """The end of one agent's step, shared by the per-agent and the by-cell kernels: the
    law (law.py) on the agent's state and sums, and the writes."""
    law = agent_step(rule, periodic, dim, False, vectorial)

    @ti.func
    def finish(i, xi, acc, theta: ti.template(), ew: ti.template(), ids: ti.template(),
               pos_out: ti.template(), theta_out: ti.template(), ew_out: ti.template(),
               prm: ti.template(), key, key2, bad: ti.template()):
        """Agent i's new heading from its neighbourhood sums acc, its move, the writes."""
        th = 0.0
        if ti.static(rule != RULES["vicsek"]):
            th = theta[i]
        q = ti.Vector([prm[P.V0DT], prm[P.ETA], prm[P.G], prm[P.L], prm[P.THETA0],
                       prm[P.CAP]])
        x, e_new, new, nonfinite = law(th, xi, row(ew, i, dim), acc, ids[i], key, key2, q,
                                       ti.static(int(move_new)))
        set_row(pos_out, i, x)
        if ti.static(rule != RULES["vicsek"]):
            theta_out[i] = new
        # The unit vectors travel with the state: each heading's cos and sin (2D) are
        # computed once, here.
        set_row(ew_out, i, e_new)
        if nonfinite:
            ti.atomic_add(bad[0], 1)

    return finish


@cache
def step_kernel(rule: int, inclusive: bool, periodic: bool, move_new: bool, with_graph: bool,
                dim: int, vectorial: bool):
    """Compile-time specialised step for one rule, geometry, dimension and noise. `with_graph`
    also fills the graph observables of G(t) from the same neighbour visit: each agent's
    degree, and the union of every edge into `parent` (slot-indexed) for the components."""

    # The sums' last lane counts the closed neighbourhood: the JLM rules average over it,
    # the vicsek rule needs it only for the degrees and for vectorial noise (eta n_i).
    counted = rule != RULES["vicsek"] or with_graph or vectorial

    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        ew, theta, prm, parent = ti.static(S[0], S[1], S[2], S[3])
        # Branch-free accumulation: w is 1 for a neighbour, 0 otherwise.
        w = ti.cast(within(d.dot(d), prm[P.R2], inclusive), float)
        if ti.static(rule == RULES["vicsek"]):
            ek = row(ew, k, dim)
            if ti.static(counted):
                acc += w * ti.Vector([ek[c] for c in ti.static(range(dim))] + [1.0])
            else:  # the count is for the degrees only: one add a pair fewer without them
                acc += w * ek
        else:
            acc += w * ti.math.vec3(theta[k], 0.0, 1.0)
        if ti.static(with_graph):
            if w > 0.0 and k > i:
                ri = find(parent, i)
                rk = find(parent, k)
                if ri != rk:
                    link(parent, ri, rk)
        return acc

    visit = make_visitor(pair, dim=dim)

    finish = _finisher(rule, periodic, move_new, dim, vectorial)

    @ti.kernel
    def step(pos: nd, theta: nd, ew: nd, ids: nd, pos_out: nd, theta_out: nd, ew_out: nd,
             prm: nd, key: ti.u32, key2: ti.u32, bad: nd, parent: nd, deg: nd,
             start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi = row(pos, i, dim)
            acc = visit(i, xi, ti.Vector.zero(float, dim + int(counted)), pos,
                        ti.static((start, cid, gf, gi)),
                        ti.static((ew, theta, prm, parent)), periodic)
            if ti.static(with_graph):
                deg[i] = ti.cast(acc[dim], ti.i32) - 1  # the closed neighbourhood holds i
            finish(i, xi, acc, theta, ew, ids, pos_out, theta_out, ew_out, prm, key, key2,
                   bad)

    return step


@cache
def block_step_kernel(inclusive: bool, move_new: bool, dim: int, vectorial: bool):
    """The vicsek rule's step in the periodic box with at least 3 cells across, by cell
    blocks (kernels/space/blocks.py): each agent's sum adds the same terms in the same
    order as in `step_kernel`'s visit, so the bits are the same
    (tests/kernels/vicsek/test_vicsek_by_cell.py). Vectorial noise counts n_i in the sums'
    column dim."""
    finish = _finisher(RULES["vicsek"], True, move_new, dim, vectorial)
    lanes = dim + int(vectorial)

    @ti.func
    def pair(k, p, Iv, X: ti.template(), acc: ti.template(), S: ti.template()):
        ew, prm = ti.static(S[0], S[1])
        r2 = prm[P.R2]
        ek = row(ew, k, dim)
        w = ti.Vector.zero(float, BLOCK_LANES)
        for q in ti.static(range(BLOCK_LANES)):
            d = p - lane(X, q)
            d2 = d.dot(d)
            if ti.static(inclusive):
                w[q] = ti.select(d2 <= r2, 1.0, 0.0)
            else:
                w[q] = ti.select(d2 < r2, 1.0, 0.0)
        # Four columns whatever dim (a 2D heading padded with zeros, and a 1 in column
        # dim to count n_i for vectorial noise): each lane's sum is then one add of a
        # whole vector register.
        ek4 = ti.Vector([ek[a] if a < dim else (1.0 if a == dim and vectorial else 0.0)
                         for a in ti.static(range(4))])
        for q in ti.static(range(BLOCK_LANES)):
            for a in ti.static(range(4)):
                acc[q, a] += w[q] * ek4[a]

    @ti.func
    def update(i, xi, acc, F: ti.template(), keys):
        theta, ew, ids, pos_out, theta_out, ew_out, prm, bad = ti.static(F)
        finish(i, xi, ti.Vector([acc[a] for a in ti.static(range(lanes))]), theta, ew, ids,
               pos_out, theta_out, ew_out, prm, keys[0], keys[1], bad)

    cell_pass = make_cell_pass(make_block_visitor(pair, dim), update, 4, "box", dim)

    @ti.kernel
    def step(pos: nd, theta: nd, ew: nd, ids: nd, pos_out: nd, theta_out: nd, ew_out: nd,
             prm: nd, key: ti.u32, key2: ti.u32, bad: nd, parent: nd, deg: nd,
             start: nd, cid: nd, gf: nd, gi: nd):
        G = ti.static((start, cid, gf, gi))
        for bucket in range(n_cells(G, "box", dim)):
            cell_pass(bucket, pos, G, ti.static((ew, prm)),
                      ti.static((theta, ew, ids, pos_out, theta_out, ew_out, prm, bad)),
                      ti.Vector([key, key2], dt=ti.u32))

    return step


@cache
def topological_step_kernel(rule: int, periodic: bool, move_new: bool, with_graph: bool,
                            dim: int, symmetric: bool, vectorial: bool):
    """The step with topological neighbours (kernels/space/knn.py): S_i = the sums over
    {i} and its k nearest (nearest first; with `symmetric`, then the agents that have i
    among their k and are not among i's, by slot), the same law. The lists come from the
    search run on this step's state; `with_graph` also writes each degree |N_i| and unions
    every edge into `parent` (slot-indexed) for the components; `vectorial`: Grégoire–Chaté
    noise (eta n_i u_i added to S)."""
    counted = rule != RULES["vicsek"] or with_graph or vectorial
    finish = _finisher(rule, periodic, move_new, dim, vectorial)

    @ti.func
    def term(k, ew: ti.template(), theta: ti.template()):
        """Agent k's term of the sums: its unit vector (vicsek) or (theta_k, 0, 1)."""
        if ti.static(rule == RULES["vicsek"]):
            ek = row(ew, k, dim)
            if ti.static(counted):
                return ti.Vector([ek[c] for c in ti.static(range(dim))] + [1.0])
            return ek
        return ti.math.vec3(theta[k], 0.0, 1.0)

    @ti.func
    def join(parent: ti.template(), u, v):
        ru = find(parent, u)
        rv = find(parent, v)
        if ru != rv:
            link(parent, ru, rv)

    @ti.kernel
    def step(pos: nd, theta: nd, ew: nd, ids: nd, pos_out: nd, theta_out: nd, ew_out: nd,
             prm: nd, key: ti.u32, key2: ti.u32, bad: nd, parent: nd, deg: nd,
             nbr: nd, cnt: nd, in_start: nd, in_src: nd):
        for i in range(pos.shape[0]):
            acc = term(i, ew, theta)  # the closed neighbourhood holds i
            n_i = cnt[i]
            for t in range(n_i):
                j = nbr[i, t]
                acc += term(j, ew, theta)
                if ti.static(with_graph):
                    join(parent, i, j)
            if ti.static(symmetric):
                for q in range(in_start[i], in_start[i + 1]):
                    acc += term(in_src[q], ew, theta)
                n_i += in_start[i + 1] - in_start[i]
            if ti.static(with_graph):
                deg[i] = n_i
            finish(i, row(pos, i, dim), acc, theta, ew, ids, pos_out, theta_out, ew_out,
                   prm, key, key2, bad)

    return step
