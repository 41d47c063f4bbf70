"""The frame of a point-mass state (position r_i, velocity v_i): the arrays a run records
for the double-integrator families (flocking, Cucker–Smale), on every schedule.

  position  r_i,
  velocity  v_i,
  heading   atan2(v_y, v_x) in 2D; in 3D the unit velocity v_i / |v_i| ((1, 0, 0) where
            v_i = 0, as atan2(0, 0) = 0); or, for a family that holds each agent's unit
            direction e_i beside its speed (Couzin), e_i itself: atan2(e_y, e_x) in 2D.
"""

from collections.abc import Callable

import numpy as np

from .initial import unit_rows


def point_mass_frame(pos: Callable[[], np.ndarray], vel: Callable[[], np.ndarray],
                     arrays: list[str], dim: int,
                     direction: Callable[[], np.ndarray] | None = None
                     ) -> dict[str, np.ndarray]:
    """The named `arrays` of the state whose (N, dim) rows in agent-id order `pos()` and
    `vel()` give (each read only when an array needs it, once); the heading from the unit
    rows `direction()` where given."""
    out = {}
    if "position" in arrays:
        out["position"] = pos()
    if "velocity" in arrays:
        out["velocity"] = vel()
    if "heading" in arrays:
        if direction is not None:
            e = direction()
            out["heading"] = e if dim == 3 else np.arctan2(e[:, 1], e[:, 0])
        else:
            v = out["velocity"] if "velocity" in out else vel()
            out["heading"] = unit_rows(v) if dim == 3 else np.arctan2(v[:, 1], v[:, 0])
    return out
