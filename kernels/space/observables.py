"""Statistics of a state shared by the model families: the heading spread on the circle,
on the host (numpy) and in Taichi (the fused schedules' observation pass, the per-step
kernels' buckets).

The spread is the length of the shortest arc holding every heading: 2 pi minus the
largest gap between consecutive headings on the circle. In Taichi it needs no sort:
n headings in n equal buckets of [0, 2 pi) keep each bucket's min and max, and by
pigeonhole the largest gap lies between buckets (exact, O(n)).
"""

import numpy as np
import taichi as ti

TWO_PI = 2 * np.pi


def circular_spread(theta: np.ndarray, overwrite: bool = False) -> float:
    """Length of the shortest arc holding every heading: 2 pi minus the largest gap.
    `overwrite`: reduce and sort `theta` in place (no N-sized temporary; same value)."""
    a = np.mod(theta, 2 * np.pi, out=theta if overwrite else None)
    a.sort()
    if a.size < 2:
        return 0.0
    gap = np.max([np.diff(a[k:k + 65537]).max() for k in range(0, a.size - 1, 65536)])
    wrap = a[0] + 2 * np.pi - a[-1]
    return float(2 * np.pi - max(gap, wrap))


@ti.func
def on_circle(th):
    """th mod 2 pi, in [0, 2 pi) (the subtraction can round up to 2 pi itself)."""
    a = th - TWO_PI * ti.floor(th / TWO_PI)
    if a >= TWO_PI:
        a -= TWO_PI
    return a


@ti.func
def arc_bucket(a, nb):
    """The bucket of the angle a in [0, 2 pi) among nb equal ones."""
    return ti.min(ti.cast(a / TWO_PI * nb, ti.i32), nb - 1)


@ti.func
def largest_gap(b0, nb, lo: ti.template(), hi: ti.template()):
    """The largest gap on the circle between the extremes of consecutive non-empty
    buckets b0 .. b0 + nb - 1 (lo <= hi where not empty), the wrap-around one included.
    Serial."""
    first = ti.math.inf
    last = -ti.math.inf
    gap = 0.0
    for b in range(b0, b0 + nb):
        if lo[b] <= hi[b]:
            if last > -ti.math.inf:
                gap = ti.max(gap, lo[b] - last)
            else:
                first = lo[b]
            last = hi[b]
    return ti.max(gap, first + TWO_PI - last)


def make_circular_spread(heading):
    """`spread(a0, n, lo, hi, S)`: the spread of the headings `heading(k, S)` (an angle)
    of slots a0 .. a0 + n - 1, serially in one task (a fused replica's), with lo and hi
    (rows a0 .. a0 + n) as its n buckets; 0 under two headings."""

    @ti.func
    def spread(a0, n, lo: ti.template(), hi: ti.template(), S: ti.template()):
        res = 0.0
        if n >= 2:
            for k in range(a0, a0 + n):
                lo[k] = ti.math.inf
                hi[k] = -ti.math.inf
            for i in range(a0, a0 + n):
                a = on_circle(heading(i, S))
                k = a0 + arc_bucket(a, n)
                lo[k] = ti.min(lo[k], a)
                hi[k] = ti.max(hi[k], a)
            res = TWO_PI - largest_gap(a0, n, lo, hi)
        return res

    return spread
