"""M1: Vicsek and the Jadbabaie–Lin–Morse heading rules (paper 001).

Agents move at a common speed v0 with heading theta_i; x_i(t+1) = x_i(t) + v0 dt e(theta_i).
Heading rules over the closed neighbourhood N_i ∪ {i}, N_i = {j : |r_ij| <= r} (metric) or
the k nearest other agents (topological, Ballerini et al. 2008):
  vicsek    theta_i <- arg sum_j e^{i theta_j} + xi_i               (Vicsek et al. 1995)
  average   theta_i <- (theta_i + sum_{N_i} theta_j) / (1 + n_i)    (eq. 1-2)
  laplacian theta   <- theta - (1/g) L theta,  g > N                (eq. 17-18)
  leader    theta_i <- (theta_i + sum_{N_i} theta_j + b_i theta_0) / (1 + n_i + b_i)   (eq. 22)
xi_i is uniform in [-eta/2, eta/2] (optional for the JLM rules, whose theorems are noise-free).
In 3D (rule vicsek only) the noise turns the mean direction to a direction uniform in the
spherical cap of half-angle eta/2 around it (docs/MODELS_3D.md).
noise "vectorial" (rule vicsek, Grégoire & Chaté 2004): e(theta_i) <- w / |w|,
w = sum_{N_i ∪ {i}} e(theta_j) + eta n_i u_i, u_i a random unit vector, n_i = |N_i ∪ {i}|.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

from pydantic import Field, StrictBool, StrictFloat

from .base import NonNegativeReal, PositiveReal, Real
from .catalog import ModelContext, ModelParams, Overlay, register_model

Rule = Literal["vicsek", "average", "laplacian", "leader"]


@register_model
class VicsekParams(ModelParams):
    """Vicsek / Jadbabaie–Lin–Morse nearest-neighbour heading rules."""

    paper: ClassVar[str] = "001 Jadbabaie, Lin, Morse (2003); Vicsek et al. (1995)"
    equations: ClassVar[str] = (
        "vicsek: arg-sum of unit vectors + noise; average: eq. 1-2 (F = (I+D)^-1 (A+I)); "
        "laplacian: eq. 17-18, theta <- theta - L theta / g, g > N; leader: eq. 22; "
        "noise 'vectorial': Grégoire-Chaté (2004), e <- w/|w|, w = sum e_j + eta n_i u_i"
    )
    summary: ClassVar[str] = "Constant-speed agents aligning headings with their neighbours."
    paper_inclusive: ClassVar[bool] = True
    state_arrays: ClassVar[tuple[str, ...]] = ("position", "heading")
    derived_arrays: ClassVar[tuple[str, ...]] = ("degree",)
    observables: ClassVar[tuple[str, ...] | None] = (
        "polarization", "heading_spread", "leader_error", "components", "degree_mean",
        "degree_min", "degree_max", "isolated", "linked_intervals")
    dimensions: ClassVar[tuple[int, ...]] = (2, 3)
    dimensions_note: ClassVar[str] = (
        "3D for rule vicsek only: average, laplacian and leader act on angles (2D)")
    default_plots: ClassVar[tuple[str, ...]] = ("polarization", "heading_spread", "components")
    details: ClassVar[str] = "docs/models/vicsek.md"
    overlays: ClassVar[tuple[Overlay, ...]] = ("edges", "marked")
    constant_speed: ClassVar[str | None] = "v0"
    neighbour_kinds: ClassVar[tuple[str, ...]] = ("metric", "topological")
    neighbours_note: ClassVar[str] = (
        "every rule sums over {i} and its k nearest (Ballerini et al. 2008; Ginelli & Chate "
        "2010), per-step schedule only; degree is k for every agent (asymmetric graph)")

    kind: Literal["vicsek"] = "vicsek"
    rule: Rule = Field(default="vicsek", description="Heading update rule.")
    v0: NonNegativeReal = Field(default=0.03, description="Common speed (length per time).")
    # Its own bounds, not NonNegativeReal's: pydantic keeps the last `le` of the merged
    # metadata, so a field `le` beside the type's 1e300 bound was silently dropped.
    eta: Annotated[float, Field(ge=0, le=6.283185307179586 + 1e-12, allow_inf_nan=False),
                   StrictFloat] = Field(
        default=0.0,
        description="Noise amplitude: xi uniform in [-eta/2, eta/2] (radians), per agent "
        "and step; in 3D a direction uniform in the spherical cap of half-angle eta/2 "
        "around the mean. 0 for the JLM theorems.",
    )
    noise: Literal["angular", "vectorial"] = Field(
        default="angular",
        description="Rule vicsek's noise. angular (Vicsek 1995): the mean direction turned by "
        "xi uniform in [-eta/2, eta/2] (3D: into the cap of half-angle eta/2). vectorial "
        "(Grégoire & Chaté 2004, 'extrinsic'): e_i <- w/|w|, w = sum_j e_j + eta n_i u_i over "
        "the closed neighbourhood (n_i agents), u_i a random unit vector: eta is the noise's "
        "length against a fully aligned neighbourhood's mean (the literature moves with the "
        "new heading: position_update new_heading). docs/models/vicsek.md relates the "
        "two eta scales.",
    )
    g: PositiveReal | None = Field(
        default=None, description="Laplacian rule gain denominator; must exceed N (eq. 18)."
    )
    leader_heading: Real = Field(
        default=0.0, description="theta_0 of the leader (agent 0) for the leader rule (rad)."
    )
    position_update: Literal["old_heading", "new_heading"] = Field(
        default="old_heading",
        description="Move with theta(t) (synchronous, as x(t+1) = x(t) + v(t) dt) or with "
        "theta(t+1).",
    )
    track_linked_intervals: StrictBool | None = Field(
        default=None,
        description="Track Theorem 2's 'linked together' intervals (one union-find pass per "
        "step; the linked_intervals observable and summary entry). null: on when "
        "recording.observables names linked_intervals, or when it is null and the rule is "
        "one whose theorem the intervals check (average and laplacian: Theorem 2; leader: "
        "Theorem 4, a union graph connected over all agents links every follower to the "
        "leader) with N <= 100000; off for the vicsek rule, which no theorem covers.",
    )

    def tracks_linked(self, n_agents: int, observables: list[str] | None) -> bool:
        """Whether a run tracks the linked intervals (`track_linked_intervals`)."""
        if self.track_linked_intervals is not None:
            return self.track_linked_intervals
        if observables is not None:
            return "linked_intervals" in observables
        return self.rule in ("average", "laplacian", "leader") and n_agents <= 100_000

    def check_context(self, ctx: ModelContext) -> None:
        if ctx.neighbours is None:
            raise ValueError("model vicsek needs a neighbours block: the radius r (metric) "
                             "or k (topological)")
        n = ctx.n_agents
        if self.noise == "vectorial" and self.rule != "vicsek":
            raise ValueError(
                f"noise 'vectorial' adds a random vector to the sum of unit headings: rule "
                f"'vicsek' only (rule {self.rule!r} averages angles)")
        if ctx.dimension != 2 and self.rule != "vicsek":
            raise ValueError(
                f"rule {self.rule!r} averages headings as angles and runs in 2D only; "
                f"space.dimension = {ctx.dimension} needs rule 'vicsek'")
        if self.rule == "laplacian":
            if self.g is None:
                raise ValueError(f"rule 'laplacian' needs g > N = {n} (eq. 18)")
            if self.g <= n:
                raise ValueError(f"rule 'laplacian' needs g > N: g = {self.g:g} <= N = {n}")
        elif self.g is not None:
            raise ValueError("g applies only to rule 'laplacian'")
        if self.rule == "leader" and n < 2:
            raise ValueError("rule 'leader' needs N >= 2 (agent 0 is the leader)")

    def scene(self) -> dict[str, Any]:
        """The leader rule's agent 0 (eq. 22), ringed."""
        if self.rule != "leader":
            return {}
        return {"marked": [0], "marked_label": "leader (agent 0, eq. 22)"}
