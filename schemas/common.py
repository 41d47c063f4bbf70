"""Blocks common to every scenario: space, neighbours, initial state, time, recording, backend."""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

from pydantic import Field, StrictBool, StrictInt, ValidationInfo, field_validator, model_validator

from .base import (
    MAX_ABS_COORD,
    NonNegativeInt,
    NonNegativePair,
    Point,
    PositiveInt,
    PositiveReal,
    Real,
    RealPair,
    Strict,
    Vec2,
    Vec3,
)

MAX_AGENTS = 50_000_000
# Steps, and every "every k steps" count, at most this (the kernels take them as int32).
MAX_STEPS = 10**9
# 2: the plane and the square box (the papers' setting); 3: space and the cube.
Dimension = Literal[2, 3]
DIMENSION_DOC = "Spatial dimension: 2 (default) or 3."
# Topological neighbourhoods hold k neighbour slots an agent: k at most this.
MAX_TOPOLOGICAL_K = 1024


class PeriodicBox(Strict):
    """A square periodic box [0, L)^2 (Vicsek's setting), or in 3D the cube [0, L)^3;
    positions are wrapped into it."""

    kind: Literal["periodic"] = "periodic"
    L: PositiveReal = Field(description="Side length of the periodic box (length units).")
    dimension: Dimension = Field(default=2, description=DIMENSION_DOC)


class Plane(Strict):
    """The unbounded plane (the control papers), or in 3D unbounded space. The neighbour
    grid follows the swarm."""

    kind: Literal["plane"] = "plane"
    dimension: Dimension = Field(default=2, description=DIMENSION_DOC)


Space = Annotated[PeriodicBox | Plane, Field(discriminator="kind")]


class Neighbours(Strict):
    """Who interacts with whom. kind "metric" (the default): N_i = {j : |r_ij| < radius} (or
    <= radius). kind "topological" (Ballerini et al., PNAS 105, 1232, 2008): N_i = the k
    nearest other agents (minimum image in the periodic box; equal distances ordered by
    agent id), only those within `radius` when it is given; `symmetric` makes the graph
    undirected (i ~ j when either is among the other's k)."""

    kind: Literal["metric", "topological"] = Field(
        default="metric",
        description="metric: every agent within the radius; topological: the k nearest "
        "(metric-free, Ballerini et al. 2008), for the models whose card lists it.",
    )
    radius: PositiveReal | None = Field(
        default=None,
        description="Interaction radius (r, R or d in the papers); required for kind "
        "metric. Topological: an optional cap, only agents within it count.",
    )
    inclusive: StrictBool | None = Field(
        default=None,
        description="True: |r_ij| <= radius ('in or on' the circle); False: strict <. "
        "null: the paper's own choice for the model.",
    )
    k: StrictInt | None = Field(
        default=None, ge=1, le=MAX_TOPOLOGICAL_K,
        description="Topological: the number of nearest other agents each agent follows "
        "(Ballerini et al.: 6-7); with N <= k every other agent is a neighbour.",
    )
    symmetric: StrictBool = Field(
        default=False,
        description="Topological: True makes the graph undirected (i ~ j when either is "
        "among the other's k nearest); False: i follows its own k nearest (directed).",
    )

    @model_validator(mode="after")
    def _kind_fields(self) -> Neighbours:
        if self.kind == "metric":
            if self.radius is None:
                raise ValueError("neighbours.radius is required for kind 'metric' (or set "
                                 "neighbours.kind 'topological' with k)")
            if self.k is not None or self.symmetric:
                raise ValueError("neighbours.k and neighbours.symmetric apply to kind "
                                 "'topological' only")
        elif self.k is None:
            raise ValueError("neighbours.k is required for kind 'topological' (the number "
                             "of nearest neighbours, e.g. 7)")
        return self

    @property
    def topological(self) -> bool:
        return self.kind == "topological"


