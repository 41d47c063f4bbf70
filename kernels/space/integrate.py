"""Classic RK4 in stage form, for any system y' = f(y) of (N, C) float64 arrays.

  k1 = f(y0), k2 = f(y0 + h/2 k1), k3 = f(y0 + h/2 k2), k4 = f(y0 + h k3),
  y1 = y0 + h/6 (k1 + 2 k2 + 2 k3 + k4).

`rk4_begin` sets the stage state ys = y0 and the sum yk = 0. The caller evaluates f at ys
into k; `rk4_stage` adds w k to yk (w = 1, 2, 2) and moves ys to y0 + c k for the next
stage (c = h/2, h/2, h); after the fourth evaluation `rk4_finish` writes y1. The sums run
in the order above, so y1 has the same bits as the formula written out.

The double integrator dr/dt = v, dv/dt = u(r, v) of M2/M3 (paper 000 eq. 1) is the pair
y = (r, v), f = (v, u), moved by the `_pair` kernels (one launch for both arrays: a small
run's step is mostly launches): its position stage takes the stage velocity as k and reads
it before the velocity stage moves it; `rk4_pair_step` is that step of a family's u (flocking,
Cucker–Smale). M4's single integrator r' = u(r) is one array.
The arithmetic of a stage and of the finish is written once, on values (`stage_value`,
`finish_value`, and for the pair `stage_pair` / `finish_pair`, over STAGES): these kernels
apply it to array entries, the fused schedules (one replica per CPU task) to an agent's
vectors, so every schedule's RK4 is the same sums.
Semi-implicit Euler, the default, is fused into the force kernels of each family;
`nonfinite` is their test of a step's result.
"""

from collections.abc import Callable
from typing import Any

import taichi as ti

nd = ti.types.ndarray()
# The stages after k1: (weight w of the k just evaluated in the sum, the next stage's step
# c as a fraction of h): c = h/2, h/2, h (h * 0.5 is h / 2 exactly).
STAGES = ((1.0, 0.5), (2.0, 0.5), (2.0, 1.0))


@ti.func
def stage_value(y0, k, yk, w, c):
    """One stage on values (scalars or vectors): (yk + w k, y0 + c k), the sum so far and
    the next stage state."""
    return yk + w * k, y0 + c * k


@ti.func
def finish_value(y0, k, yk, h6):
    """y1 = y0 + h/6 (yk + k4), k = k4."""
    return y0 + h6 * (yk + k)


@ti.func
def stage_pair(r0, v0, vs, u, rk, vk, w, c):
    """One stage of (r, v)' = (v, u) on an agent's values: (rs, vs, rk, vk) of the next
    stage, the position's k the stage velocity vs (read before vs moves)."""
    rk1, rs1 = stage_value(r0, vs, rk, w, c)
    vk1, vs1 = stage_value(v0, u, vk, w, c)
    return rs1, vs1, rk1, vk1


@ti.func
def finish_pair(r0, v0, vs, u, rk, vk, h6):
    """(r1, v1) of (r, v)' = (v, u) from the last stage (vs, u) and the sums (rk, vk)."""
    return finish_value(r0, vs, rk, h6), finish_value(v0, u, vk, h6)


@ti.func
def _begin(y0: ti.template(), ys: ti.template(), yk: ti.template(), i, m):
    ys[i, m] = y0[i, m]
    yk[i, m] = 0.0


@ti.func
def _stage(y0: ti.template(), ys: ti.template(), k: ti.template(), yk: ti.template(), w, c,
           i, m):
    yk[i, m], ys[i, m] = stage_value(y0[i, m], k[i, m], yk[i, m], w, c)


@ti.func
def _finish(y0: ti.template(), k: ti.template(), yk: ti.template(), h6, y_out: ti.template(),
            i, m):
    y_out[i, m] = finish_value(y0[i, m], k[i, m], yk[i, m], h6)


@ti.kernel
def rk4_begin(y0: nd, ys: nd, yk: nd):
    """Stage state y0, sum zero."""
    for i in range(y0.shape[0]):
        for m in range(y0.shape[1]):
            _begin(y0, ys, yk, i, m)


@ti.kernel
def rk4_stage(y0: nd, ys: nd, k: nd, yk: nd, w: float, c: float):
    """yk += w k; ys <- y0 + c k."""
    for i in range(y0.shape[0]):
        for m in range(y0.shape[1]):
            _stage(y0, ys, k, yk, w, c, i, m)


