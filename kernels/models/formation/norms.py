"""Row lengths of 2- or 3-column arrays, the one place the formation family takes a norm.

2D keeps `np.hypot` (the bits of every 2D run predate 3D); 3D takes the square root of the
sum of squares.
"""

import numpy as np


def norms(a: np.ndarray) -> np.ndarray:
    """|a| along the last axis, for a last axis of 2 or 3."""
    if a.shape[-1] == 2:
        return np.hypot(a[..., 0], a[..., 1])
    return np.sqrt(a[..., 0] * a[..., 0] + a[..., 1] * a[..., 1] + a[..., 2] * a[..., 2])
