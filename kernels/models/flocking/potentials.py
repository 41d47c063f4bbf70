"""Pair potentials behind one interface, as Taichi functions of the squared distance.

Every potential here has the form V(s) = a / s^2 + ln s^2 + c (Definition 2 of paper 000:
nonnegative, infinite at s = 0, unique minimum at s = sqrt(a)); `schemas.flocking.
PotentialSpec.coefficients` gives (a, c): log_barrier (d/s)^2 + ln (s/d)^2 is (d^2, -ln d^2),
paper 002's 1/s^2 + log s^2 is (1, 0). A potential of another form adds its own pair of
functions here and a static switch where the kernels call them.

The force on agent i from j is -grad_{r_i} V(|r_ij|) = (V'(s) / s) (r_j - r_i), and
V'(s) / s = 2 / s^2 - 2 a / s^4 needs no square root.
"""

import taichi as ti


@ti.func
def value(s2, a, c):
    """V(s) from s^2."""
    return a / s2 + ti.log(s2) + c


@ti.func
def force_factor(s2, a):
    """V'(s) / s from s^2: the force on i is force_factor * (r_j - r_i)."""
    inv = 1.0 / s2
    return 2.0 * inv * (1.0 - a * inv)
