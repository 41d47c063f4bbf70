"""Statistics of a state shared by the model families (numpy, on the host)."""

import numpy as np


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
