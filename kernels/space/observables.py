"""Statistics of a state shared by the model families (numpy, on the host)."""

import numpy as np


def circular_spread(theta: np.ndarray) -> float:
    """Length of the shortest arc holding every heading: 2 pi minus the largest gap."""
    a = np.sort(np.mod(theta, 2 * np.pi))
    if a.size < 2:
        return 0.0
    gaps = np.diff(a)
    wrap = a[0] + 2 * np.pi - a[-1]
    return float(2 * np.pi - max(gaps.max(), wrap))
