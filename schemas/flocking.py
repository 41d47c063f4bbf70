"""M2: flocking with fixed or switching topology (paper 000, Tanner–Jadbabaie–Pappas).

Double integrator (eq. 1): dr_i/dt = v_i, dv_i/dt = u_i, with the control law (eq. 3)
  u_i = - sum_{j in N_i} (v_i - v_j) - sum_{j in N_i} grad_{r_i} V_ij(|r_ij|).
fixed topology: N_i from a given or generated graph; energy W = 1/2 sum_i (V_i + |v_i|^2)
(eq. 4-5). switching topology: i ~ j iff |r_ij| < R (section 5), V_ij saturated beyond R
(U_ij of eq. 10); energy Q of eq. 10.

The pair potential (Definition 2) is V(s) = a / s^2 + ln s^2 + c: `log_barrier` is
(d/s)^2 + ln (s/d)^2 (a = d^2, c = -ln d^2, minimum V(d) = 1 at s = d); `paper002` is
paper 002's 1/s^2 + log s^2 (a = 1, c = 0, minimum at s = 1).
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

import pydantic
from pydantic import Field, model_validator

from .base import NonNegativeInt, PositiveInt, PositiveReal, Strict
from .catalog import ModelContext, ModelParams, Overlay, register_model

# Undirected edges a fixed graph may hold (CSR: 2 x 4 bytes per edge, 400 MB at the limit).
MAX_GRAPH_EDGES = 50_000_000
# Explicit stability limits on the real axis, h * |eigenvalue|: semi-implicit Euler on an
# undamped oscillator (h omega < 2) and on pure damping (h lambda < 2); classic RK4 (2.78).
STABILITY = {"semi_implicit_euler": 2.0, "rk4": 2.78}
# neighbour_search "auto" visits all pairs up to this N; "all_pairs" is refused above the max.
ALL_PAIRS_AUTO = 64
ALL_PAIRS_MAX = 4096

Integrator = Literal["semi_implicit_euler", "rk4"]


class PotentialSpec(Strict):
    """The pair potential V(s) of Definition 2 (paper 000) / U_ij (paper 002)."""

    kind: Literal["log_barrier", "paper002"] = Field(
        default="log_barrier",
        description="log_barrier: V(s) = (d/s)^2 + ln (s/d)^2, minimum V(d) = 1 at s = d. "
        "paper002: V(s) = 1/s^2 + log s^2 (paper 002), minimum at s = 1.",
    )
    d: PositiveReal | None = Field(
        default=None,
        description="Desired inter-agent distance d (length), log_barrier only; default 1.",
    )

    @model_validator(mode="after")
    def _d_only_for_log_barrier(self) -> PotentialSpec:
        if self.kind == "paper002" and self.d is not None:
            raise ValueError(
                "potential 'paper002' is 1/s^2 + log s^2 with its minimum fixed at s = 1; "
                "d applies only to kind 'log_barrier'"
            )
        return self

    @property
    def distance(self) -> float:
        """The minimiser d of V."""
        return 1.0 if self.d is None else self.d

    def coefficients(self) -> tuple[float, float]:
        """(a, c) of V(s) = a / s^2 + ln s^2 + c."""
        if self.kind == "paper002":
            return 1.0, 0.0
        d2 = self.distance**2
        return d2, -math.log(d2)

    def value(self, s: float) -> float:
        a, c = self.coefficients()
        return a / (s * s) + math.log(s * s) + c

    def curvature(self) -> float:
        """V''(d) = 6 a / d^4 - 2 / d^2 = 4 / d^2: the stiffness at the minimum."""
        return 4.0 / self.distance**2


# An edge accepts a JSON array or a Python list or tuple (the items stay strict).
Edge = Annotated[tuple[NonNegativeInt, NonNegativeInt], pydantic.Strict(False)]
GraphKind = Literal["complete", "ring", "path", "tree", "random_connected", "edges"]


class GraphSpec(Strict):
    """A fixed interaction graph on agents 0..N-1 (undirected; no spatial search)."""

    kind: GraphKind = Field(
        description="complete; ring (i ~ i+1 mod N); path (i ~ i+1); tree (b-ary, or a "
        "seeded random recursive tree); random_connected (seeded random spanning tree plus "
        "uniformly random extra edges up to mean_degree); edges (the given edge list).",
    )
    branching: PositiveInt | None = Field(
        default=None,
        description="tree only: b-ary tree, parent of i is (i - 1) // b. null: a random "
        "recursive tree (parent of i uniform among 0..i-1, ids shuffled), seeded.",
    )
    mean_degree: PositiveReal | None = Field(
        default=None,
        description="random_connected only: mean valency 2 E / N, between 2 (N - 1) / N "
        "(a spanning tree) and N - 1 (complete). Default 4.",
    )
    seed: NonNegativeInt | None = Field(
        default=None,
        description="Seed of a random graph (tree without branching, random_connected); "
        "null: the scenario seed.",
    )
    edges: list[Edge] | None = Field(
        default=None, description="edges only: undirected pairs (i, j), i != j, each once."
    )

    @model_validator(mode="after")
    def _fields_match_kind(self) -> GraphSpec:
        owners = {"branching": ("tree",), "mean_degree": ("random_connected",),
                  "seed": ("tree", "random_connected"), "edges": ("edges",)}
        for name, kinds in owners.items():
            if getattr(self, name) is not None and self.kind not in kinds:
                raise ValueError(f"graph.{name} applies only to kind {' or '.join(kinds)}")
        if self.kind == "edges" and not self.edges:
            raise ValueError("graph kind 'edges' needs a non-empty edges list")
        if self.kind == "tree" and self.branching is not None and self.seed is not None:
            raise ValueError("graph.seed applies only to the random tree (branching null)")
        return self

    @property
    def degree(self) -> float:
        return 4.0 if self.mean_degree is None else self.mean_degree

    def n_edges(self, n: int) -> int:
        if self.kind == "complete":
            return n * (n - 1) // 2
        if self.kind == "ring":
            return n if n >= 3 else n - 1
        if self.kind in ("path", "tree"):
            return n - 1
        if self.kind == "random_connected":
            return round(self.degree * n / 2)
        return len(self.edges or [])

    def max_valency(self, n: int) -> int | None:
        """The largest valency when known before generating the graph."""
        if n == 1:
            return 0
        if self.kind == "complete":
            return n - 1
        if self.kind in ("ring", "path"):
            return min(2, n - 1)
        if self.kind == "tree" and self.branching is not None:
            return min(self.branching + 1, n - 1)
        if self.kind == "edges":
            deg: dict[int, int] = {}
            for i, j in self.edges or []:
                deg[i] = deg.get(i, 0) + 1
                deg[j] = deg.get(j, 0) + 1
            return max(deg.values())
        return None

    def check(self, n: int) -> None:
        """Raise ValueError (field-named) if this graph cannot be built on N agents."""
        m = self.n_edges(n)
        if m > MAX_GRAPH_EDGES:
            raise ValueError(
                f"graph '{self.kind}' on N = {n} agents has {m} edges, over the limit of "
                f"{MAX_GRAPH_EDGES}"
            )
        if self.kind == "random_connected":
            lo = 2 * (n - 1) / n
            if not lo - 1e-12 <= self.degree <= n - 1:
                raise ValueError(
                    f"graph.mean_degree = {self.degree:g} must lie in [2 (N-1)/N, N-1] = "
                    f"[{lo:g}, {n - 1}] for N = {n} (a connected graph needs N - 1 edges)"
                )
        if self.kind == "edges":
            seen: set[tuple[int, int]] = set()
            for k, (i, j) in enumerate(self.edges or []):
                if i >= n or j >= n:
                    raise ValueError(f"graph.edges[{k}] = ({i}, {j}) names an agent >= N = {n}")
                if i == j:
                    raise ValueError(f"graph.edges[{k}] = ({i}, {j}) is a self-loop")
                key = (min(i, j), max(i, j))
                if key in seen:
                    raise ValueError(f"graph.edges[{k}] = ({i}, {j}) repeats an earlier edge")
                seen.add(key)


HIST_BINS = 16  # valency_hist_0 .. valency_hist_15, then valency_hist_16plus
# The observables of M2 and M3 (docs/models/flocking.md); each run reports those of its
# variant: W on a fixed graph, Q and Q_reduced on a switching one; valency_<i> (each
# agent's) when N <= valency_per_agent_max, the histogram otherwise; the z components in
# 3D. lambda2, an eigensolve on the host at every observation, is the costly one: a run
# that does not name it skips it.
FLOCK_OBSERVABLES = (
    "speed_min", "speed_mean", "speed_max", "mean_velocity_x", "mean_velocity_y",
    "mean_velocity_z", "velocity_disagreement", "velocity_disagreement_max",
    "heading_spread", "Q", "Q_reduced", "components", "valency_mean", "valency_min",
    "valency_max", "valency_<i>", *(f"valency_hist_{k}" for k in range(HIST_BINS)),
    f"valency_hist_{HIST_BINS}plus", "min_distance", "min_pair_i", "min_pair_j", "lambda2")


class DoubleIntegratorParams(ModelParams):
    """Parameters shared by the double-integrator flocking models (M2, M3)."""

    state_arrays: ClassVar[tuple[str, ...]] = ("position", "velocity", "heading")
    derived_arrays: ClassVar[tuple[str, ...]] = ("degree",)
    units: ClassVar[tuple[str | None, str | None]] = ("s", "m")  # papers 000 and 002
    details: ClassVar[str] = "docs/models/flocking.md"
    overlays: ClassVar[tuple[Overlay, ...]] = ("edges",)

    potential: PotentialSpec = Field(default=PotentialSpec(), description="Pair potential.")
    integrator: Integrator = Field(
        default="semi_implicit_euler",
        description="semi_implicit_euler: v += dt u(r, v); r += dt v (new v). rk4: classic "
        "fourth-order Runge-Kutta on (r, v), neighbour sets re-evaluated at every stage.",
    )
    neighbour_search: Literal["auto", "grid", "all_pairs"] = Field(
        default="auto",
        description="Metric neighbours: the uniform grid, or every pair (O(N^2) but no grid "
        f"rebuild, faster at small N). auto: all_pairs when N <= {ALL_PAIRS_AUTO}.",
    )
    valency_per_agent_max: NonNegativeInt = Field(
        default=32,
        description="Report each agent's valency (Fig. 6 of paper 000) when N <= this; "
        "otherwise a histogram valency_hist_0..15 and valency_hist_16plus.",
    )
    lambda2_max_agents: NonNegativeInt = Field(
        default=2_000,
        description="Compute lambda_2 of the graph Laplacian (sparse shift-invert) only when "
        "N <= this; above it the observable lambda2 reports -1 (not computed).",
    )

    def _check_plane(self, ctx: ModelContext, paper: str) -> None:
        if ctx.space != "plane":
            raise ValueError(
                f"model {self.kind!r} runs on the unbounded plane (space.kind 'plane'), as in "
                f"paper {paper}"
            )

    def uses_all_pairs(self, n: int) -> bool:
        return self.neighbour_search == "all_pairs" or (
            self.neighbour_search == "auto" and n <= ALL_PAIRS_AUTO
        )

    def _check_search(self, ctx: ModelContext) -> None:
        n = ctx.n_agents
        if self.neighbour_search == "all_pairs" and n > ALL_PAIRS_MAX:
            raise ValueError(
                f"neighbour_search 'all_pairs' costs N^2 per step: allowed up to N = "
                f"{ALL_PAIRS_MAX}, here N = {n}; use 'grid' or 'auto'"
            )

    def _check_dt(self, ctx: ModelContext, max_valency: int | None) -> None:
        """Reject a dt beyond the integrator's explicit stability limit for (a) a pair
        oscillating at the potential's minimum, omega^2 = 2 V''(d), and (b) the alignment
        term, whose Laplacian eigenvalues are at most 2 * (largest valency) when known."""
        dt = ctx.dt
        limit = STABILITY[self.integrator]
        omega = math.sqrt(2.0 * self.potential.curvature())
        if dt * omega >= limit:
            raise ValueError(
                f"time.dt = {dt:g} is too large for the pair potential: a pair oscillates at "
                f"omega = sqrt(2 V''(d)) = {omega:.4g} rad/s about d = "
                f"{self.potential.distance:g}, and {self.integrator} needs dt * omega < "
                f"{limit:g} (dt < {limit / omega:.4g})"
            )
        if max_valency:
            lam = 2.0 * max_valency
            if dt * lam >= limit:
                raise ValueError(
                    f"time.dt = {dt:g} is too large for the alignment term: the graph's "
                    f"largest valency is {max_valency}, so its Laplacian eigenvalues reach "
                    f"up to {lam:g} and {self.integrator} needs dt * lambda_max < {limit:g} "
                    f"(dt < {limit / lam:.4g})"
                )


@register_model
class FlockingParams(DoubleIntegratorParams):
    """Tanner–Jadbabaie–Pappas flocking of double integrators."""

    paper: ClassVar[str] = (
        "000 Tanner, Jadbabaie, Pappas, Flocking agents with varying interconnection topology"
    )
    equations: ClassVar[str] = (
        "eq. 1 (double integrator), eq. 3 (u_i), eq. 4-5 (V_i, W; fixed topology), "
        "section 5 (i ~ j iff |r_ij| < R) and eq. 10 (saturated U_ij, Q; switching)"
    )
    summary: ClassVar[str] = (
        "Double integrators aligning velocities and keeping distance through pair potentials, "
        "on a fixed graph or the proximity graph |r_ij| < R."
    )
    paper_inclusive: ClassVar[bool] = False
    observables: ClassVar[tuple[str, ...] | None] = (*FLOCK_OBSERVABLES, "W")
    dimensions: ClassVar[tuple[int, ...]] = (2, 3)
    default_plots: ClassVar[tuple[str, ...]] = (
        "velocity_disagreement", "speed_mean", "components")
    neighbour_kinds: ClassVar[tuple[str, ...]] = ("metric", "topological")
    neighbours_note: ClassVar[str] = (
        "topology 'switching' only: N_i = the k nearest within R = neighbours.radius "
        "(required: V saturates at R, eq. 10), the same u_i (eq. 3) over them (RK4: "
        "searched again at each stage); per-step schedule only; degree is k for every agent with k "
        "others within R (asymmetric graph unless symmetric); Q (eq. 10-11) is not "
        "checked, since links then switch at any distance, not at R")

    kind: Literal["flocking"] = "flocking"
    topology: Literal["fixed", "switching"] = Field(
        default="switching",
        description="fixed: neighbours from model.graph, never changing (section 4). "
        "switching: i ~ j iff |r_ij| < R = neighbours.radius (section 5).",
    )
    graph: GraphSpec | None = Field(
        default=None, description="The fixed graph (topology 'fixed' only)."
    )

    def non_increasing(self) -> dict[str, str]:
        if self.topology == "fixed":
            return {"W": "paper 000, eq. 5-6: the energy W of a fixed graph never increases"}
        return {"Q": "paper 000, eq. 10-11: Q never increases under switching"}

    def check_context(self, ctx: ModelContext) -> None:
        self._check_plane(ctx, "000")
        n = ctx.n_agents
        if self.topology == "fixed":
            if self.graph is None:
                raise ValueError("topology 'fixed' needs model.graph (e.g. {'kind': 'ring'})")
            if ctx.neighbours is not None:
                raise ValueError(
                    "topology 'fixed' takes its neighbours from model.graph; remove the "
                    "neighbours block (it would be ignored)"
                )
            if self.neighbour_search != "auto":
                raise ValueError("neighbour_search applies to topology 'switching' only")
            self.graph.check(n)
            self._check_dt(ctx, self.graph.max_valency(n))
            return
        if self.graph is not None:
            raise ValueError("model.graph applies only to topology 'fixed'")
        if ctx.radius is None:
            raise ValueError(
                "topology 'switching' needs a neighbours block with the radius R "
                "(section 5: i ~ j iff |r_ij| < R; topological: the k nearest within R)"
            )
        if ctx.neighbours == "topological" and self.neighbour_search == "all_pairs":
            raise ValueError("neighbour_search 'all_pairs' applies to metric neighbours; "
                             "topological ones are searched on their grid")
        check_radius_exceeds_d(ctx.radius, self.potential)
        self._check_search(ctx)
        self._check_dt(ctx, None)


def check_radius_exceeds_d(radius: float, potential: PotentialSpec) -> None:
    """Lemma 1 (paper 000) assumes the desired distance is below R, so V increases at R."""
    if radius <= potential.distance:
        raise ValueError(
            f"neighbours.radius R = {radius:g} must exceed the potential's desired distance "
            f"d = {potential.distance:g} (paper 000, Lemma 1: V_ij increasing at R)"
        )
