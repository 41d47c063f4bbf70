"""Initial state as numpy arrays in agent-id order, from the scenario's initial block.

In 3D the state's vectors have three columns, and the random directions are uniform on the
sphere (z uniform in [-1, 1], azimuth uniform: Archimedes' hat-box theorem).

Random draws come from numpy's PCG64 seeded with the scenario seed, one double a value, in
a fixed order: the positions (2D: 2 N, the x and y of each agent in turn, or the lattice's
jitter likewise, or the disc's N radii then N angles; 3D: 3 N, the ball's N radii, N z
and N azimuths of the directions), then the headings (N; 3D: the directions, N z then N
azimuths), then the N speeds. Each run of draws has its own generator advanced to its
place in that order (`PCG64.advance`), so an array no model reads is never drawn and none
waits on another: Vicsek's kernel builds positions and headings without velocities, a
flocking kernel positions and velocities without headings (velocities draw their own
headings or directions: a caller may have changed those it read). The bits are those of
one generator drawing everything in order.

Each array is filled a block of agents at a time, with the same operations on the same
operands as whole-array numpy code (the same bits), so building the state at N = 10^6
takes its arrays and no N-sized temporaries (whose freed pages the C allocator would keep
resident beside the device arrays).
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from flocklab.schemas import ExplicitInitial, PeriodicBox, Scenario

from .stream import blocks


def _draws(seed: int, skip: int) -> np.random.Generator:
    """The scenario's generator (= np.random.default_rng(seed)) after `skip` doubles."""
    bits = np.random.PCG64(seed)
    bits.advance(skip)
    return np.random.Generator(bits)


def _polar(r: np.ndarray, angle: np.ndarray, out: np.ndarray) -> None:
    """out[:, 0] = r cos(angle), out[:, 1] = r sin(angle). cos and sin run on contiguous
    arrays, as np.cos(angle) alone would (numpy's vector loops differ from its strided ones
    in the last bit), and only the exact product is written into the strided column."""
    t = np.cos(angle)
    np.multiply(r, t, out=out[:, 0])
    np.sin(angle, out=t)
    np.multiply(r, t, out=out[:, 1])


def _sphere(zs: np.random.Generator, phis: np.random.Generator, out: np.ndarray) -> None:
    """Unit vectors into the rows of `out`: z from `zs`, the azimuth from `phis`."""
    z = zs.uniform(-1.0, 1.0, size=len(out))
    phi = phis.uniform(-np.pi, np.pi, size=len(out))
    out[:, 2] = z
    _polar(np.sqrt(np.maximum(0.0, 1.0 - z * z)), phi, out)


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

    def _rng(self, stream: str, part: int = 0) -> np.random.Generator:
        """The generator at the first draw of `stream` (module docstring's order), or of
        its `part`-th run of N draws."""
        n, d = self.n, self.dim
        skip = {"positions": 0, "headings": d * n, "speeds": (2 * d - 1) * n}[stream]
        return _draws(self.seed, skip + part * n)

    @cached_property
    def positions(self) -> np.ndarray:
        init, d, n = self.init, self.dim, self.n
        if self.explicit:
            return _wrap(np.array(init.positions, dtype=np.float64).reshape(-1, d), self.space)
        region = init.region
        kind = "box" if region is None else region.kind
        low, high = (0.0, self.space.L) if region is None else (None, None)
        if region is not None and kind == "box":
            low, high = region.low, region.high
        side = 0
        if kind == "lattice":
            side = region.side(n) if d == 3 else math.ceil(math.sqrt(n))
        # The runs of N draws: the box's or lattice's rows (one run of d N), or the disc's
        # radii and angles, the ball's radii, z and azimuths.
        runs = [self._rng("positions", k) for k in range(1 if kind in ("box", "lattice")
                                                              else d)]
        pos = np.empty((n, d))
        for lo, hi in blocks(n):
            out, m = pos[lo:hi], hi - lo
            if kind == "box":  # the periodic box when no region is given
                out[:] = runs[0].uniform(low, high, size=(m, d))
            elif kind == "lattice":  # low + spacing (grid point + jitter)
                k = np.arange(lo, hi)
                out[:, 0] = k % side
                if d == 2:
                    out[:, 1] = k // side
                else:
                    out[:, 1] = (k // side) % side
                    out[:, 2] = k // (side * side)
                out += runs[0].uniform(-region.jitter, region.jitter, size=(m, d))
                out *= region.spacing
                out += np.asarray(region.low)
            elif d == 2:  # disc: radius R sqrt(u), the angle uniform
                _polar(region.radius * np.sqrt(runs[0].uniform(size=m)),
                       runs[1].uniform(-np.pi, np.pi, size=m), out)
                out += region.center
            else:  # ball: a uniform direction at radius R u^(1/3) is uniform in volume
                r = region.radius * np.cbrt(runs[0].uniform(size=m))
                _sphere(runs[1], runs[2], out)
                out *= r[:, None]
                out += np.asarray(region.center)
            _wrap(out, self.space)
        return pos

    @cached_property
    def directions(self) -> np.ndarray | None:
        """(N, 3) unit vectors in 3D (the velocities' directions; x where a velocity is
        zero); None in 2D."""
        if self.dim == 2:
            return None
        if self.explicit:
            return unit_rows(self._explicit_velocities())
        return self._directions()

    def _directions(self) -> np.ndarray:
        out = np.empty((self.n, 3))
        zs, phis = self._rng("headings"), self._rng("headings", 1)
        for lo, hi in blocks(self.n):
            _sphere(zs, phis, out[lo:hi])
        return out

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
        """speed times the heading's unit vector (3D: the direction), per agent."""
        if self.explicit:
            return self._explicit_velocities()
        n = self.n
        speeds = self._rng("speeds")
        s_lo, s_hi = self.init.speed_range
        if self.dim == 3:
            vel = self._directions()
            for lo, hi in blocks(n):
                vel[lo:hi] *= speeds.uniform(s_lo, s_hi, size=hi - lo)[:, None]
            return vel
        vel = np.empty((n, 2))
        heads = self._rng("headings")
        h_lo, h_hi = self.init.heading_range
        for lo, hi in blocks(n):
            _polar(speeds.uniform(s_lo, s_hi, size=hi - lo),
                   heads.uniform(h_lo, h_hi, size=hi - lo), vel[lo:hi])
        return vel

    def _explicit_velocities(self) -> np.ndarray:
        init = self.init
        if init.velocities is None:
            return np.zeros((self.n, self.dim))
        return np.array(init.velocities, dtype=np.float64).reshape(-1, self.dim)


def initial_state(scenario: Scenario) -> InitialState:
    """The scenario's initial state (arrays built as they are read)."""
    return InitialState(scenario)


def _wrap(pos: np.ndarray, space) -> np.ndarray:
    """Positions folded into the periodic box [0, L)^dim, in place."""
    if isinstance(space, PeriodicBox):
        np.mod(pos, space.L, out=pos)
        pos[pos >= space.L] -= space.L  # np.mod can round up to L itself
    return pos
