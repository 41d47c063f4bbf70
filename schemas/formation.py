"""M4: Xi–Abed formation control with virtual leaders (paper 003).

First-order agents (eq. 1-2): dr_i/dt = v_Ai + v_Ri.
  repulsion (eq. 4)  v_Ri = sum_{j in N_i} g(|r_j - r_i|) (r_j - r_i)/|r_j - r_i|,
                     N_i = {j : |r_ij| < d}, g < 0 on (0, d), g(s) = 0 for s >= d
  F1 (eq. 3)         v_Ai = f(|r_id - r_i|) (r_id - r_i)/|r_id - r_i|,  r_id(t) = p(t) + b_i(t)
  F2 (eq. 5)         v_Ai = f(|r_0 - r_i|) (r_0 - r_i)/|r_0 - r_i|,     r_0(t) = p(t)
The leader path p(t) is a straight line or a spline through waypoints, timed by arc length,
then still at its end. F1's offsets b_i come from a named formation or are given, and a
schedule may rotate the formation or morph it into another over time intervals.
d is the scenario's `neighbours.radius`.

In 3D (`space.dimension = 3`) f and g act along the same unit vectors, so the laws are
unchanged: the path's points, the offsets and the rotation axes are 3-vectors
(docs/MODELS_3D.md).
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

from pydantic import Field, model_validator

from .base import Point, PositiveInt, PositiveReal, Real, Strict, Vec3
from .catalog import ModelContext, ModelParams, Overlay, register_model

MAX_WAYPOINTS = 1000


# --- f: the attraction magnitude (continuous, increasing, f(0) = 0) ----------------------


class LinearF(Strict):
    """f(s) = k s (Simulation 1; Propositions 3.1-3.2)."""

    kind: Literal["linear"] = "linear"
    k: PositiveReal = Field(default=1.0, description="Gain k of f(s) = k s (1/time).")


class QuadraticF(Strict):
    """f(s) = c (s^2 + s) (Simulation 2 prints c = 0.02)."""

    kind: Literal["quadratic"] = "quadratic"
    c: PositiveReal = Field(default=0.02, description="c of f(s) = c (s^2 + s).")


class SaturatingF(Strict):
    """f(s) = v_max tanh(k s / v_max): slope k at 0, never faster than v_max."""

    kind: Literal["saturating"] = "saturating"
    k: PositiveReal = Field(default=1.0, description="Slope of f at s = 0 (1/time).")
    v_max: PositiveReal = Field(default=10.0, description="Saturation speed (length/time).")


Attraction = Annotated[LinearF | QuadraticF | SaturatingF, Field(discriminator="kind")]


# --- g: the repulsion magnitude (g < 0 on (0, d), g(d) = 0, g -> -inf at 0) ---------------


class InverseG(Strict):
    """g(s) = -k_g (1/s - 1/d) for s < d, 0 beyond."""

    kind: Literal["inverse"] = "inverse"
    k_g: PositiveReal = Field(default=100.0, description="Gain k_g (length^2/time).")


class InverseSquareG(Strict):
    """g(s) = -k_g (1/s^2 - 1/d^2) for s < d, 0 beyond."""

    kind: Literal["inverse_square"] = "inverse_square"
    k_g: PositiveReal = Field(default=1000.0, description="Gain k_g (length^3/time).")


Repulsion = Annotated[InverseG | InverseSquareG, Field(discriminator="kind")]


# --- the virtual leader's path p(t) -------------------------------------------------------


class _Timed(Strict):
    start: Point | None = Field(
        default=None, description="p(0); default: the initial centroid of the agents "
        "((x, y), or (x, y, z) in 3D)."
    )
    speed: PositiveReal | None = Field(
        default=None, description="Leader speed along the path (length/time)."
    )
    arrival_time: PositiveReal | None = Field(
        default=None, description="T: the time the leader reaches the end (then stays)."
    )

    @model_validator(mode="after")
    def _one_timing(self) -> _Timed:
        if (self.speed is None) == (self.arrival_time is None):
            raise ValueError("give exactly one of speed and arrival_time")
        return self


class StraightPath(_Timed):
    """p(t) moves on a straight line from p(0) to the target r_t, then p(t) = r_t (t >= T)."""

    kind: Literal["straight"] = "straight"
    target: Point = Field(description="r_t, where the leader stops.")


class SplinePath(_Timed):
    """p(t) follows a natural cubic spline through p(0) and the waypoints (chord-length
    knots) at constant speed along its arc length, then stays at the last waypoint."""

    kind: Literal["spline"] = "spline"
    waypoints: list[Point] = Field(
        min_length=1, max_length=MAX_WAYPOINTS,
        description="Points after p(0); the last is the target r_t.",
    )

    @model_validator(mode="after")
    def _distinct(self) -> SplinePath:
        pts = ([self.start] if self.start is not None else []) + list(self.waypoints)
        for j in range(1, len(pts)):
            if pts[j] == pts[j - 1]:
                raise ValueError(f"waypoints {j - 1} and {j} coincide (counting start)")
        return self


Path = Annotated[StraightPath | SplinePath, Field(discriminator="kind")]


# --- F1: the offsets b_i ------------------------------------------------------------------

Shape = Literal["line", "column", "wedge", "diamond", "circle", "hex", "cube", "shell"]
SHAPES_3D = ("cube", "shell")  # the shapes that need space.dimension = 3


class NamedFormation(Strict):
    """A named formation of N agents with mean-zero offsets, neighbours at distance d and no
    two agents closer than d. Reference heading +x: column = one behind another along x,
    line = abreast along y, wedge = a filled triangle with its apex at +x (rows 1, 2, 3...
    of the triangular lattice), diamond = a k x k square lattice turned 45 deg (apex at +x),
    circle = N agents on a circle with adjacent ones d apart, hex = the N triangular-lattice
    points nearest the origin. 3D only: cube = a cubic lattice of spacing d, m = ceil(N^(1/3))
    a side, filled x fastest, then y, then z; shell = N points of a Fibonacci sphere, its
    radius chosen so that the nearest pair is d apart. In 3D the plane shapes lie in the
    xy plane (z = 0) and `orientation` turns about the z axis."""

    kind: Literal["named"] = "named"
    shape: Shape = Field(description="Formation shape.")
    orientation: Real = Field(
        default=0.0, description="Rotation of the whole shape, counter-clockwise (radians; "
        "about the z axis in 3D)."
    )


class ExplicitFormation(Strict):
    """Offsets b_i given in agent-id order; their mean must be zero (paper condition 1)."""

    kind: Literal["explicit"] = "explicit"
    offsets: list[Point] = Field(
        min_length=1, description="N offsets b_i: (x, y) rows, or (x, y, z) rows in 3D.")

    @property
    def dimension(self) -> int:
        """The number of columns of the offsets."""
        return len(self.offsets[0])

    @model_validator(mode="after")
    def _mean_zero(self) -> ExplicitFormation:
        n, dim = len(self.offsets), self.dimension
        for k, b in enumerate(self.offsets):
            if len(b) != dim:
                raise ValueError(f"offsets[{k}] has {len(b)} coordinates, offsets[0] has {dim}")
        mean = [math.fsum(b[c] for b in self.offsets) / n for c in range(dim)]
        scale = max(max(abs(x) for x in b) for b in self.offsets)
        if math.hypot(*mean) > 1e-9 * max(scale, 1.0):
            raise ValueError(
                f"offsets must have mean zero (paper condition 1); their mean is "
                f"({', '.join(f'{m:.6g}' for m in mean)})"
            )
        return self


FormationSpec = Annotated[NamedFormation | ExplicitFormation, Field(discriminator="kind")]


class FormationChange(Strict):
    """One change of F1's formation over [start, end]: rotate the formation in force by
    `rotate` radians about its centre (in 3D about `axis`, default the z axis, by the
    right-hand rule), or morph it into `formation`. The blend weight
    s(u), u = (t - start)/(end - start), is smoothstep 3u^2 - 2u^3 (velocity continuous)
    or linear; start == end changes abruptly."""

    start: Real = Field(ge=0, description="Start of the change (time).")
    end: Real = Field(ge=0, description="End of the change (time).")
    rotate: Real | None = Field(default=None, description="Rotation angle (radians).")
    axis: Vec3 | None = Field(
        default=None, description="3D only: the rotation axis (any length but zero); "
        "default the z axis.")
    formation: FormationSpec | None = Field(default=None, description="Formation to morph to.")
    relaxation: Literal["smoothstep", "linear"] = Field(
        default="smoothstep", description="Blend profile over the interval."
    )

    @model_validator(mode="after")
    def _valid(self) -> FormationChange:
        if self.end < self.start:
            raise ValueError(f"change ends ({self.end:g}) before it starts ({self.start:g})")
        if (self.rotate is None) == (self.formation is None):
            raise ValueError("a formation change needs exactly one of rotate and formation")
        if self.axis is not None:
            if self.rotate is None:
                raise ValueError("axis applies only to a rotation (rotate)")
            if not any(self.axis):
                raise ValueError("axis must not be the zero vector")
        return self


# --- the model ----------------------------------------------------------------------------


@register_model
class FormationParams(ModelParams):
    """Xi–Abed formation control: F1 (a virtual leader per agent) or F2 (one leader)."""

    paper: ClassVar[str] = "003 Xi, Abed (2005), New formation control designs with virtual leaders"
    equations: ClassVar[str] = (
        "dr_i/dt = v_Ai + v_Ri (eq. 1-2); v_Ri = sum g(|r_ji|) r_ji/|r_ji| over |r_ij| < d "
        "(eq. 4); F1: v_Ai = f(|r_id - r_i|) n_di, r_id = p + b_i (eq. 3); F2: v_Ai = "
        "f(|r_0 - r_i|) n_0i, r_0 = p (eq. 5); lag a: f(|a|) a/|a| = -q (eq. 8); V1 (eq. 10); "
        "V2 (eq. 16); F2 formation D1-D3 (Sec. 3.2)"
    )
    summary: ClassVar[str] = (
        "First-order agents tracking virtual leaders on a path, with short-range repulsion."
    )
    paper_inclusive: ClassVar[bool] = False
    state_arrays: ClassVar[tuple[str, ...]] = ("position", "velocity")
    # Each design reports its own (docs/models/formation.md): F1 formation_error .. V1, F2 V2 ..
    # components; leader_z and centroid_z in 3D. D3 is the costly one in 3D (a linear
    # program per component and observation): a scenario that does not name it skips it.
    observables: ClassVar[tuple[str, ...] | None] = (
        "leader_x", "leader_y", "leader_z", "leader_speed", "centroid_x", "centroid_y",
        "centroid_z", "centroid_distance", "speed_min", "speed_mean", "speed_max",
        "speed_error_max", "velocity_mismatch_max", "min_distance", "degree_mean",
        "formation_error", "formation_error_max", "lag", "V1", "V2", "D1", "D2", "D3",
        "isolated", "components")
    dimensions: ClassVar[tuple[int, ...]] = (2, 3)
    dimensions_note: ClassVar[str] = (
        "3D: 3-vector paths and offsets, shapes cube and shell, rotations about an axis")
    units: ClassVar[tuple[str | None, str | None]] = ("s", None)  # its lengths have none
    # F1 reports formation_error, F2 does not: F2 runs plot the other three.
    default_plots: ClassVar[tuple[str, ...]] = (
        "formation_error", "velocity_mismatch_max", "min_distance", "speed_mean")
    details: ClassVar[str] = "docs/models/formation.md"
    overlays: ClassVar[tuple[Overlay, ...]] = ("leaders",)

    kind: Literal["formation"] = "formation"
    design: Literal["F1", "F2"] = Field(
        default="F1", description="F1: a virtual leader per agent (eq. 3); F2: one (eq. 5)."
    )
    attraction: Attraction = Field(default=LinearF(), description="f, the attraction.")
    repulsion: Repulsion = Field(default=InverseG(), description="g, the repulsion.")
    path: Path = Field(description="The virtual leader's path p(t).")
    formation: FormationSpec | None = Field(
        default=None, description="F1: the offsets b_i at t = 0 (required for F1)."
    )
    schedule: list[FormationChange] = Field(
        default=[], description="F1: formation changes, in time order, not overlapping."
    )
    lag_sign: Literal["eq8", "prop3.2"] = Field(
        default="eq8",
        description="Sign of the steady lag a used by the formation error: eq8 solves "
        "f(|a|) a/|a| = -q (agents trail their leaders, which is what the dynamics do); "
        "prop3.2 solves f(|a|) a/|a| = +q as Proposition 3.2 prints it.",
    )
    integrator: Literal["euler", "rk4"] = Field(
        default="euler", description="Explicit Euler, or classical RK4 (accuracy checks)."
    )
    max_exact_candidates: PositiveInt | None = Field(
        default=1024,
        description="Cap on the pair work per agent: when the densest neighbour cell (side "
        "d) would make an agent visit more than this many candidates (9 x its count), an "
        "Euler step coarse-grains far pairs by sub-cell (docs/models/formation.md); null: always "
        "exact. Runs with N <= 113 (the paper's: N <= 100) are always exact.",
    )
    collision_distance: PositiveReal | None = Field(
        default=None,
        description="D1: two agents closer than this count as a collision (default d/100; "
        "the paper's point agents collide only at distance 0).",
    )
    leader_tolerance: PositiveReal | None = Field(
        default=None,
        description="D2-D3: an agent within this distance of r_0 is 'at r_0' (default d/100).",
    )

    def collision(self, d: float) -> float:
        """D1's collision distance for neighbour radius d (default d/100)."""
        return self.collision_distance or d / 100.0

    def at_leader(self, d: float) -> float:
        """D2-D3's tolerance for 'at r_0' for neighbour radius d (default d/100)."""
        return self.leader_tolerance or d / 100.0

    def check_context(self, ctx: ModelContext) -> None:
        if ctx.space != "plane":
            raise ValueError("model formation runs on the unbounded plane: space.kind = 'plane'")
        if ctx.radius is None:
            raise ValueError("model formation needs a neighbours block: its radius is d")
        n = ctx.n_agents
        if self.design == "F2":
            if self.formation is not None or self.schedule:
                raise ValueError("design F2 has no formation or schedule (one virtual leader)")
        else:
            if self.formation is None:
                raise ValueError("design F1 needs a formation (named or explicit offsets)")
            formations = [self.formation] + [c.formation for c in self.schedule if c.formation]
            for j, fm in enumerate(formations):
                if isinstance(fm, ExplicitFormation) and len(fm.offsets) != n:
                    where = "formation" if j == 0 else "a schedule formation"
                    raise ValueError(f"{where} has {len(fm.offsets)} offsets, N = {n}")
            for j in range(1, len(self.schedule)):
                if self.schedule[j].start < self.schedule[j - 1].end:
                    raise ValueError(
                        f"schedule[{j}] starts at {self.schedule[j].start:g}, before "
                        f"schedule[{j - 1}] ends at {self.schedule[j - 1].end:g}"
                    )
        self._check_dimension(ctx.dimension)
        f = self.attraction
        speed = self.path.speed
        if isinstance(f, SaturatingF) and speed is not None and speed >= f.v_max:
            raise ValueError(
                f"path.speed = {speed:g} >= attraction.v_max = {f.v_max:g}: "
                "the agents could never keep up (eq. 8 has no solution)"
            )

    def _check_dimension(self, dim: int) -> None:
        """Every point, offset and axis has `dim` coordinates; cube and shell are 3D."""
        path = self.path
        points = [("path.start", path.start)] if path.start is not None else []
        if isinstance(path, StraightPath):
            points.append(("path.target", path.target))
        else:
            points += [(f"path.waypoints[{k}]", w) for k, w in enumerate(path.waypoints)]
        for name, point in points:
            if len(point) != dim:
                raise ValueError(f"{name} has {len(point)} coordinates; space.dimension is "
                                 f"{dim}")
        formations = [("formation", self.formation)] + [
            (f"schedule[{j}].formation", c.formation) for j, c in enumerate(self.schedule)]
        for name, fm in formations:
            if isinstance(fm, ExplicitFormation) and fm.dimension != dim:
                cols = "(x, y)" if fm.dimension == 2 else "(x, y, z)"
                raise ValueError(
                    f"{name}.offsets have {fm.dimension} columns {cols}; space.dimension = "
                    f"{dim} needs {dim} columns per offset")
            if isinstance(fm, NamedFormation) and fm.shape in SHAPES_3D and dim != 3:
                raise ValueError(f"{name}: shape {fm.shape!r} is a 3D formation and runs in "
                                 f"3D only; space.dimension is {dim}")
        for j, c in enumerate(self.schedule):
            if c.axis is not None and dim != 3:
                raise ValueError(f"schedule[{j}].axis is 3D only (a 2D rotation is about the "
                                 f"plane's normal); space.dimension is {dim}")
