"""Classic RK4 in stage form, for any system y' = f(y) of (N, C) float64 arrays.

  k1 = f(y0), k2 = f(y0 + h/2 k1), k3 = f(y0 + h/2 k2), k4 = f(y0 + h k3),
  y1 = y0 + h/6 (k1 + 2 k2 + 2 k3 + k4).

`rk4_begin` sets the stage state ys = y0 and the sum yk = 0. The caller evaluates f at ys
into k; `rk4_stage` adds w k to yk (w = 1, 2, 2) and moves ys to y0 + c k for the next
stage (c = h/2, h/2, h); after the fourth evaluation `rk4_finish` writes y1. The sums run
in the order above, so y1 has the same bits as the formula written out.

The double integrator dr/dt = v, dv/dt = u(r, v) of M2/M3 (paper 000 eq. 1) is the pair
y = (r, v), f = (v, u): its position stage takes the stage velocity as k and must run
before the velocity stage moves it (`rk4_stage(r0, rs, vs, ...)`, then
`rk4_stage(v0, vs, u, ...)`). M4's single integrator r' = u(r) is one array. Semi-implicit
Euler, the default, is fused into the force kernels of each family.
"""

import taichi as ti

nd = ti.types.ndarray()


@ti.kernel
def rk4_begin(y0: nd, ys: nd, yk: nd):
    """Stage state y0, sum zero."""
    for i in range(y0.shape[0]):
        for c in range(y0.shape[1]):
            ys[i, c] = y0[i, c]
            yk[i, c] = 0.0


@ti.kernel
def rk4_stage(y0: nd, ys: nd, k: nd, yk: nd, w: float, c: float):
    """yk += w k; ys <- y0 + c k."""
    for i in range(y0.shape[0]):
        for m in range(y0.shape[1]):
            yk[i, m] += w * k[i, m]
            ys[i, m] = y0[i, m] + c * k[i, m]


@ti.kernel
def rk4_finish(y0: nd, k: nd, yk: nd, h6: float, y_out: nd):
    """y1 = y0 + h/6 (k1 + 2 k2 + 2 k3 + k4), with k4 = k."""
    for i in range(y0.shape[0]):
        for m in range(y0.shape[1]):
            y_out[i, m] = y0[i, m] + h6 * (yk[i, m] + k[i, m])


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
def count_nonfinite_pairs(a: nd, b: nd, bad: nd):
    """bad[0] += the rows i where a[i] or b[i] holds a NaN or an infinity."""
    for i in range(a.shape[0]):
        s = 0.0
        for m in range(a.shape[1]):
            s += a[i, m] + b[i, m]
        if ti.math.isnan(s) or ti.math.isinf(s):
            ti.atomic_add(bad[0], 1)


@ti.kernel
def gather_rows(src: nd, dst: nd, perm: nd):
    """dst[i, :] = src[perm[i], :] (undo a grid permutation)."""
    for i in range(dst.shape[0]):
        for m in range(src.shape[1]):
            dst[i, m] = src[perm[i], m]
