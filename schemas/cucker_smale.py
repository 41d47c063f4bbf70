"""Cucker–Smale flocking (Cucker & Smale, IEEE TAC 52(5), 852–862, 2007).

Double integrator with velocity alignment weighted by distance:
  dx_i/dt = v_i,  dv_i/dt = (lambda / D_i) sum_j psi(|x_j - x_i|) (v_j - v_i),
  psi(r) = K / (sigma^2 + r^2)^beta,
with D_i = N (normalization "mean", the usual lambda/N form), 1 ("sum", the paper's
un-normalised a_ij sum) or sum_j psi(|x_j - x_i|) over every j, i included ("local", the
Motsch–Tadmor 2011 variant: row-stochastic weights, not symmetric). beta < 1/2:
unconditional flocking (velocities converge to a common one, the position diameter stays
bounded; Ha & Liu 2009 extend it to beta <= 1/2).

A `cutoff` radius sets psi to zero from that distance on (|x_ij| < cutoff interacts):
found on the uniform grid at any N. It changes the model: the theorems above are for the
all-to-all psi, and a cut-off swarm may split into groups that never meet again.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from .base import NonNegativeReal, PositiveReal
from .catalog import ModelContext, ModelParams, register_model

# All-to-all costs N^2 per step: allowed up to this N (above it: a cutoff on the grid).
ALL_TO_ALL_MAX = 10_000
# Explicit stability limits on the real axis, h * |eigenvalue| (as schemas/flocking.py):
# Euler on pure damping (2), classic RK4 (2.78).
STABILITY = {"semi_implicit_euler": 2.0, "rk4": 2.78}

CS_OBSERVABLES = ("velocity_diameter", "position_diameter", "mean_velocity_x",
                  "mean_velocity_y", "mean_velocity_z", "velocity_variance")


@register_model
class CuckerSmaleParams(ModelParams):
    """Cucker–Smale alignment of double integrators, all-to-all or with a cutoff."""

    paper: ClassVar[str] = "Cucker, Smale, Emergent behavior in flocks, IEEE TAC 52(5), 2007"
    equations: ClassVar[str] = (
        "the model v_i(t+h) - v_i(t) = h sum_j a_ij (v_j - v_i), a_ij = H / (1 + r^2)^beta "
        "(normalization 'sum'; K = H, sigma = 1; eq. 1 of the authors' 'Mathematics of "
        "emergence', 2007, drawn from the TAC paper, whose numbers are to check), its "
        "continuous form dv/dt = -L_x v, Theorem 1 (beta < 1/2: unconditional flocking); "
        "'mean': lambda/N (Ha & Liu 2009); 'local': Motsch & Tadmor, J. Stat. Phys. 144, 2011"
    )
    summary: ClassVar[str] = (
        "Velocity alignment weighted by psi(r) = K / (sigma^2 + r^2)^beta, all-to-all "
        "(N <= 10^4) or with a cutoff on the grid (a cutoff changes the model)."
    )
    paper_inclusive: ClassVar[bool] = False
    neighbour_kinds: ClassVar[tuple[str, ...]] = ()  # no neighbours block: all pairs or a cutoff
    neighbours_note: ClassVar[str] = (
        "none: all-to-all, or the pairs closer than model.cutoff (no neighbours block)")
    state_arrays: ClassVar[tuple[str, ...]] = ("position", "velocity", "heading")
    observables: ClassVar[tuple[str, ...] | None] = CS_OBSERVABLES
    dimensions: ClassVar[tuple[int, ...]] = (2, 3)
    units: ClassVar[tuple[str | None, str | None]] = (None, None)  # the paper has none
    default_plots: ClassVar[tuple[str, ...]] = ("velocity_diameter", "position_diameter")
    details: ClassVar[str] = "docs/models/cucker_smale.md"

    kind: Literal["cucker_smale"] = "cucker_smale"
    K: PositiveReal = Field(default=1.0, description="K: the weight's strength, psi(0) = "
                            "K / sigma^(2 beta) (the paper's H).")
    sigma: PositiveReal = Field(default=1.0, description="sigma (length): the weight's "
                                "core radius (the paper's 1).")
    beta: NonNegativeReal = Field(default=0.25, description="beta: the weight's decay, "
                                  "psi ~ r^(-2 beta); beta < 1/2 flocks unconditionally "
                                  "(Theorem 1).")
    coupling: PositiveReal = Field(default=1.0, description="lambda (1/time): the coupling "
                                   "strength in front of the sum.")
    normalization: Literal["mean", "sum", "local"] = Field(
        default="mean",
        description="mean: lambda/N sum_j; sum: lambda sum_j (the paper's a_ij sum); local: "
        "lambda / sum_j psi_ij sum_j (Motsch-Tadmor, i included in the denominator).",
    )
    cutoff: PositiveReal | None = Field(
        default=None,
        description="null: all-to-all (N <= 10^4). A radius: psi = 0 from |x_ij| = cutoff "
        "on, neighbours found on the uniform grid at any N. THIS CHANGES THE MODEL: the "
        "unconditional-flocking theorem is for all-to-all psi; a cut-off swarm can split.",
    )
    integrator: Literal["semi_implicit_euler", "rk4"] = Field(
        default="semi_implicit_euler",
        description="semi_implicit_euler: v += dt u(x, v); x += dt v (new v). rk4: classic "
        "fourth-order Runge-Kutta on (x, v), neighbours re-found at every stage.",
    )

    @property
    def psi_max(self) -> float:
        """psi(0) = K / sigma^(2 beta), the largest weight."""
        return self.K / self.sigma ** (2.0 * self.beta)

    def rate_bound(self, n: int) -> float:
        """An upper bound on the alignment's decay rates (the eigenvalues of the linearised
        v' = -lambda L v / D): a Laplacian with weights <= psi_max is below psi_max times
        the complete graph's, whose eigenvalues are N; row-normalised ('local'), at most 2."""
        if self.normalization == "local":
            return 2.0 * self.coupling
        scale = 1.0 if self.normalization == "mean" else float(n)
        return self.coupling * self.psi_max * scale

    def check_context(self, ctx: ModelContext) -> None:
        if ctx.space != "plane":
            raise ValueError("model 'cucker_smale' runs on the unbounded plane (space.kind "
                             "'plane'), as the paper's R^d")
        if ctx.neighbours is not None or ctx.radius is not None:
            raise ValueError("cucker_smale takes no neighbours block: every pair interacts "
                             "(all-to-all), or those closer than model.cutoff")
        if self.cutoff is None and ctx.n_agents > ALL_TO_ALL_MAX:
            raise ValueError(
                f"model.cutoff: all-to-all costs N^2 per step, allowed up to N = "
                f"{ALL_TO_ALL_MAX}, here N = {ctx.n_agents}; set model.cutoff (a radius: "
                "it changes the model)")
        lam = self.rate_bound(ctx.n_agents)
        limit = STABILITY[self.integrator]
        if ctx.dt * lam >= limit:
            raise ValueError(
                f"time.dt = {ctx.dt:g} is too large: the alignment's rates reach up to "
                f"{lam:.4g} (coupling * psi(0){' * N' if self.normalization == 'sum' else ''}"
                f"; normalization {self.normalization!r}) and {self.integrator} needs "
                f"dt * rate < {limit:g} (dt < {limit / lam:.4g})")