@ti.kernel
def rk4_finish(y0: nd, k: nd, yk: nd, h6: float, y_out: nd):
    """y1 = y0 + h/6 (k1 + 2 k2 + 2 k3 + k4), with k4 = k."""
    for i in range(y0.shape[0]):
        for m in range(y0.shape[1]):
            _finish(y0, k, yk, h6, y_out, i, m)


@ti.kernel
def rk4_begin_pair(r0: nd, rs: nd, rk: nd, v0: nd, vs: nd, vk: nd):
    """rk4_begin for r and for v."""
    for i in range(r0.shape[0]):
        for m in range(r0.shape[1]):
            _begin(r0, rs, rk, i, m)
            _begin(v0, vs, vk, i, m)


@ti.kernel
def rk4_stage_pair(r0: nd, rs: nd, rk: nd, v0: nd, vs: nd, vk: nd, u: nd, w: float,
                   c: float):
    """rk4_stage for (r, v)' = (v, u): r's with k = vs, read before v's (k = u) moves vs."""
    for i in range(r0.shape[0]):
        for m in range(r0.shape[1]):
            _stage(r0, rs, vs, rk, w, c, i, m)
            _stage(v0, vs, u, vk, w, c, i, m)


@ti.kernel
def rk4_finish_pair(r0: nd, rk: nd, v0: nd, vs: nd, vk: nd, u: nd, h6: float, r_out: nd,
                    v_out: nd, bad: nd):
    """rk4_finish for r (k4 = vs) and for v (k4 = u); bad[0] += the rows where either
    holds a NaN or an infinity."""
    for i in range(r0.shape[0]):
        s = 0.0
        for m in range(r0.shape[1]):
            _finish(r0, vs, rk, h6, r_out, i, m)
            _finish(v0, u, vk, h6, v_out, i, m)
            s += r_out[i, m] + v_out[i, m]  # NaN if any term is NaN or infinite
        if ti.math.isnan(s) or ti.math.isinf(s):
            ti.atomic_add(bad[0], 1)


@ti.func
def nonfinite(x, v):
    """1 if the dim-vectors x or v (a state's position and velocity, say) hold a NaN or an
    infinity, else 0: their sum does then."""
    s = x[0] + x[1] + v[0] + v[1]
    if ti.static(x.n == 3):
        s += x[2] + v[2]
    return ti.cast(ti.math.isnan(s) or ti.math.isinf(s), ti.i32)


@ti.func
def put_pair(pos: ti.template(), vel: ti.template(), i, x, v):
    """Row i of the state (pos, vel) set to (x, v); `nonfinite(x, v)`."""
    pos[i] = x
    vel[i] = v
    return nonfinite(x, v)


@ti.kernel
def count_nonfinite(a: nd, bad: nd):
    """bad[0] += the rows of `a` holding a NaN or an infinity."""
    for i in range(a.shape[0]):
        s = 0.0
        for m in range(a.shape[1]):
            s += a[i, m]  # NaN if any term is NaN or infinite
        if ti.math.isnan(s) or ti.math.isinf(s):
            ti.atomic_add(bad[0], 1)


@ti.kernel
def gather_rows(src: nd, dst: nd, perm: nd):
    """dst[i, :] = src[perm[i], :] (undo a grid permutation)."""
    for i in range(dst.shape[0]):
        for m in range(src.shape[1]):
            dst[i, m] = src[perm[i], m]


def rk4_pair_step(x0, v0, b: dict, h: float, accel: Callable[[Any, Any, Any, bool], None],
                  r_out, v_out, bad) -> None:
    """One classical RK4 step of (r, v)' = (v, u(r, v)) into (r_out, v_out), in place of
    the state (x0, v0): k1 at the state, then the stages at h/2, h/2 and h, weights
    1, 2, 2, 1. `accel(pos, vel, out, at_state)` writes u; `b` holds the stage buffers
    xs, xk, vs, vk and a (rk4_begin_pair / rk4_stage_pair / rk4_finish_pair)."""
    rk4_begin_pair(x0, b["xs"], b["xk"], v0, b["vs"], b["vk"])
    accel(x0, v0, b["a"], True)
    for w, f in STAGES:
        rk4_stage_pair(x0, b["xs"], b["xk"], v0, b["vs"], b["vk"], b["a"], w, f * h)
        accel(b["xs"], b["vs"], b["a"], False)
    rk4_finish_pair(x0, b["xk"], v0, b["vs"], b["vk"], b["a"], h / 6, r_out, v_out, bad)
