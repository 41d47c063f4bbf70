"""M1's law: one agent's step under the Vicsek and Jadbabaie–Lin–Morse rules (paper 001).

Written once, for every schedule (the per-step kernels of step.py, the fused and batched
ones of fused.py), as a function of values: the agent's state at t, the sums over its
closed neighbourhood N_i ∪ {i} (eq. 2 text; how they are gathered is the schedule's), its
id and the step's noise keys. With S_i those sums:
  vicsek    e(theta_i') = R(xi_i) S / |S|, S = sum e(theta_j)   (Vicsek et al. 1995;
            3D: S / |S| turned to a direction uniform in the spherical cap of half-angle
            eta/2 around it, noise.py, docs/MODELS_3D.md)
  average   theta_i' = sum theta_j / (1 + n_i) + xi_i               (eq. 1-2)
  laplacian theta_i' = theta_i - ((1 + n_i) theta_i - sum theta_j) / g + xi_i (eq. 17-18)
  leader    as average; agent 0 (the leader) holds theta_0       (eq. 22)
  x_i' = x_i + v0 dt e(phi_i), phi = theta (old, default) or theta' (new), wrapped into
  the periodic box [0, L)^d.
xi_i = eta (u - 1/2), u the counter-based hash of (seed, step, agent id) (rng.py).
Vectorial noise (the vicsek rule, Grégoire & Chaté, PRL 92, 025702, 2004):
  e(theta_i') = w / |w|, w = S + eta n_i u_i, n_i = |N_i ∪ {i}|, u_i a random unit vector
  (2D: at angle 2 pi u; 3D: uniform on the sphere from two draws, `unit_vector`).
"""

from functools import cache

import taichi as ti

from ...space import rng, trig
from .noise import cap_turn, unit_vector

RULES = {"vicsek": 0, "average": 1, "laplacian": 2, "leader": 3}
# The law's parameters, in this order: v0 dt, eta, g (laplacian), L (periodic box),
# theta_0 (leader), 1 - cos(eta/2) (3D: the spherical cap's height).
V0DT, ETA, G, L, THETA0, CAP = range(6)


@cache
def agent_step(rule: int, periodic: bool, dim: int, reciprocal: bool, vectorial: bool = False):
    """The law of one rule, geometry and dimension. `reciprocal`: the 2D vicsek rule
    scales S by 1 / |S| (the fused and batched schedules) instead of dividing each
    component by |S| (the per-step one): the two round differently, and each schedule
    keeps the bits it has always had. `vectorial`: the vicsek rule with Grégoire–Chaté
    noise (the sums then carry the count n_i in acc[dim])."""
    vicsek = rule == RULES["vicsek"]
    assert vicsek or not vectorial, "vectorial noise is the vicsek rule's"

    @ti.func
    def step(th, x, e, acc, agent, key, key2, q, move_new):
        """(x', e(theta'), theta', bad) of an agent at x with heading theta (`th`: its angle
        for the JLM rules, any finite value for the vicsek rule) and unit vector e, from
        its closed-neighbourhood sums `acc` ((S, count) for the vicsek rule, (sum theta_j,
        0, count) for the JLM rules); q: the parameters (V0DT ..); bad is 1 when the new
        state is not finite."""
        new = th
        e_new = ti.Vector.unit(dim, 0, float)
        if ti.static(vectorial):
            if q[ETA] > 0.0:  # w = S + eta n_i u_i, in place of S
                u = unit_vector(rng.uniform(key, agent), rng.uniform(key2, agent), dim)
                for c in ti.static(range(dim)):
                    acc[c] += q[ETA] * acc[dim] * u[c]
        if ti.static(vicsek):
            nrm2 = acc[0] * acc[0] + acc[1] * acc[1]
            if ti.static(dim == 3):
                nrm2 += acc[2] * acc[2]
            nrm = ti.sqrt(nrm2)
            if nrm > 0.0:  # arg(0) = 0, as atan2(0, 0); in 3D the x axis
                if ti.static(reciprocal and dim == 2):
                    e_new = ti.math.vec2(acc[0], acc[1]) * (1.0 / nrm)
                else:
                    for c in ti.static(range(dim)):
                        e_new[c] = acc[c] / nrm
        elif ti.static(rule == RULES["laplacian"]):
            new = th - (acc[2] * th - acc[0]) / q[G]  # eq. 18
        else:
            new = acc[0] / acc[2]  # eq. 1-2 (and 22 for the leader)
        if ti.static(not vectorial):  # angular noise (vectorial: in w already)
            if ti.static(dim == 3):
                if q[ETA] > 0.0:
                    e_new = cap_turn(e_new, rng.uniform(key, agent), rng.uniform(key2, agent),
                                     q[CAP])
            elif q[ETA] > 0.0:
                noise = q[ETA] * (rng.uniform(key, agent) - 0.5)
                if ti.static(vicsek):
                    cs = trig.cos_sin(noise)  # rotate e_new by the noise angle
                    cn = cs[0]
                    sn = cs[1]
                    e_new = ti.math.vec2(cn * e_new[0] - sn * e_new[1],
                                         sn * e_new[0] + cn * e_new[1])
                else:
                    new += noise
        if ti.static(rule == RULES["leader"]):
            if agent == 0:
                new = q[THETA0]
        if ti.static(not vicsek):
            e_new = ti.math.vec2(ti.cos(new), ti.sin(new))
        if move_new:
            e = e_new
        x = x + q[V0DT] * e
        if ti.static(periodic):
            Lb = q[L]
            # x - L floor(x / L) is x itself for x in [0, L) (x / L < 1 there, in
            # rounding too): the division only for an agent that crossed the box.
            for c in ti.static(range(dim)):
                if x[c] < 0.0 or x[c] >= Lb:
                    x[c] -= Lb * ti.floor(x[c] / Lb)
                    if x[c] >= Lb:  # x - L floor(x / L) can round up to L itself
                        x[c] -= Lb
        v = new + x[0] + x[1] + e_new[0]  # NaN if any term is NaN or infinite
        if ti.static(dim == 3):
            v += x[2] + e_new[1] + e_new[2]
        return x, e_new, new, ti.cast(ti.math.isnan(v) or ti.math.isinf(v), ti.i32)

    return step
