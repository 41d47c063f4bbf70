"""Couzin's zone law (J. Theor. Biol. 218, 1-11, 2002), written once for every schedule
(the per-step kernel of step.py, the fused one of fused.py) as functions of values; how
an agent's partners are gathered (the plane grid's cells of side r_a, or all pairs) is
the schedule's.

For agent i at x_i with unit direction e_i, and each other agent j (r_ij = x_j - x_i,
r = |r_ij| > 0; a partner at r = 0, i itself included, has no direction and is skipped):
  r < r_r                           acc_r += (-r_ij / r, 1)           (eq. 1)
  r_r <= r < r_o, e_i.r_ij >= c r   acc_o += (e_j, 1)                 (eq. 2)
  r_o <= r < r_a, e_i.r_ij >= c r   acc_a += (r_ij / r, 1)            (eq. 3)
with c = cos(field_of_view / 2) (the blind cone behind i is not seen; repulsion sees all).
  d = acc_r if any repulsion partner, else (d_o + d_a) / 2 if both (combine "unit": of
      d_o / |d_o| and d_a / |d_a|), else the one present, else e_i; d = e_i also when it
      sums to zero;  d <- d / |d|
  noise: g = sigma sqrt(-2 ln(1 - u1)) cos(2 pi u2) (Box-Muller), d rotated by g (2D:
      counter-clockwise; 3D: towards b = cos(2 pi u3) b1 + sin(2 pi u3) b2, (b1, b2) an
      orthonormal frame normal to d from the axis least aligned with d)
  turn: e_i' = d if e_i.d >= cos(theta tau), else cos(theta tau) e_i + sin(theta tau) w,
      w the unit part of d normal to e_i (d = -e_i: w from the frame above); e_i'
      normalised
  move: x_i' = x_i + s tau e_i'.
u1, u2, u3: the counter-based uniforms of streams 0, 1, 2 at (seed, step, agent id).
"""

import math

import numpy as np
import taichi as ti

from ...space import rng
from ...space.params import Slots

# Runtime parameters: r_r^2, r_o^2, r_a^2, cos(alpha / 2) (-2 at alpha = 360: every
# partner seen, whatever the rounding), s tau, cos and sin of theta tau, sigma, 1 when
# d_o and d_a are made unit vectors before they are averaged (`combine: "unit"`).
P = Slots("RR2", "RO2", "RA2", "COS_VIEW", "STEP", "COS_TURN", "SIN_TURN", "SIGMA", "UNIT")
STREAMS = 3  # u1, u2 (the Gaussian), u3 (3D: the rotation's azimuth)
ACC = 3  # zone sums: repulsion, orientation, attraction, each (vector, count)
DIVERGED_CAUSE = "a position or direction became non-finite"


def parameters(p, dt: float) -> np.ndarray:
    """The runtime parameter vector of model block `p` at time step dt."""
    turn = p.max_turn * dt
    view = -2.0 if p.field_of_view >= 360.0 else math.cos(math.radians(p.field_of_view) / 2)
    return P.pack(RR2=p.r_r ** 2, RO2=p.r_o ** 2, RA2=p.r_a ** 2, COS_VIEW=view,
                  STEP=p.speed * dt, COS_TURN=math.cos(turn), SIN_TURN=math.sin(turn),
                  SIGMA=p.sigma, UNIT=float(p.combine == "unit"))


def step_keys(seed: int, step: int) -> np.ndarray:
    """The noise keys of one step (streams 0, 1, 2), as uint32."""
    return np.array([rng.step_key(seed, s, step) for s in range(STREAMS)], dtype=np.uint32)


@ti.func
def load(prm: ti.template()):
    """The parameter vector q from a (P.size,) array."""
    return ti.Vector([prm[c] for c in ti.static(range(P.size))], dt=float)


@ti.func
def zero_acc(dim: ti.template()):
    """Empty zone sums: ACC blocks of (dim components, count)."""
    return ti.Vector.zero(float, ACC * (dim + 1))


