"""Classic RK4 for the double integrator dr/dt = v, dv/dt = u(r, v) (paper 000 eq. 1).

With y = (r, v) and f(y) = (v, u(r, v)):
  k1 = f(y0), k2 = f(y0 + h/2 k1), k3 = f(y0 + h/2 k2), k4 = f(y0 + h k3),
  y1 = y0 + h/6 (k1 + 2 k2 + 2 k3 + k4).
The caller evaluates u at each stage state (xs, vs) into `a`; `rk4_stage` adds the stage's
k = (vs, a) with weight w to the sums (xk, vk) and moves (xs, vs) to y0 + c k for the next
stage; `rk4_finish` adds k4 and writes y1. Semi-implicit Euler, the default, is fused into
the force kernels (kernels/models/flocking/forces.py).
"""

import taichi as ti

nd = ti.types.ndarray()


@ti.kernel
def rk4_begin(x0: nd, v0: nd, xs: nd, vs: nd, xk: nd, vk: nd):
    """Stage state y0, sums zero."""
    for i in range(x0.shape[0]):
        for c in ti.static(range(2)):
            xs[i, c] = x0[i, c]
            vs[i, c] = v0[i, c]
            xk[i, c] = 0.0
            vk[i, c] = 0.0


@ti.kernel
def rk4_stage(x0: nd, v0: nd, xs: nd, vs: nd, a: nd, xk: nd, vk: nd, w: ti.f64, c: ti.f64):
    """(xk, vk) += w (vs, a); (xs, vs) <- (x0 + c vs, v0 + c a)."""
    for i in range(x0.shape[0]):
        for m in ti.static(range(2)):
            xk[i, m] += w * vs[i, m]
            vk[i, m] += w * a[i, m]
            xs[i, m] = x0[i, m] + c * vs[i, m]
            vs[i, m] = v0[i, m] + c * a[i, m]


@ti.kernel
def rk4_finish(x0: nd, v0: nd, vs: nd, a: nd, xk: nd, vk: nd, x_out: nd, v_out: nd,
               h6: ti.f64, bad: nd):
    """y1 = y0 + h/6 (k1 + 2 k2 + 2 k3 + k4), with k4 = (vs, a)."""
    for i in range(x0.shape[0]):
        s = 0.0
        for m in ti.static(range(2)):
            x_out[i, m] = x0[i, m] + h6 * (xk[i, m] + vs[i, m])
            v_out[i, m] = v0[i, m] + h6 * (vk[i, m] + a[i, m])
            s += x_out[i, m] + v_out[i, m]
        if ti.math.isnan(s) or ti.math.isinf(s):
            ti.atomic_add(bad[0], 1)


@ti.kernel
def gather_rows(src: nd, dst: nd, perm: nd):
    """dst[i, :] = src[perm[i], :] (undo a grid permutation)."""
    for i in range(dst.shape[0]):
        for m in range(src.shape[1]):
            dst[i, m] = src[perm[i], m]
