"""Initial state as numpy arrays in agent-id order, from the scenario's initial block.

In 3D the state's vectors have three columns, and the random directions are uniform on the
sphere (z uniform in [-1, 1], azimuth uniform: Archimedes' hat-box theorem)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flocklab.schemas import ExplicitInitial, PeriodicBox, Scenario


@dataclass
class InitialState:
    positions: np.ndarray  # (N, dim) float64
    headings: np.ndarray  # (N,) float64; in 3D the azimuths of `directions`
    velocities: np.ndarray  # (N, dim) float64
    directions: np.ndarray | None = None  # (N, 3) unit vectors, 3D only


def sphere_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """n unit vectors uniform on the sphere (two draws each: z, then the azimuth)."""
    z = rng.uniform(-1.0, 1.0, size=n)
    phi = rng.uniform(-np.pi, np.pi, size=n)
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def unit_rows(v: np.ndarray) -> np.ndarray:
    """Each row of v over its length; a zero row becomes (1, 0, 0), as atan2(0, 0) = 0."""
    norm = np.linalg.norm(v, axis=1)
    out = np.zeros_like(v)
    out[:, 0] = 1.0
    nz = norm > 0
    out[nz] = v[nz] / norm[nz, None]
    return out


def initial_state(scenario: Scenario) -> InitialState:
    """Positions, headings and velocities. Random draws use numpy's PCG64 seeded with the
    scenario seed, in a fixed order (positions, headings, speeds)."""
    init = scenario.initial
    space = scenario.space
    if scenario.dimension == 3:
        return _initial_3d(scenario)
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
    return InitialState(_wrap(pos, space), head.copy(), vel.copy())


def _wrap(pos: np.ndarray, space) -> np.ndarray:
    if isinstance(space, PeriodicBox):
        pos = np.mod(pos, space.L)
        pos[pos >= space.L] -= space.L  # np.mod can round up to L itself
    return pos.copy()


def _initial_3d(scenario: Scenario) -> InitialState:
    """The 3D state: draws in the order positions, directions (z, azimuth), speeds."""
    init = scenario.initial
    space = scenario.space
    if isinstance(init, ExplicitInitial):
        pos = np.asarray(init.positions, dtype=np.float64).reshape(-1, 3)
        if init.velocities is not None:
            vel = np.asarray(init.velocities, dtype=np.float64).reshape(-1, 3)
        else:
            vel = np.zeros_like(pos)
        dirs = unit_rows(vel)
    else:
        rng = np.random.default_rng(scenario.seed)
        n = init.N
        region = init.region
        if region is None:  # the whole periodic cube (validated: only allowed there)
            assert isinstance(space, PeriodicBox)
            pos = rng.uniform(0.0, space.L, size=(n, 3))
        elif region.kind == "box":
            pos = rng.uniform(region.low, region.high, size=(n, 3))
        elif region.kind == "lattice":
            side = region.side(n)
            k = np.arange(n)
            grid = np.stack([k % side, (k // side) % side, k // (side * side)],
                            axis=1).astype(np.float64)
            jitter = rng.uniform(-region.jitter, region.jitter, size=(n, 3))
            pos = np.asarray(region.low) + region.spacing * (grid + jitter)
        else:  # ball: a uniform direction at radius R u^(1/3) is uniform in volume
            rad = region.radius * np.cbrt(rng.uniform(size=n))
            pos = sphere_directions(rng, n) * rad[:, None] + np.asarray(region.center)
        dirs = sphere_directions(rng, n)
        speed = rng.uniform(init.speed_range[0], init.speed_range[1], size=n)
        vel = speed[:, None] * dirs
    head = np.arctan2(dirs[:, 1], dirs[:, 0])
    return InitialState(_wrap(pos, space), head, vel.copy(), dirs)
