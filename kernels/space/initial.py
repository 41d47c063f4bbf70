"""Initial state as numpy arrays in agent-id order, from the scenario's initial block."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flocklab.schemas import ExplicitInitial, PeriodicBox, Scenario


@dataclass
class InitialState:
    positions: np.ndarray  # (N, 2) float64
    headings: np.ndarray  # (N,) float64
    velocities: np.ndarray  # (N, 2) float64


def initial_state(scenario: Scenario) -> InitialState:
    """Positions, headings and velocities. Random draws use numpy's PCG64 seeded with the
    scenario seed, in a fixed order (positions, headings, speeds)."""
    init = scenario.initial
    space = scenario.space
    if isinstance(init, ExplicitInitial):
        pos = np.asarray(init.positions, dtype=np.float64).reshape(-1, 2)
        if init.velocities is not None:
            vel = np.asarray(init.velocities, dtype=np.float64).reshape(-1, 2)
        else:
            vel = np.zeros_like(pos)
        if init.headings is not None:
            head = np.asarray(init.headings, dtype=np.float64)
        else:
            head = np.arctan2(vel[:, 1], vel[:, 0])
    else:
        rng = np.random.default_rng(scenario.seed)
        n = init.N
        region = init.region
        if region is None:  # the whole periodic box (validated: only allowed there)
            assert isinstance(space, PeriodicBox)
            pos = rng.uniform(0.0, space.L, size=(n, 2))
        elif region.kind == "box":
            pos = rng.uniform(region.low, region.high, size=(n, 2))
        elif region.kind == "lattice":
            side = math.ceil(math.sqrt(n))
            k = np.arange(n)
            grid = np.stack([k % side, k // side], axis=1).astype(np.float64)
            jitter = rng.uniform(-region.jitter, region.jitter, size=(n, 2))
            pos = np.asarray(region.low) + region.spacing * (grid + jitter)
        else:
            rad = region.radius * np.sqrt(rng.uniform(size=n))
            ang = rng.uniform(-np.pi, np.pi, size=n)
            pos = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1) + region.center
        head = rng.uniform(init.heading_range[0], init.heading_range[1], size=n)
        speed = rng.uniform(init.speed_range[0], init.speed_range[1], size=n)
        vel = np.stack([speed * np.cos(head), speed * np.sin(head)], axis=1)
    if isinstance(space, PeriodicBox):
        pos = np.mod(pos, space.L)
        pos[pos >= space.L] -= space.L  # np.mod can round up to L itself
    return InitialState(pos.copy(), head.copy(), vel.copy())
