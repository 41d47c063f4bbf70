"""numpy-side observables of Couzin's model, at observation steps only, from the device
arrays read a block of rows at a time (kernels/space/stream.py): no N-sized host copy.

  polarization  p = |sum_i e_i| / N                        (the paper's group polarization)
  milling       m = |sum_i u_ic x e_i| / N, u_ic = (x_i - c) / |x_i - c|, c the mean
                position (the paper's group angular momentum; 2D: |z component|; an agent
                at c itself adds nothing)
"""

from __future__ import annotations

import numpy as np

from ...space.stream import Rows, RowSum, blocks


def cross(u: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Row-wise u x e: 2D its z component (N, 1), 3D (N, 3)."""
    if u.shape[1] == 2:
        return (u[:, 0] * e[:, 1] - u[:, 1] * e[:, 0])[:, None]
    return np.cross(u, e)


def observe(pos, ew) -> dict[str, float]:
    """polarization and milling of the state (pos, ew: (N, dim) device arrays, any order)."""
    n = pos.shape[0]
    prow, erow = Rows(pos), Rows(ew)
    centre = RowSum()
    heading = RowSum()
    for lo, hi in blocks(n):
        centre.add(prow.wide(lo, hi))
        heading.add(erow.wide(lo, hi))
    c = centre.total() / n
    spin = RowSum()
    for lo, hi in blocks(n):
        r = prow.wide(lo, hi) - c
        norm = np.sqrt(np.einsum("ak,ak->a", r, r))
        u = np.divide(r, norm[:, None], out=np.zeros_like(r), where=norm[:, None] > 0)
        spin.add(cross(u, erow.wide(lo, hi)))
    return {"polarization": float(np.linalg.norm(heading.total())) / n,
            "milling": float(np.linalg.norm(spin.total())) / n}
