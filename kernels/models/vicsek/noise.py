"""The 3D Vicsek noise, shared by the per-step and the fused kernels (docs/MODELS_3D.md)."""

import taichi as ti


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
    phi = 2.0 * ti.math.pi * u2
    return ct * m + st * (ti.cos(phi) * b1 + ti.sin(phi) * b2)
