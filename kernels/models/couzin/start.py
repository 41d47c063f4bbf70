"""The initial state of Couzin's model on every schedule: positions and unit directions."""

import numpy as np

from flocklab.schemas import Scenario

from ...space.initial import initial_state


def directions(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """The initial positions and unit directions (2D: of the headings; 3D: uniform on the
    sphere, or the explicit velocities' directions)."""
    init = initial_state(scenario)
    if scenario.dimension == 3:
        return init.positions, init.directions
    th = init.headings
    return init.positions, np.stack([np.cos(th), np.sin(th)], axis=1)