class Box(Strict):
    """Uniform random positions in an axis-aligned box (2 or 3 coordinates per corner)."""

    kind: Literal["box"] = "box"
    low: Point = Field(description="Lower corner.")
    high: Point = Field(description="Upper corner.")

    @property
    def dimension(self) -> int:
        return len(self.low)

    @model_validator(mode="after")
    def _ordered(self) -> Box:
        if len(self.low) != len(self.high):
            raise ValueError(f"box low has {len(self.low)} coordinates, high "
                             f"{len(self.high)}")
        if not all(lo < hi for lo, hi in zip(self.low, self.high, strict=True)):
            raise ValueError("box needs low < high in every coordinate")
        return self


class Disc(Strict):
    """Uniform random positions in a disc (uniform in area)."""

    kind: Literal["disc"] = "disc"
    center: Vec2 = (0.0, 0.0)
    radius: PositiveReal = Field(description="Disc radius.")
    dimension: ClassVar[int] = 2


class Ball(Strict):
    """Uniform random positions in a ball (3D: uniform in volume)."""

    kind: Literal["ball"] = "ball"
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: PositiveReal = Field(description="Ball radius.")
    dimension: ClassVar[int] = 3


class Lattice(Strict):
    """A jittered square lattice: agent k at low + spacing (k mod m, k div m) + u, with
    m = ceil(sqrt(N)) and u uniform in [-jitter, jitter]^2 * spacing. In 3D (`low` with
    three coordinates) the cubic lattice low + spacing (k mod m, k div m mod m, k div m^2)
    + u, m = ceil(cbrt(N)). No two agents are
    closer than spacing (1 - 2 jitter): the non-overlapping start that potentials
    singular at s = 0 need at large N (uniform random positions put some pair ~1e-6
    apart at N = 10^6)."""

    kind: Literal["lattice"] = "lattice"
    low: Point = Field(default=(0.0, 0.0), description="Position of lattice point 0.")
    spacing: PositiveReal = Field(description="Lattice spacing (length units).")
    jitter: float = Field(default=0.0, ge=0.0, lt=0.5, allow_inf_nan=False,
                          description="Uniform displacement per axis, as a fraction of spacing.")

    @property
    def dimension(self) -> int:
        return len(self.low)

    def side(self, n: int) -> int:
        """Lattice points per axis for n agents: ceil(N^(1/dimension)), exactly."""
        if self.dimension == 2:
            return math.ceil(math.sqrt(n))
        m = max(1, round(n ** (1.0 / self.dimension)))
        while m ** self.dimension < n:
            m += 1
        while m > 1 and (m - 1) ** self.dimension >= n:
            m -= 1
        return m


Region = Annotated[Box | Disc | Ball | Lattice, Field(discriminator="kind")]


class RandomInitial(Strict):
    """Seeded random initial state: positions uniform in a region, headings uniform in a
    range, speeds uniform in a range (models with a common speed ignore the speeds). In 3D
    the directions are uniform on the sphere (heading_range is then left at its default)."""

    kind: Literal["random"] = "random"
    N: PositiveInt = Field(description="Number of agents.", le=MAX_AGENTS)
    region: Region | None = Field(
        default=None, description="Where agents start; default: the whole periodic box."
    )
    heading_range: RealPair = Field(
        default=(-math.pi, math.pi), description="Headings uniform in [a, b) (radians)."
    )
    speed_range: NonNegativePair = Field(
        default=(0.0, 0.0), description="Speeds uniform in [a, b) (double integrators)."
    )

    @model_validator(mode="after")
    def _ranges(self) -> RandomInitial:
        if self.heading_range[0] > self.heading_range[1]:
            raise ValueError("heading_range needs a <= b")
        if self.speed_range[0] > self.speed_range[1]:
            raise ValueError("speed_range needs a <= b")
        return self


