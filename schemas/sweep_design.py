"""Sampling designs for a sweep (`design`) and the sensitivity analysis of one measure over
them (`analysis`).

A design draws its points in the unit cube [0, 1)^D, D the number of `bounds`, then maps
coordinate u of each path onto its bounds [lo, hi]:

  plain     lo + u (hi - lo)
  log       exp(log lo + u (log hi - log lo))        (lo > 0: uniform in the logarithm)
  integer   lo + floor(u (hi - lo + 1)), at most hi  (every integer lo .. hi equally likely;
            with log, the log-mapped value rounded to the nearest integer)

Kinds (the points in order; every one a grid point of the sweep):
  lhs      scipy.stats.qmc.LatinHypercube(D, rng=seed): n points, one in each of the n
           equal strata of every axis
  halton   scipy.stats.qmc.Halton(D, scramble=True, rng=seed): n points
  sobol    scipy.stats.qmc.Sobol(D, scramble=True, rng=seed): n points (n a power of 2, so
           the sequence is balanced); with analysis 'sobol', Saltelli's cross-sampling for
           first-order and total indices, SALib.sample.sobol.sample(calc_second_order=
           False, seed=seed): n (D + 2) points
  morris   SALib.sample.morris.sample(N=n trajectories, num_levels=levels, seed=seed):
           n (D + 1) points on a grid of `levels` levels per axis

The same design (kind, n, seed, bounds, log, integer, levels, and the analysis kind) gives
the same points with the pinned scipy and SALib. scipy and SALib are imported only when
the points are drawn (`pip install 'flocklab[design]'`), numpy too (schemas/ stays
pydantic at import).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import Field, StrictStr, field_validator, model_validator

from .base import NonNegativeInt, PositiveInt, RealPair, Strict
from .paths import split_path

if TYPE_CHECKING:
    import numpy as np

# The most points a design may draw (the sweep's run limit applies on top).
MAX_DESIGN_POINTS = 100_000
# The most parameters one design may sample (a flocking model has 5-15).
MAX_DESIGN_AXES = 64


class DesignUnavailable(ValueError):
    """scipy or SALib, which draw the points, is not installed (a ValueError: inside a
    sweep's validation it becomes one of the sweep's problems)."""


class Design(Strict):
    """Points of a sampling design over the scenario fields named in `bounds`."""

    kind: Literal["lhs", "sobol", "halton", "morris"] = Field(
        description="lhs (Latin hypercube), sobol (scrambled Sobol' sequence; Saltelli's "
        "scheme with analysis 'sobol'), halton (scrambled Halton), morris (Morris "
        "trajectories, SALib).")
    n: PositiveInt = Field(le=MAX_DESIGN_POINTS, description="Points (lhs, halton, sobol), "
                           "base samples (sobol with analysis 'sobol': n (D + 2) points) or "
                           "trajectories (morris: n (D + 1) points).")
    seed: Annotated[NonNegativeInt, Field(lt=2**63)] = Field(
        description="Seed of the design's random scrambling / permutation: the same seed, "
        "the same points.")
    bounds: dict[StrictStr, RealPair] = Field(
        min_length=1, max_length=MAX_DESIGN_AXES, description="Dotted field path -> "
        "[low, high] (high > low); one "
        "design axis each, a column of runs.csv and table.csv.",
        examples=[{"model.eta": [0, 5], "neighbours.radius": [0.5, 2]}])
    log: list[StrictStr] = Field(default=[], description="Paths sampled uniformly in the "
                                 "logarithm (their low bound > 0).")
    integer: list[StrictStr] = Field(default=[], description="Paths whose values are "
                                     "integers low .. high (integral bounds).")
    levels: PositiveInt = Field(default=4, ge=2, le=1000, description="morris only: the "
                                "grid levels per axis (SALib's num_levels; even is usual).")

    @field_validator("bounds")
    @classmethod
    def _bounds(cls, v: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
        for path, (lo, hi) in v.items():
            split_path(path)
            if path in ("seed", "replicas"):
                raise ValueError(f"{path!r} cannot be a design axis")
            if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
                raise ValueError(f"{path}: bounds [{lo}, {hi}] need finite low < high")
        return v

    @model_validator(mode="after")
    def _flags(self) -> Design:
        for name in ("log", "integer"):
            extra = [p for p in getattr(self, name) if p not in self.bounds]
            if extra:
                raise ValueError(f"{name}: {', '.join(extra)} not in bounds")
        for p in self.log:
            if self.bounds[p][0] <= 0:
                raise ValueError(f"log: {p} needs a low bound > 0, not {self.bounds[p][0]}")
        for p in self.integer:
            if any(b != math.floor(b) for b in self.bounds[p]):
                raise ValueError(f"integer: {p} needs integral bounds, not "
                                 f"{list(self.bounds[p])}")
        if self.levels != 4 and self.kind != "morris":
            raise ValueError("levels applies to kind 'morris' only")
        if self.kind == "sobol" and self.n & (self.n - 1):
            raise ValueError(f"a sobol design needs n a power of 2 (a balanced sequence), "
                             f"not {self.n}")
        return self

    def n_points(self, analysis: Literal["sobol", "morris"] | None = None) -> int:
        d = len(self.bounds)
        if self.kind == "morris":
            return self.n * (d + 1)
        if self.kind == "sobol" and analysis == "sobol":
            return self.n * (d + 2)
        return self.n

    def unit_points(self, analysis: Literal["sobol", "morris"] | None = None) -> np.ndarray:
        """The points in the unit cube, shape (n_points, D), axes in `bounds` order."""
        d = len(self.bounds)
        try:
            from scipy.stats import qmc

            if self.kind in ("morris", "sobol") and (self.kind == "morris"
                                                     or analysis == "sobol"):
                from SALib.sample import morris, sobol
        except ImportError as exc:
            raise DesignUnavailable(f"a '{self.kind}' design needs {exc.name}: pip "
                                    "install 'flocklab[design]'") from None
        if self.kind == "lhs":
            return qmc.LatinHypercube(d, rng=self.seed).random(self.n)
        if self.kind == "halton":
            return qmc.Halton(d, scramble=True, rng=self.seed).random(self.n)
        unit = {"num_vars": d, "names": list(self.bounds), "bounds": [[0.0, 1.0]] * d}
        if self.kind == "morris":
            return morris.sample(unit, self.n, num_levels=self.levels, seed=self.seed)
        if analysis == "sobol":
            return sobol.sample(unit, self.n, calc_second_order=False, scramble=True,
                                seed=self.seed)
        return qmc.Sobol(d, scramble=True, rng=self.seed).random(self.n)

    def points(self, analysis: Literal["sobol", "morris"] | None = None
               ) -> list[dict[str, Any]]:
        """path -> value for each point, the unit points mapped onto the bounds."""
        u = self.unit_points(analysis)
        columns = [self._map(path, u[:, j]) for j, path in enumerate(self.bounds)]
        return [dict(zip(self.bounds, row, strict=True)) for row in zip(*columns, strict=True)]

    def _map(self, path: str, u: np.ndarray) -> list[Any]:
        import numpy as np

        lo, hi = self.bounds[path]
        if path in self.log:
            x = np.exp(math.log(lo) + u * (math.log(hi) - math.log(lo)))
            x = np.where(u <= 0, lo, np.where(u >= 1, hi, np.clip(x, lo, hi)))  # exact ends
            if path in self.integer:
                return [int(v) for v in np.clip(np.rint(x), lo, hi)]
            return [float(v) for v in x]
        if path in self.integer:
            return [int(v) for v in np.minimum(lo + np.floor(u * (hi - lo + 1)), hi)]
        return [float(v) for v in lo + u * (hi - lo)]


class Analysis(Strict):
    """A sensitivity analysis of one table quantity over the design (sensitivity.csv)."""

    kind: Literal["sobol", "morris"] = Field(
        description="sobol: first-order and total Sobol' indices with bootstrap confidence "
        "intervals (needs design kind 'sobol'); morris: mu, mu*, sigma of the elementary "
        "effects and mu*'s confidence interval (needs design kind 'morris'). SALib.")
    measure: StrictStr = Field(description="A measure's name (or a quantity of table.csv "
                               "such as 'phi_m1'); its per-point mean over replicas is the "
                               "model output.")
    conf_level: float = Field(default=0.95, gt=0, lt=1, description="Of the intervals.")
    resamples: PositiveInt = Field(default=1000, le=100_000, description="Bootstrap "
                                   "resamples of the intervals.")
    seed: Annotated[NonNegativeInt, Field(lt=2**32)] = Field(
        default=0, description="Seed of the bootstrap.")


def design_problems(design: Design | None, analysis: Analysis, has_axes: bool,
                    quantities: set[str], max_points: int) -> list[str]:
    """What is wrong with an analysis given the sweep's design, axes and table quantities
    (empty: nothing); the points are not drawn."""
    problems = []
    if design is None:
        problems.append("an analysis needs a design")
    elif design.kind != analysis.kind:
        problems.append(f"'{analysis.kind}' needs a design of kind '{analysis.kind}', not "
                        f"'{design.kind}'")
    elif design.n_points(analysis.kind) > max_points:
        problems.append(f"the design has {design.n_points(analysis.kind)} points with this "
                        f"analysis, more than the limit of {max_points} runs")
    if has_axes:
        problems.append("an analysis needs a design without axes (every grid point must be "
                        "a design point)")
    if analysis.measure not in quantities:
        problems.append(f"measure {analysis.measure!r} is not a quantity of the table "
                        f"(known: {', '.join(sorted(quantities)) or 'none'})")
    return problems
