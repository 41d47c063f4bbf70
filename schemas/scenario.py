"""The Scenario: the whole wire contract for one simulation run."""

from __future__ import annotations

import math

from pydantic import Field, StrictInt, model_validator

from .base import Strict
from .catalog import MODELS, ModelContext
from .common import (
    Backend,
    Convergence,
    ExplicitInitial,
    Initial,
    Neighbours,
    PeriodicBox,
    Precision,
    Recording,
    Space,
    TimeSpec,
)
from .models import ModelSpec
from .presets import PRESETS

# Taichi indexes with 32-bit integers: N times the components per agent must stay below it.
MAX_INDEX = 2**31 - 1
SCHEMA_VERSION = 1


class Scenario(Strict):
    """A complete, validated simulation request. Canonical JSON is `model_dump(mode="json")`."""

    schema_version: StrictInt = Field(default=SCHEMA_VERSION, ge=1, le=SCHEMA_VERSION)
    name: str | None = Field(default=None, max_length=200, description="Free-form label.")
    model: ModelSpec = Field(description="Model family and its parameters (by `kind`).")
    space: Space = Field(default=PeriodicBox(L=10.0), description="Periodic box or plane.")
    neighbours: Neighbours | None = Field(
        default=None,
        description="The neighbourhood: metric (a radius, the default kind) or topological "
        "(the k nearest); required by models with neighbours."
    )
    initial: Initial = Field(description="Initial state (random with the seed, or explicit).")
    time: TimeSpec = Field(description="Steps and step length.")
    recording: Recording = Field(default=Recording(), description="Frames and observables.")
    convergence: Convergence = Field(default=Convergence())
    seed: StrictInt = Field(default=0, ge=0, lt=2**63, description="Seed for all randomness.")
    backend: Backend = Field(
        default="cpu",
        description="Taichi backend: cpu, cuda, vulkan, or auto (a GPU if one works, else cpu).",
    )
    threads: StrictInt | None = Field(
        default=None, ge=1, le=1024, description="CPU threads (default: all allowed cores)."
    )
    precision: Precision = Field(
        default="float64",
        description="The engine's arithmetic: every position, velocity, heading, parameter "
        "and pair sum is held and computed in this type (float64: what the papers' theorem "
        "checks assume; float32: half the memory traffic, for large N and GPUs). Integers "
        "(steps, counters, ids) and the noise's 32 random bits are the same in both. Not "
        "the storage type of the recorded frames: `recording.precision` only converts what "
        "is written.",
    )

    @property
    def n_agents(self) -> int:
        return self.initial.N

    @property
    def dimension(self) -> int:
        """2 or 3: the space's (every vector of the state has this many components)."""
        return self.space.dimension

    @property
    def inclusive(self) -> bool:
        """The neighbourhood test in force: the scenario's choice or the paper's."""
        chosen = self.neighbours.inclusive if self.neighbours else None
        return type(self.model).paper_inclusive if chosen is None else chosen

    @property
    def n_frames(self) -> int:
        every = self.recording.every
        if every == 0:
            return 0
        # Frames at 0, k, 2k, ... and always the final state.
        return self.time.steps // every + 1 + (1 if self.time.steps % every else 0)

    def _check_dimension(self) -> None:
        """The initial state's points have space.dimension coordinates."""
        d = self.dimension
        init = self.initial
        if isinstance(init, ExplicitInitial):
            if init.dimension != d:
                raise ValueError(f"space.dimension: initial.positions have {init.dimension} "
                                 f"coordinates, space.dimension is {d}")
            return
        region = init.region
        if region is not None and region.dimension != d:
            raise ValueError(f"space.dimension: initial.region {region.kind!r} is "
                             f"{region.dimension}D, space.dimension is {d} (3D regions: "
                             "box and lattice with 3 coordinates, ball)")
        if d == 3 and init.heading_range != (-math.pi, math.pi):
            raise ValueError("space.dimension: initial.heading_range is 2D; in 3D the "
                             "initial directions are uniform on the sphere")

    def _check_derived_arrays(self) -> None:
        """recording.arrays names only the derived arrays the model has (degree, radius)."""
        model = type(self.model)
        missing = [a for a in self.recording.derived if a not in model.derived_arrays]
        if not missing:
            return
        has = [*model.state_arrays, *model.derived_arrays]
        why = {"degree": "it keeps no per-agent degree",
               "radius": "its agents share one radius, neighbours.radius (per-agent radii "
                         "R_i: flocking_obstacles)"}
        raise ValueError(
            f"recording.arrays: model {self.model.kind} cannot record "
            f"{', '.join(missing)} ({'; '.join(why[a] for a in missing)}); it records "
            f"{', '.join(has)}")

    def _check_neighbour_kind(self) -> None:
        """neighbours.kind is one the model runs with (topological: the Vicsek family)."""
        nb = self.neighbours
        kinds = type(self.model).neighbour_kinds
        # A model with no neighbour kinds refuses any neighbours block in its own words.
        if nb is not None and kinds and nb.kind not in kinds:
            with_it = [k for k, m in MODELS.items() if nb.kind in m.neighbour_kinds]
            raise ValueError(
                f"neighbours.kind: model {self.model.kind} takes {' or '.join(kinds)} "
                f"neighbours only, not {nb.kind!r} (models with {nb.kind} neighbours: "
                f"{', '.join(with_it) or 'none'})")

    @model_validator(mode="after")
    def _cross_checks(self) -> Scenario:
        n = self.n_agents
        if 4 * n > MAX_INDEX:
            raise ValueError(f"N = {n} is too large for 32-bit indexing (N * 4 < 2^31)")
        if self.n_frames > self.recording.max_frames:
            raise ValueError(
                f"recording every {self.recording.every} steps gives {self.n_frames} frames "
                f"> recording.max_frames = {self.recording.max_frames}"
            )
        init = self.initial
        self._check_dimension()
        if isinstance(self.space, PeriodicBox) and not isinstance(init, ExplicitInitial):
            region = init.region
            if region is not None and region.kind in ("box", "lattice"):
                lo = region.low
                hi = region.high if region.kind == "box" else [
                    c + region.spacing * region.side(init.N) for c in lo]
                if min(lo) < 0 or max(hi) > self.space.L:
                    raise ValueError("initial.region must lie inside the periodic box "
                                     f"[0, L]^{self.dimension}")
        if (
            not isinstance(init, ExplicitInitial)
            and init.region is None
            and not isinstance(self.space, PeriodicBox)
        ):
            raise ValueError("initial.region is required on the unbounded plane")
        # Any radius in the periodic box: each pair interacts through its minimum image
        # only, which also holds beyond L/2, where a ball of radius r wraps onto itself;
        # from the half-diagonal L sqrt(dim) / 2 on, every pair is within r.
        self._check_derived_arrays()
        chosen = self.recording.observables
        if chosen is not None:
            known = type(self.model).observables
            if known is None:
                raise ValueError(
                    f"recording.observables: model {self.model.kind} does not declare its "
                    "observables; leave it null (all are evaluated)")
            unknown = sorted(n for n in set(chosen) if not type(self.model).reports(n))
            if unknown:
                raise ValueError(
                    f"recording.observables: {', '.join(unknown)} not reported by model "
                    f"{self.model.kind}; it reports {type(self.model).observables_listing()}")
        dims = type(self.model).dimensions
        if self.dimension not in dims:
            raise ValueError(
                f"space.dimension: model {self.model.kind} runs in dimension "
                f"{' or '.join(map(str, dims))}, not {self.dimension}")
        self._check_neighbour_kind()
        nb = self.neighbours
        ctx = ModelContext(
            n_agents=self.n_agents, dimension=self.dimension, space=self.space.kind,
            radius=None if nb is None else nb.radius, dt=self.time.dt,
            neighbours=None if nb is None else nb.kind)
        try:
            self.model.check_context(ctx)
        except ValueError as exc:
            raise ValueError(f"model: {exc}") from exc
        return self


def get_preset(name: str) -> Scenario:
    """The named scenario, validated (the families register theirs in schemas/*_presets.py)."""
    if name not in PRESETS:
        raise KeyError(f"unknown preset {name!r}; known: {', '.join(sorted(PRESETS))}")
    return Scenario.model_validate(PRESETS[name].build())