class ExplicitInitial(Strict):
    """Initial state given as arrays in agent-id order."""

    kind: Literal["explicit"] = "explicit"
    positions: list[Point] = Field(
        min_length=1, description="N positions (x, y), or (x, y, z) in 3D.")
    headings: list[Real] | None = Field(
        default=None, description="N headings (radians; 2D only).")
    velocities: list[Point] | None = Field(
        default=None, description="N velocities (vx, vy), or (vx, vy, vz) in 3D.")

    @property
    def N(self) -> int:
        return len(self.positions)

    @property
    def dimension(self) -> int:
        return len(self.positions[0])

    @field_validator("positions")
    @classmethod
    def _magnitude(cls, v: list[tuple[float, ...]]) -> list[tuple[float, ...]]:
        for k, p in enumerate(v):
            if max(abs(c) for c in p) > MAX_ABS_COORD:
                raise ValueError(f"positions[{k}] exceeds {MAX_ABS_COORD:g} in magnitude")
        return v

    @field_validator("positions", "velocities")
    @classmethod
    def _one_dimension(cls, v: list[tuple[float, ...]] | None, info: ValidationInfo
                       ) -> list[tuple[float, ...]] | None:
        # Every row as long as the first: one dimension for the whole state.
        for k, row in enumerate(v or ()):
            if len(row) != len(v[0]):
                raise ValueError(f"{info.field_name}[{k}] has {len(row)} coordinates, "
                                 f"{info.field_name}[0] has {len(v[0])}")
        return v

    @model_validator(mode="after")
    def _lengths(self) -> ExplicitInitial:
        for name in ("headings", "velocities"):
            arr = getattr(self, name)
            if arr is not None and len(arr) != self.N:
                raise ValueError(f"{name} has {len(arr)} entries, positions has {self.N}")
        if self.velocities is not None and len(self.velocities[0]) != self.dimension:
            raise ValueError(f"velocities have {len(self.velocities[0])} coordinates, "
                             f"positions {self.dimension}")
        if self.headings is not None and self.dimension != 2:
            raise ValueError("headings are angles in the plane: give velocities in 3D")
        return self


Initial = Annotated[RandomInitial | ExplicitInitial, Field(discriminator="kind")]


class TimeSpec(Strict):
    """How long to run. Discrete-time models advance one step per dt."""

    steps: PositiveInt = Field(description="Number of steps.", le=MAX_STEPS)
    dt: PositiveReal = Field(
        default=1.0,
        description="Step length (time units). Discrete-time models (M1) use it as the "
        "time between updates; continuous-time models as the integration step.",
    )


# The recordable per-agent arrays computed from the state rather than held in it (a model
# lists those it has in `derived_arrays`).
DERIVED_ARRAYS = ("degree", "radius")
# The trajectory files frames can go to: trajectory.h5 (service/h5md.py) and trajectory.gsd
# (service/gsd_trajectory.py).
TrajectoryFormat = Literal["h5md", "gsd"]

