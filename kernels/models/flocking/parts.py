"""What a flock's parts (radius.py, mission.py) read of the flock they plug into.

The parts are handed the whole `kernel.Flock`; this protocol names the few attributes
they use, so a part depends on this, not on the kernel that imports it.
"""

from __future__ import annotations

from typing import Any, Protocol

import taichi as ti

from ...space.plane_grid import PlaneGrid
from ...space.state import SortedState


class FlockView(Protocol):
    """The flock as its parts see it."""

    n: int  # agents
    dim: int  # space dimension
    p: Any  # the model's parameters (FlockingParams or ObstacleFlockingParams)
    a: float  # the pair potential's coefficients (eq. 3)
    c: float
    state: SortedState  # positions, velocities (and radii) in grid order
    mission: Any  # the mission part (NoMission or Mission)
    flags: dict[str, Any]  # compile-time choices of the grid kernels
    grid: PlaneGrid
    prm: ti.Ndarray  # the force parameters (forces.P)

    def search(self, grid: PlaneGrid) -> str: ...



