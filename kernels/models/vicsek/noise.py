"""The Vicsek noises' random directions, for every schedule (law.py; docs/MODELS_3D.md)."""

import taichi as ti

from ...space import trig


@ti.func
def cap_turn(m, u1, u2, cap):
    """The unit 3-vector m turned to a direction uniform in the spherical cap around it of
    height cap = 1 - cos(eta/2): 1 - cos t = u1 cap, azimuth 2 pi u2 about m."""
    h = u1 * cap  # 1 - cos t, exact near t = 0 (no 1 - cos^2 cancellation)
    ct = 1.0 - h
    st = ti.sqrt(ti.max(0.0, h * (2.0 - h)))
    # An orthonormal frame (m, b1, b2): b1 from the axis least aligned with m.
    axis = ti.math.vec3(1.0, 0.0, 0.0)
    if ti.abs(m[0]) > 0.5:
        axis = ti.math.vec3(0.0, 1.0, 0.0)
    b1 = ti.math.normalize(axis - axis.dot(m) * m)
    b2 = m.cross(b1)
    # cos and sin of phi = 2 pi u2 as -(cos, sin)(phi - pi): trig.cos_sin's range, and one
    # call instead of libm's two (5 % of a 3D step at 10^6 in a profile).
    cs = -trig.cos_sin(2.0 * ti.math.pi * u2 - ti.math.pi)
    return ct * m + st * (cs[0] * b1 + cs[1] * b2)


@ti.func
def unit_vector(u1, u2, dim: ti.template()):
    """A random unit vector from two uniforms on [0, 1): 2D at angle 2 pi u1 (u2 unused),
    3D uniform on the sphere (Archimedes: z = 2 u1 - 1 uniform, azimuth 2 pi u2). The
    angle as -(cos, sin)(2 pi u - pi), trig.cos_sin's range, as in `cap_turn`."""
    out = ti.Vector.zero(float, dim)
    if ti.static(dim == 2):
        cs = -trig.cos_sin(2.0 * ti.math.pi * u1 - ti.math.pi)
        out = ti.Vector([cs[0], cs[1]])
    else:
        z = 2.0 * u1 - 1.0
        rho = ti.sqrt(ti.max(0.0, 1.0 - z * z))
        cs = -trig.cos_sin(2.0 * ti.math.pi * u2 - ti.math.pi)
        out = ti.Vector([rho * cs[0], rho * cs[1], z])
    return out