@ti.func
def zone_term(acc, d, ej, ei, q):
    """acc plus partner j's term (eqs. 1-3), d = x_j - x_i, ej its direction."""
    dim = ti.static(d.n)
    w = ti.static(dim + 1)
    r2 = d.dot(d)
    if r2 > 0.0 and r2 < q[P.RA2]:
        r = ti.sqrt(r2)
        if r2 < q[P.RR2]:
            for c in ti.static(range(dim)):
                acc[c] -= d[c] / r
            acc[dim] += 1.0
        elif ei.dot(d) >= q[P.COS_VIEW] * r:
            if r2 < q[P.RO2]:
                for c in ti.static(range(dim)):
                    acc[w + c] += ej[c]
                acc[w + dim] += 1.0
            else:
                for c in ti.static(range(dim)):
                    acc[2 * w + c] += d[c] / r
                acc[2 * w + dim] += 1.0
    return acc


@ti.func
def _block(acc, b: ti.template(), dim: ti.template()):
    return ti.Vector([acc[b * (dim + 1) + c] for c in ti.static(range(dim))], dt=float)


@ti.func
def _unit_or_zero(v):
    n2 = v.dot(v)
    out = v
    if n2 > 0.0:
        out = v / ti.sqrt(n2)
    return out


@ti.func
def desired(acc, ei, q):
    """The desired direction d / |d| from the zone sums (e_i when there is none)."""
    dim = ti.static(ei.n)
    w = ti.static(dim + 1)
    d = ei
    if acc[dim] > 0.0:
        d = _block(acc, 0, dim)
    elif acc[w + dim] > 0.0 and acc[2 * w + dim] > 0.0:
        do = _block(acc, 1, dim)
        da = _block(acc, 2, dim)
        if q[P.UNIT] != 0.0:  # each zone's pull counts once, not once per partner
            do = _unit_or_zero(do)
            da = _unit_or_zero(da)
        d = 0.5 * (do + da)
    elif acc[w + dim] > 0.0:
        d = _block(acc, 1, dim)
    elif acc[2 * w + dim] > 0.0:
        d = _block(acc, 2, dim)
    n2 = d.dot(d)
    out = ei
    if n2 > 0.0:
        out = d / ti.sqrt(n2)
    return out


@ti.func
def normal(m):
    """A unit vector normal to the unit vector m (2D: m turned by +90 degrees; 3D: from the
    axis least aligned with m) and, in 3D, a second one completing the frame."""
    b1 = ti.Vector.zero(float, m.n)
    b2 = ti.Vector.zero(float, m.n)
    if ti.static(m.n == 2):
        b1 = ti.Vector([-m[1], m[0]], dt=float)
    else:
        axis = ti.math.vec3(1.0, 0.0, 0.0)
        if ti.abs(m[0]) > 0.5:
            axis = ti.math.vec3(0.0, 1.0, 0.0)
        b1 = ti.math.normalize(axis - axis.dot(m) * m)
        b2 = m.cross(b1)
    return b1, b2


@ti.func
def perturb(d, u1, u2, u3, sigma):
    """d rotated by the wrapped-Gaussian angle g = sigma N(0, 1) (Box-Muller from u1, u2);
    3D: towards the normal direction at azimuth 2 pi u3."""
    g = sigma * ti.sqrt(-2.0 * ti.log(1.0 - u1)) * ti.cos(2.0 * math.pi * u2)
    b1, b2 = normal(d)
    b = b1
    if ti.static(d.n == 3):
        phi = 2.0 * math.pi * u3
        b = ti.cos(phi) * b1 + ti.sin(phi) * b2
    return ti.cos(g) * d + ti.sin(g) * b


@ti.func
def turn(ei, d, q):
    """e_i turned towards d by at most theta tau."""
    c = ei.dot(d)
    out = d
    if c < q[P.COS_TURN]:
        w = d - c * ei
        n2 = w.dot(w)
        if n2 > 0.0:
            w = w / ti.sqrt(n2)
        else:  # d = -e_i: any normal direction
            b1, _b2 = normal(ei)
            w = b1
        out = q[P.COS_TURN] * ei + q[P.SIN_TURN] * w
    return out / out.norm()


@ti.func
def agent_step(xi, ei, acc, agent, keys, q):
    """(x_i', e_i') from agent i's zone sums; keys: the step's three noise keys."""
    d = desired(acc, ei, q)
    if q[P.SIGMA] > 0.0:
        u3 = 0.0
        if ti.static(ei.n == 3):
            u3 = rng.uniform(keys[2], agent)
        d = perturb(d, rng.uniform(keys[0], agent), rng.uniform(keys[1], agent), u3,
                    q[P.SIGMA])
    e = turn(ei, d, q)
    return xi + q[P.STEP] * e, e
