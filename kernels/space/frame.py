"""The frame of a point-mass state (position r_i, velocity v_i): the arrays a run records
for the double-integrator families (flocking, Cucker–Smale), on every schedule.

  position  r_i,
  velocity  v_i,
  heading   atan2(v_y, v_x) in 2D; in 3D the unit velocity v_i / |v_i| ((1, 0, 0) where
            v_i = 0, as atan2(0, 0) = 0).
"""

from collections.abc import Callable

import numpy as np

from .initial import unit_rows


def point_mass_frame(pos: Callable[[], np.ndarray], vel: Callable[[], np.ndarray],
                     arrays: list[str], dim: int) -> dict[str, np.ndarray]:
    """The named `arrays` of the state whose (N, dim) rows in agent-id order `pos()` and
    `vel()` give (each read only when an array needs it, once)."""
    out = {}
    if "position" in arrays:
        out["position"] = pos()
    if "velocity" in arrays or "heading" in arrays:
        v = vel()
        if "velocity" in arrays:
            out["velocity"] = v
        if "heading" in arrays:
            out["heading"] = unit_rows(v) if dim == 3 else np.arctan2(v[:, 1], v[:, 0])
    return out