class Recording(Strict):
    """What to record and how often. Frames go to the trajectory files of `format`."""

    every: NonNegativeInt = Field(
        default=0, le=MAX_STEPS, description="Record a frame every k steps (0: no frames; the last "
        "frame is always recorded when k > 0)."
    )
    arrays: list[Literal["position", "velocity", "heading", "degree", "radius"]] = Field(
        default=["position"],
        description="Per-agent arrays to record. position, velocity, heading: the state; "
        "a model records those it has. degree: each agent's |N_i| in the model's "
        "interaction graph (the metric graph, or the fixed graph of flocking fixed); "
        "radius: each agent's own R_i (flocking_obstacles, eq. 4). degree and radius are "
        "refused by a model without them, and take the per-step engine path "
        "(docs/TRAJECTORIES.md).",
    )
    max_frames: PositiveInt = Field(default=10_000, description="Refuse runs with more frames.")
    observables_every: PositiveInt = Field(
        default=1, le=MAX_STEPS,
        description="Evaluate the observables every k steps (and at the end).",
    )
    observables: list[str] | None = Field(
        default=None, max_length=100,
        description="The observables to evaluate, by the names the model reports (see "
        "`flocklab models`); null: all of them. Naming only cheap ones is faster: on the "
        "small-N path the Vicsek family skips the graph observables (components, "
        "degree_*, isolated) and the heading spread unless they are named; flocking and "
        "flocking_obstacles skip lambda2 (an eigensolve) and formation F2's D3 in 3D (a "
        "linear program per component) unless named. Per-agent names: valency_<i> stands "
        "for valency_0, valency_1, ...",
    )
    precision: Literal["float64", "float32"] = Field(
        default="float64", description="Floating-point type of the recorded frames in the "
        "H5MD file: float32 halves a large trajectory (positions keep about 7 significant "
        "digits). The run's own arithmetic is the scenario's `precision` (float64 by default).",
    )
    compression: Literal["none", "gzip"] = Field(
        default="none", description="Compress the recorded frames in the H5MD file (gzip "
        "level 4 with HDF5's shuffle filter, which every HDF5 reader decodes): smaller "
        "files, slower writes and reads.",
    )
    checkpoint_every: NonNegativeInt = Field(
        default=0, le=MAX_STEPS, description="Write a checkpoint every k steps (0: none) "
        "into the run folder, from which `flocklab run --resume` continues bit for bit "
        "(docs/CHECKPOINTS.md).",
    )
    checkpoint_seconds: PositiveReal | None = Field(
        default=None, description="Also write a checkpoint whenever this many seconds of "
        "wall-clock time have passed since the last one (null: by steps only).",
    )
    format: TrajectoryFormat | list[TrajectoryFormat] = Field(
        default="h5md", description="The trajectory files the frames go to: h5md "
        "(trajectory.h5, which flocklab render and the service's /trajectory read), gsd "
        "(trajectory.gsd, HOOMD's schema, read by OVITO, freud and MDAnalysis, 2D "
        "included: docs/TRAJECTORIES.md), or both. trajectory.h5 is written either way "
        "(observables, scenario, drawing); with gsd alone it holds no frames.",
    )

    @model_validator(mode="after")
    def _gsd_frames(self) -> Recording:
        """A GSD file is its frames, and a HOOMD frame is its particles' positions."""
        formats = self.formats
        if not formats or len(set(formats)) != len(formats):
            raise ValueError(f"recording.format: name each of h5md, gsd at most once, and "
                             f"at least one (got {self.format!r})")
        if "gsd" in formats and (self.every == 0 or "position" not in self.arrays):
            raise ValueError("recording.format gsd writes frames of positions: it needs "
                             "recording.every > 0 and position in recording.arrays")
        return self

    @property
    def formats(self) -> tuple[TrajectoryFormat, ...]:
        """The trajectory files, as a tuple (`format` may be one name or a list)."""
        return (self.format,) if isinstance(self.format, str) else tuple(self.format)

    @property
    def enabled(self) -> bool:
        return self.every > 0

    @property
    def checkpoints(self) -> bool:
        """Whether the run writes checkpoints (by steps, by wall-clock time or both)."""
        return self.checkpoint_every > 0 or self.checkpoint_seconds is not None

    @property
    def derived(self) -> list[str]:
        """The requested arrays computed from the state rather than held in it."""
        return [a for a in self.arrays if a in DERIVED_ARRAYS]

    def wants(self, observable: str) -> bool:
        """Whether the run reports `observable` (observables null: every one)."""
        return self.observables is None or observable in self.observables


Backend = Literal["cpu", "cuda", "vulkan", "auto"]
# The engine's floating-point type (the scenario's `precision`, not the frames' dtype).
Precision = Literal["float64", "float32"]


class Convergence(Strict):
    """Tolerance for the time-to-converge report: the first recorded time after which the
    model's convergence observable stays below the tolerance until the end."""

    tolerance: PositiveReal = Field(default=1e-3, description="Tolerance (observable units).")
