"""Initial state as numpy arrays in agent-id order, from the scenario's initial block.

In 3D the state's vectors have three columns, and the random directions are uniform on the
sphere (z uniform in [-1, 1], azimuth uniform: Archimedes' hat-box theorem).

Random draws come from numpy's PCG64 seeded with the scenario seed, one double a value, in
a fixed order: positions (2 N in 2D: x and y, the lattice's jitter, or the disc's radius
then angle; 3 N in 3D), then the headings (N; 3D: the directions' z, then their azimuths,
2 N), then the speeds (N). Each array starts its own generator advanced to its place in
that order (`PCG64.advance`), so an array no model reads is never drawn and none waits on
another (velocities draw their own headings or directions: a caller may have changed
those it read): Vicsek's kernel builds positions and headings without velocities, a
flocking kernel positions and velocities without keeping headings; the bits are those of
one generator drawing everything in order. Arrays are built in place where the formula allows
(the same operations on the same operands: the same bits), so at N = 10^6 building the
state needs little beyond the arrays it returns.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from flocklab.schemas import ExplicitInitial, PeriodicBox, Scenario


def _draws(seed: int, skip: int) -> np.random.Generator:
    """The scenario's generator (= np.random.default_rng(seed)) after `skip` doubles."""
    bits = np.random.PCG64(seed)
    bits.advance(skip)
    return np.random.Generator(bits)


def sphere_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """n unit vectors uniform on the sphere (two draws each: z, then the azimuth)."""
    z = rng.uniform(-1.0, 1.0, size=n)
    phi = rng.uniform(-np.pi, np.pi, size=n)
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    out = np.empty((n, 3))
    out[:, 2] = z
    del z
    _polar(rho, phi, out)
    return out


def _polar(r: np.ndarray, angle: np.ndarray, out: np.ndarray) -> None:
    """out[:, 0] = r cos(angle), out[:, 1] = r sin(angle). cos and sin run on contiguous
    arrays, as np.cos(angle) alone would (numpy's vector loops differ from its strided ones
    in the last bit), and only the exact product is written into the strided column."""
    t = np.cos(angle)
    np.multiply(r, t, out=out[:, 0])
    np.sin(angle, out=t)
    np.multiply(r, t, out=out[:, 1])


def unit_rows(v: np.ndarray) -> np.ndarray:
    """Each row of v over its length; a zero row becomes (1, 0, 0), as atan2(0, 0) = 0."""
    norm = np.linalg.norm(v, axis=1)
    out = np.zeros_like(v)
    out[:, 0] = 1.0
    nz = norm > 0
    out[nz] = v[nz] / norm[nz, None]
    return out


class InitialState:
    """Positions (N, dim), headings (N,), velocities (N, dim) and, in 3D, directions (N, 3)
    unit vectors (the headings are then their azimuths), each built on first use.

    `initial_state(scenario)` makes one; a kernel reads the arrays it needs and drops the
    object once its device arrays hold them."""

    def __init__(self, scenario: Scenario):
        self.init = scenario.initial
        self.space = scenario.space
        self.dim = scenario.dimension
        self.seed = scenario.seed
        self.n = scenario.n_agents
        self.explicit = isinstance(self.init, ExplicitInitial)

    def _rng(self, stream: str) -> np.random.Generator:
        """The generator at the first draw of `stream` (module docstring's order)."""
        n, d = self.n, self.dim
        skip = {"positions": 0, "headings": d * n, "speeds": (2 * d - 1) * n}[stream]
        return _draws(self.seed, skip)

    @cached_property
    def positions(self) -> np.ndarray:
        init, d, n = self.init, self.dim, self.n
        if self.explicit:
            pos = np.array(init.positions, dtype=np.float64).reshape(-1, d)
        else:
            rng = self._rng("positions")
            region = init.region
            if region is None:  # the whole periodic box (validated: only allowed there)
                assert isinstance(self.space, PeriodicBox)
                pos = rng.uniform(0.0, self.space.L, size=(n, d))
            elif region.kind == "box":
                pos = rng.uniform(region.low, region.high, size=(n, d))
            elif region.kind == "lattice":
                pos = _lattice(rng, region, n, d)
            elif d == 2:  # disc: radius R sqrt(u), angle uniform
                rad = region.radius * np.sqrt(rng.uniform(size=n))
                ang = rng.uniform(-np.pi, np.pi, size=n)
                pos = np.empty((n, 2))
                _polar(rad, ang, pos)
                pos += region.center
            else:  # ball: a uniform direction at radius R u^(1/3) is uniform in volume
                rad = region.radius * np.cbrt(rng.uniform(size=n))
                pos = sphere_directions(rng, n)
                pos *= rad[:, None]
                pos += np.asarray(region.center)
        return _wrap(pos, self.space)

    @cached_property
    def directions(self) -> np.ndarray | None:
        """(N, 3) unit vectors in 3D (the velocities' directions; x where a velocity is
        zero); None in 2D."""
        if self.dim == 2:
            return None
        if self.explicit:
            return unit_rows(self._explicit_velocities())
        return sphere_directions(self._rng("headings"), self.n)

    @cached_property
    def headings(self) -> np.ndarray:
        if self.dim == 3:
            e = self.directions
            return np.arctan2(e[:, 1], e[:, 0])
        init = self.init
        if not self.explicit:
            lo, hi = init.heading_range
            return self._rng("headings").uniform(lo, hi, size=self.n)
        if init.headings is not None:
            return np.array(init.headings, dtype=np.float64)
        vel = self._explicit_velocities()
        return np.arctan2(vel[:, 1], vel[:, 0])

    @cached_property
    def velocities(self) -> np.ndarray:
        if self.explicit:
            return self._explicit_velocities()
        lo, hi = self.init.speed_range
        speed = self._rng("speeds").uniform(lo, hi, size=self.n)
        if self.dim == 3:
            vel = sphere_directions(self._rng("headings"), self.n)
            vel *= speed[:, None]  # = speed[:, None] * directions, bit for bit
            return vel
        lo, hi = self.init.heading_range
        vel = np.empty((self.n, 2))
        _polar(speed, self._rng("headings").uniform(lo, hi, size=self.n), vel)
        return vel

    def _explicit_velocities(self) -> np.ndarray:
        init = self.init
        if init.velocities is None:
            return np.zeros((self.n, self.dim))
        return np.array(init.velocities, dtype=np.float64).reshape(-1, self.dim)


def initial_state(scenario: Scenario) -> InitialState:
    """The scenario's initial state (arrays built as they are read)."""
    return InitialState(scenario)


def _lattice(rng: np.random.Generator, region, n: int, d: int) -> np.ndarray:
    """low + spacing (grid + jitter): the k-th agent at grid point (k % side, k // side)
    (3D: (k % side, (k // side) % side, k // side^2)), jitter uniform in +-jitter."""
    side = math.ceil(math.sqrt(n)) if d == 2 else region.side(n)
    k = np.arange(n)
    pos = np.empty((n, d))
    pos[:, 0] = k % side
    if d == 2:
        pos[:, 1] = k // side
    else:
        pos[:, 1] = (k // side) % side
        pos[:, 2] = k // (side * side)
    del k
    pos += rng.uniform(-region.jitter, region.jitter, size=(n, d))
    pos *= region.spacing
    pos += np.asarray(region.low)
    return pos


def _wrap(pos: np.ndarray, space) -> np.ndarray:
    """Positions folded into the periodic box [0, L)^dim, in place."""
    if isinstance(space, PeriodicBox):
        np.mod(pos, space.L, out=pos)
        pos[pos >= space.L] -= space.L  # np.mod can round up to L itself
    return pos
