"""M3: flocking with obstacle avoidance and a destination (paper 002, Tanner).

Double integrator (eq. 1) with the control law (eq. 3)
  u_i = - sum_{j in N_i} [(v_i - v_j) + grad_{r_i} U_ij] - grad_{r_i} V_i - c_d v_i [V_i > V_min],
N_i = {j : |r_ij| <= R_i}; U_ij = 1/s^2 + log s^2 for s < R_i, V_R beyond (p. 3).
Mission potential (a navigation function), destination r_d, obstacles o:
  beta_io = (1 - lambda [delta - d]^2 / ([delta - d]^2 + 1))^m,
  m = 1/2 (sign(d^2 - delta^2) + 1), lambda = (d^2 + 1) / d^2,
  V_i = |r_i - r_d|^2 / (|r_i - r_d|^(2 kappa) + prod_o beta_io)^(1 / kappa),
delta the distance from r_i to the obstacle's boundary (a point: |r_i - r_o|; a disc:
|r_i - r_o| - rho). Adaptive radius (eq. 4): R_i <- R_i / 2 when agent i is immobilised
(|v_i| < stuck_speed) while V_i > V_min, else R_i <- max(R_i, R_j for j in N_i).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal

import pydantic
from pydantic import Field, StrictBool

from .base import NonNegativeReal, Point, PositiveInt, PositiveReal, Strict
from .catalog import ModelContext, Overlay, register_model
from .common import MAX_STEPS
from .flocking import (
    FLOCK_OBSERVABLES,
    DoubleIntegratorParams,
    PotentialSpec,
    check_radius_exceeds_d,
)

MAX_OBSTACLES = 1_000_000
Kappa = Annotated[float, Field(ge=1.0, le=100.0, allow_inf_nan=False), pydantic.Strict(True)]


class DiscObstacle(Strict):
    """A disc obstacle (in 3D a sphere): delta = |r_i - center| - radius is the distance to
    its boundary."""

    center: Point = Field(description="Centre r_o (length; 3 coordinates in 3D).")
    radius: PositiveReal = Field(description="Radius rho (length).")


@register_model
class ObstacleFlockingParams(DoubleIntegratorParams):
    """Tanner's flocking among obstacles towards a destination, with adaptive radii."""

    paper: ClassVar[str] = (
        "002 Tanner, Flocking with obstacle avoidance in switching networks of "
        "interconnected vehicles"
    )
    equations: ClassVar[str] = (
        "eq. 1 (double integrator), eq. 3 (u_i with damping), p. 3 (U_ij, beta_io, lambda, "
        "m, V_i navigation function), eq. 4 (adaptive radius), eq. 5 (Q)"
    )
    summary: ClassVar[str] = (
        "Flocking double integrators steered by a navigation function to a destination "
        "around point and disc obstacles, halving their radius when stuck."
    )
    paper_inclusive: ClassVar[bool] = True
    derived_arrays: ClassVar[tuple[str, ...]] = ("degree", "radius")
    observables: ClassVar[tuple[str, ...] | None] = (
        *FLOCK_OBSERVABLES, "velocity_disagreement_components",
        "velocity_disagreement_components_max", "radius_min", "radius_mean", "radius_max",
        "mission_potential_max", "destination_distance_mean", "destination_distance_max",
        "inside_vmin_fraction", "obstacle_distance_min")
    dimensions: ClassVar[tuple[int, ...]] = (2, 3)
    dimensions_note: ClassVar[str] = "in 3D: point and sphere obstacles (discs with 3D centres)"
    default_plots: ClassVar[tuple[str, ...]] = (
        "velocity_disagreement_components", "destination_distance_mean", "components")
    overlays: ClassVar[tuple[Overlay, ...]] = ("edges", "obstacles")

    kind: Literal["flocking_obstacles"] = "flocking_obstacles"
    potential: PotentialSpec = Field(
        default=PotentialSpec(kind="paper002"),
        description="Interaction potential U_ij below R_i (default paper 002's 1/s^2 + log s^2).",
    )
    destination: Point = Field(default=(0.0, 0.0), description="Destination r_d (length).")
    obstacles: list[Point] = Field(
        default=[], max_length=MAX_OBSTACLES, description="Point obstacles r_o (length)."
    )
    discs: list[DiscObstacle] = Field(
        default=[], max_length=MAX_OBSTACLES,
        description="Disc obstacles (length); spheres in 3D.",
    )
    obstacle_range: PositiveReal = Field(
        default=0.5,
        description="d of beta_io: an obstacle whose boundary is d or farther from the agent "
        "has beta_io = 1 (length).",
    )
    kappa: Kappa = Field(
        default=1.0, description="Navigation function tuning parameter kappa, in [1, 100]."
    )
    c_d: NonNegativeReal = Field(default=0.5, description="Damping gain c_d (1/time).")
    V_min: PositiveReal = Field(
        default=0.6, lt=1.0,
        description="The level V_i = V_min of the mission potential (values lie in [0, 1)).",
    )
    damping_region: Literal["above_vmin", "below_vmin", "everywhere"] = Field(
        default="above_vmin",
        description="Where -c_d v_i acts: above_vmin (V_i > V_min, eq. 3 as printed), "
        "below_vmin (V_i <= V_min: around the destination, as the text motivates it), or "
        "everywhere.",
    )
    adaptive_radius: StrictBool = Field(
        default=True, description="Apply eq. 4; false keeps R_i = R for every agent."
    )
    radius_every: PositiveInt = Field(
        default=100, le=MAX_STEPS,
        description="Evaluate eq. 4 at steps k > 0 with k % radius_every == 0 (before that "
        "step's motion), synchronously for all agents.",
    )
    radius_floor: PositiveReal = Field(
        default=0.25, description="R_i never halves below this (length)."
    )
    stuck_speed: PositiveReal = Field(
        default=1e-3, description="Agent i counts as immobilised (v_i = 0) when |v_i| < this."
    )
    radius_rule: Literal["own", "min"] = Field(
        default="own",
        description="own: N_i = {j : |r_ij| <= R_i} and U_ij saturates at R_i, as printed "
        "(neighbourhoods may be asymmetric). min: R_i replaced by min(R_i, R_j) (symmetric).",
    )

    def check_context(self, ctx: ModelContext) -> None:
        self._check_plane(ctx, "002")
        if ctx.radius is None:
            raise ValueError(
                "model 'flocking_obstacles' needs a neighbours block: its radius is the "
                "initial R_i of every agent"
            )
        radius = ctx.radius
        check_radius_exceeds_d(radius, self.potential)
        if self.radius_floor > radius:
            raise ValueError(
                f"model.radius_floor = {self.radius_floor:g} exceeds the initial radius "
                f"neighbours.radius = {radius:g}"
            )
        dim = ctx.dimension
        points = [("destination", self.destination)]
        points += [(f"obstacles[{k}]", o) for k, o in enumerate(self.obstacles)]
        points += [(f"discs[{k}].center", d.center) for k, d in enumerate(self.discs)]
        for name, point in points:
            if len(point) != dim:
                raise ValueError(f"model.{name} has {len(point)} coordinates; "
                                 f"space.dimension is {dim}")
        for k, o in enumerate(self.obstacles):
            if tuple(o) == tuple(self.destination):
                raise ValueError(
                    f"model.obstacles[{k}] lies on the destination: V_i is 0/0 there"
                )
        for k, disc in enumerate(self.discs):
            if math.dist(self.destination, disc.center) <= disc.radius:
                raise ValueError(f"model.discs[{k}] covers the destination {self.destination}")
        self._check_search(ctx)
        self._check_dt(ctx, None)

    def scene(self) -> dict[str, Any]:
        """The point obstacles, the discs (spheres in 3D) and the destination."""
        return {"obstacle_points": [list(o) for o in self.obstacles],
                "disc_centres": [list(d.center) for d in self.discs],
                "disc_radii": [d.radius for d in self.discs],
                "destination": list(self.destination)}
