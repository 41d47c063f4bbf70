"""Olfati-Saber flocking (IEEE TAC 51(3), 401–420, 2006), Algorithms 1, 2 and 3.

Double integrators q'_i = p_i, p'_i = u_i, neighbours N_i = {j : |q_j - q_i| < r}:
  |z|_s = (sqrt(1 + eps |z|^2) - 1) / eps            (sigma-norm, eq. 8)
  rho_h(z) = 1 on [0, h), (1 + cos(pi (z - h) / (1 - h))) / 2 on [h, 1], 0 beyond (eq. 10)
  phi(z) = ((a + b) s1(z + c) + a - b) / 2, s1(z) = z / sqrt(1 + z^2), c = |a - b| / sqrt(4ab)
  phi_alpha(z) = rho_h(z / r_a) phi(z - d_a), r_a = |r|_s, d_a = |d|_s (eq. 15)
  a_ij = rho_h(|q_j - q_i|_s / r_a), n_ij = (q_j - q_i) / sqrt(1 + eps |q_j - q_i|^2)
Algorithm 1 (eq. 23): u_i = c1a sum_j phi_alpha(|q_ij|_s) n_ij + c2a sum_j a_ij (p_j - p_i)
(the paper's c1a = c2a = 1). Algorithm 2 (eq. 24): plus the gamma-agent's navigational
feedback -c1g (q_i - q_r) - c2g (p_i - p_r), the virtual leader (q_r, p_r) moving at a
constant velocity (q_r(t) = q_r(0) + t p_r). Algorithm 3 (eq. 59): plus the beta-agents
(the projections of agent i on each obstacle k with |q^_ik - q_i| < r'),
  c1b phi_beta(|q^_ik - q_i|_s) n^_ik + c2b b_ik (p^_ik - p_i),
  phi_beta(z) = rho_h'(z / d_b) (s1(z - d_b) - 1), b_ik = rho_h'(|q^_ik - q_i|_s / d_b),
and the gamma term -c1g s1(q_i - q_r) - c2g (p_i - p_r), s1(z) = z / sqrt(1 + |z|^2).
Sphere (2D: circle) centre y, radius R: mu = R / |q_i - y|, a = (q_i - y) / |q_i - y|,
q^ = mu q_i + (1 - mu) y, p^ = mu (I - a a^T) p_i; wall through y with unit normal a:
q^ = (I - a a^T) q_i + a a^T y, p^ = (I - a a^T) p_i (Lemma 4).
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

import pydantic
from pydantic import Field

from .base import Point, PositiveReal, Strict
from .catalog import ModelContext, ModelParams, Overlay, register_model

MAX_OBSTACLES = 64
Fraction = Annotated[float, Field(ge=0.0, lt=1.0, allow_inf_nan=False), pydantic.Strict(True)]

OS_OBSERVABLES = ("deviation_energy", "relative_connectivity", "velocity_mismatch",
                  "cohesion_radius", "min_obstacle_distance", "leader_distance",
                  "mean_velocity_x", "mean_velocity_y", "mean_velocity_z")


class Sphere(Strict):
    """A spherical obstacle (a disc in 2D), O_k = {x : |x - y_k| <= R_k}."""

    kind: Literal["sphere"] = "sphere"
    centre: Point = Field(description="Centre y_k (length).")
    radius: PositiveReal = Field(description="Radius R_k (length).")


class Wall(Strict):
    """A wall: the hyperplane through y_k with normal a_k, the agents on the side a_k
    points to (the normal is normalised here)."""

    kind: Literal["wall"] = "wall"
    point: Point = Field(description="A point y_k of the wall (length).")
    normal: Point = Field(description="Normal a_k towards the agents' side (any length > 0).")


Obstacle = Annotated[Sphere | Wall, Field(discriminator="kind")]


class Leader(Strict):
    """The gamma-agent: a virtual leader moving at a constant velocity."""

    position: Point = Field(description="q_r(0) (length).")
    velocity: Point = Field(description="p_r (length/time), constant.")


@register_model
class OlfatiSaberParams(ModelParams):
    """Olfati-Saber's alpha-lattice flocking: Algorithm 1 (free flocking), 2 (plus a
    gamma-agent) and 3 (plus beta-agents on obstacles)."""

    paper: ClassVar[str] = (
        "Olfati-Saber, Flocking for multi-agent dynamic systems: algorithms and theory, "
        "IEEE TAC 51(3), 401-420, 2006")
    equations: ClassVar[str] = (
        "eq. 8 (sigma-norm), eq. 10 (bump rho_h), eqs. 15-16 (phi, phi_alpha), eq. 23 "
        "(Algorithm 1), eq. 24 (Algorithm 2: gamma-agent feedback), eq. 56-59 and Lemma 4 "
        "(Algorithm 3: beta-agents of spheres and walls, the sigma_1 gamma term); quality "
        "measures of section VIII (deviation energy, relative connectivity, velocity "
        "mismatch, cohesion radius); the equation numbers are recalled, not checked against "
        "the printed paper (docs/models/olfati_saber.md)")
    summary: ClassVar[str] = (
        "Double integrators forming alpha-lattices (gradient of a bump-cut pair potential "
        "plus velocity consensus), with a virtual leader (Algorithm 2) and obstacle "
        "avoidance by beta-agents (Algorithm 3).")
    paper_inclusive: ClassVar[bool] = False
    neighbour_kinds: ClassVar[tuple[str, ...]] = ()
    neighbours_note: ClassVar[str] = (
        "none: N_i = {j : |q_j - q_i| < r}, r = kappa d (model.d, model.kappa)")
    state_arrays: ClassVar[tuple[str, ...]] = ("position", "velocity", "heading")
    observables: ClassVar[tuple[str, ...] | None] = OS_OBSERVABLES
    dimensions: ClassVar[tuple[int, ...]] = (2, 3)
    units: ClassVar[tuple[str | None, str | None]] = (None, None)  # the paper has none
    default_plots: ClassVar[tuple[str, ...]] = ("deviation_energy", "relative_connectivity",
                                                "velocity_mismatch")
    details: ClassVar[str] = "docs/models/olfati_saber.md"
    # No overlays: the renderer's obstacle overlay draws discs around a fixed destination
    # (M3's); here the target is a moving gamma-agent and walls are half-planes.
    overlays: ClassVar[tuple[Overlay, ...]] = ()

    kind: Literal["olfati_saber"] = "olfati_saber"
    algorithm: Literal[1, 2, 3] = Field(
        default=1, description="1: alpha-agents alone (eq. 23); 2: plus the gamma-agent's "
        "navigational feedback (eq. 24; needs model.leader); 3: plus beta-agents for "
        "model.obstacles and the sigma_1 gamma term (eq. 59).")
    d: PositiveReal = Field(default=7.0, description="d (length): the lattice's desired "
                            "inter-agent distance.")
    kappa: PositiveReal = Field(default=1.2, description="kappa = r / d > 1: the "
                                "interaction range r = kappa d.")
    d_obstacle: PositiveReal = Field(default=4.2, description="d' (length): the desired "
                                     "distance to an obstacle (the paper's 0.6 d).")
    kappa_obstacle: PositiveReal = Field(default=1.2, description="r' / d': the obstacle "
                                         "sensing range r' = kappa_obstacle d'.")
    epsilon: PositiveReal = Field(default=0.1, description="eps: the sigma-norm's "
                                  "parameter, 0 < eps < 1.")
    h_alpha: Fraction = Field(default=0.2, description="h of the bump in phi_alpha and "
                              "a_ij, 0 <= h < 1.")
    h_beta: Fraction = Field(default=0.9, description="h of the bump in phi_beta and b_ik.")
    a: PositiveReal = Field(default=5.0, description="a of phi, 0 < a <= b.")
    b: PositiveReal = Field(default=5.0, description="b of phi (a = b: phi odd about d).")
    c1_alpha: PositiveReal = Field(default=1.0, description="c1^alpha: gain of the gradient "
                                   "term (the paper's Algorithms 1 and 2: 1).")
    c2_alpha: PositiveReal = Field(default=1.0, description="c2^alpha: gain of the velocity "
                                   "consensus (Algorithms 1 and 2: 1).")
    c1_beta: PositiveReal = Field(default=1.0, description="c1^beta: gain of the obstacle "
                                  "gradient term (Algorithm 3).")
    c2_beta: PositiveReal = Field(default=1.0, description="c2^beta: gain of the obstacle "
                                  "velocity term (Algorithm 3).")
    c1_gamma: PositiveReal = Field(default=0.1, description="c1^gamma (1/time^2; Algorithm "
                                   "3: length/time^2): the leader's position feedback.")
    c2_gamma: PositiveReal = Field(default=0.6, description="c2^gamma (1/time): the leader's "
                                   "velocity feedback.")
    leader: Leader | None = Field(default=None, description="The gamma-agent (Algorithms 2 "
                                  "and 3): q_r(0) and its constant velocity p_r.")
    obstacles: list[Obstacle] = Field(
        default=[], max_length=MAX_OBSTACLES,
        description="Spheres (2D: discs) and walls, the beta-agents' sources (Algorithm 3).")
    integrator: Literal["semi_implicit_euler"] = Field(
        default="semi_implicit_euler",
        description="semi_implicit_euler: p += dt u(q, p, t); q += dt p (new p).")

    @property
    def r(self) -> float:
        """The interaction range r = kappa d."""
        return self.kappa * self.d

    @pydantic.model_validator(mode="after")
    def _consistent(self) -> OlfatiSaberParams:
        if self.kappa <= 1.0:
            raise ValueError("model.kappa must exceed 1 (r = kappa d > d)")
        if self.epsilon >= 1.0:
            raise ValueError("model.epsilon must lie in (0, 1)")
        if self.a > self.b:
            raise ValueError("model.a must not exceed model.b (0 < a <= b)")
        if self.algorithm >= 2 and self.leader is None:
            raise ValueError(f"model.leader is required by algorithm {self.algorithm}")
        if self.algorithm == 1 and self.leader is not None:
            raise ValueError("model.leader: algorithm 1 has no gamma-agent (use 2 or 3)")
        if self.algorithm < 3 and self.obstacles:
            raise ValueError("model.obstacles: only algorithm 3 has beta-agents")
        for k, o in enumerate(self.obstacles):
            if isinstance(o, Wall) and math.hypot(*o.normal) == 0.0:
                raise ValueError(f"model.obstacles[{k}].normal must not be zero")
        return self

    def check_context(self, ctx: ModelContext) -> None:
        if ctx.space != "plane":
            raise ValueError("model 'olfati_saber' runs on the unbounded plane (space.kind "
                             "'plane'), as the paper's R^m")
        if ctx.neighbours is not None or ctx.radius is not None:
            raise ValueError("olfati_saber takes no neighbours block: its range is "
                             "r = model.kappa * model.d")
        points = []
        if self.leader is not None:
            points += [("model.leader.position", self.leader.position),
                       ("model.leader.velocity", self.leader.velocity)]
        for k, o in enumerate(self.obstacles):
            for name in ("centre", "point", "normal"):
                if hasattr(o, name):
                    points.append((f"model.obstacles[{k}].{name}", getattr(o, name)))
        for name, v in points:
            if len(v) != ctx.dimension:
                raise ValueError(f"{name} has {len(v)} coordinates; space.dimension is "
                                 f"{ctx.dimension}")
