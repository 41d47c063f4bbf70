"""Couzin's zone model (Couzin, Krause, James, Ruxton, Franks, J. Theor. Biol. 218, 1-11,
2002): constant-speed agents with three nested zones around each.

Agent i at c_i with unit direction d_i, r_ij = c_j - c_i, r = |r_ij|, j != i:
  repulsion   r < r_r:                         d_r = -sum r_ij / r            (eq. 1)
  orientation r_r <= r < r_o, j seen:          d_o = sum d_j                  (eq. 2)
  attraction  r_o <= r < r_a, j seen:          d_a = sum r_ij / r             (eq. 3)
with r_o = r_r + dr_o, r_a = r_o + dr_a; "seen": j outside the blind cone behind i, the
angle between d_i and r_ij at most field_of_view / 2. Any neighbour in the zone of
repulsion: d = d_r (repulsion alone decides). Else d = (d_o + d_a) / 2 when both zones
hold someone (`combine: "unit"`: of d_o / |d_o| and d_a / |d_a|), the one that does
otherwise, d_i itself when none does (or d sums to 0).
Then d / |d| is rotated by a wrapped Gaussian angle of s.d. sigma (2D: about the normal;
3D: towards a uniform random direction normal to d), and d_i turns towards it by at most
theta tau (the turning rate times the time step): d_i' = d when the angle between them is
within theta tau, else d_i rotated by theta tau in the plane of d_i and d. Every desired
direction comes from the same state; then every agent moves c_i' = c_i + s tau d_i'.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

from pydantic import Field

from .base import NonNegativeReal, PositiveReal
from .catalog import ModelContext, ModelParams, register_model

COUZIN_OBSERVABLES = ("polarization", "milling")


@register_model
class CouzinParams(ModelParams):
    """Couzin et al. 2002: repulsion, orientation and attraction zones, a blind angle, a
    maximum turning rate and a constant speed."""

    paper: ClassVar[str] = ("Couzin, Krause, James, Ruxton, Franks, Collective memory and "
                            "spatial sorting in animal groups, J. Theor. Biol. 218, 1-11, 2002")
    equations: ClassVar[str] = (
        "zones of repulsion (eq. 1, overrides), orientation (eq. 2) and attraction (eq. 3); "
        "d = (d_o + d_a)/2 when both; blind cone behind (field_of_view); wrapped-Gaussian "
        "noise sigma; turn by at most theta tau; c' = c + s tau d'; order parameters "
        "p = |sum d_i|/N and m = |sum r_ic x d_i|/N (group polarization and angular "
        "momentum); combine 'unit' averages d_o/|d_o| and d_a/|d_a|. Equation numbers and "
        "Table 1 values not checked against the paper's text (docs/models/couzin.md)")
    summary: ClassVar[str] = (
        "Zones of repulsion, orientation and attraction with a blind angle, a maximum "
        "turning rate and constant speed: swarm, torus, dynamic and highly parallel groups.")
    paper_inclusive: ClassVar[bool] = False
    neighbour_kinds: ClassVar[tuple[str, ...]] = ()  # the zones are the neighbourhoods
    neighbours_note: ClassVar[str] = (
        "none: the zones r_r < r_o = r_r + dr_o < r_a = r_o + dr_a (no neighbours block)")
    state_arrays: ClassVar[tuple[str, ...]] = ("position", "velocity", "heading")
    observables: ClassVar[tuple[str, ...] | None] = COUZIN_OBSERVABLES
    dimensions: ClassVar[tuple[int, ...]] = (2, 3)
    dimensions_note: ClassVar[str] = "the paper's model is 3D; 2D is the same rules in the plane"
    units: ClassVar[tuple[str | None, str | None]] = ("s", None)  # lengths in body lengths
    default_plots: ClassVar[tuple[str, ...]] = ("polarization", "milling")
    details: ClassVar[str] = "docs/models/couzin.md"
    constant_speed: ClassVar[str | None] = "speed"

    kind: Literal["couzin"] = "couzin"
    r_r: PositiveReal = Field(default=1.0, description="r_r (length): the zone of "
                              "repulsion's radius (the paper's 1).")
    dr_o: NonNegativeReal = Field(default=2.0, description="Delta r_o (length): the zone of "
                                  "orientation's width, r_o = r_r + dr_o (paper: 0-15).")
    dr_a: NonNegativeReal = Field(default=14.0, description="Delta r_a (length): the zone of "
                                  "attraction's width, r_a = r_o + dr_a (paper: 0-15).")
    field_of_view: float = Field(
        default=270.0, gt=0.0, le=360.0, allow_inf_nan=False,
        description="alpha (degrees): the field of perception; neighbours in the cone of "
        "360 - alpha behind an agent are not seen for orientation and attraction (paper: "
        "270).")
    turning_rate: PositiveReal = Field(default=40.0, description="theta (degrees per "
                                       "second): the maximum turning rate; an agent turns "
                                       "at most theta * dt per step (paper: 40, tau = 0.1 s).")
    speed: PositiveReal = Field(default=3.0, description="s (length per second): every "
                                "agent's speed (paper: 3).")
    combine: Literal["sum", "unit"] = Field(
        default="sum",
        description="How d_o and d_a are averaged when both zones hold someone: sum: "
        "(d_o + d_a)/2 of the sums as eqs. 2-3 write them (each partner weighs one); "
        "unit: (d_o/|d_o| + d_a/|d_a|)/2 (each zone weighs one).")
    sigma: NonNegativeReal = Field(default=0.05, description="sigma (radians): the s.d. of "
                                   "the wrapped-Gaussian rotation of the desired direction "
                                   "(paper: 0.05).")

    @property
    def r_o(self) -> float:
        return self.r_r + self.dr_o

    @property
    def r_a(self) -> float:
        """The interaction range: the neighbour grid's cell side."""
        return self.r_r + self.dr_o + self.dr_a

    @property
    def max_turn(self) -> float:
        """theta tau in radians at time step tau = 1 (multiply by dt)."""
        return math.radians(self.turning_rate)

    def check_context(self, ctx: ModelContext) -> None:
        if ctx.space != "plane":
            raise ValueError("model 'couzin' runs in unbounded space (space.kind 'plane'), "
                             "as the paper's")
        if ctx.neighbours is not None or ctx.radius is not None:
            raise ValueError("couzin takes no neighbours block: its zones (model.r_r, "
                             "model.dr_o, model.dr_a) are the neighbourhoods")
        if self.max_turn * ctx.dt > math.pi:
            raise ValueError(
                f"model.turning_rate: theta * dt = {self.turning_rate * ctx.dt:g} degrees "
                "per step exceeds 180 (any turn would be allowed); lower it or time.dt")
