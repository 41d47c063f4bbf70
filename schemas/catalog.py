"""The model registry on the schema side: one parameter class per model family.

A model family registers its parameter class here (one line in `schemas/models.py`
imports the module, whose class is decorated with `@register_model`). The engine's kernel
registry must hold exactly the same kinds (a test checks it).

Each class is also the family's *model card*: everything the service, the H5MD writer,
the renderer, the CLI and the browser viewer know of the family is a class variable (or a
method) here, exported by `describe_models()` and served by GET /v1/models. Nothing outside
schemas/ and kernels/ names a model kind.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from .base import Strict

# What a snapshot can draw besides the agents (the card's `overlays`): "edges" the
# interaction graph (by default at small N), "obstacles" the obstacles and destination,
# "leaders" the virtual leader, its path and the agents' virtual leaders, "marked" agents
# ringed with a label (JLM's leader agent).
Overlay = Literal["edges", "obstacles", "leaders", "marked"]


@dataclass(frozen=True)
class ModelContext:
    """What a model's cross-block checks may read of the scenario around it. The scenario
    builds it, so a model module never imports the scenario (no import cycle)."""

    n_agents: int
    dimension: int
    space: Literal["periodic", "plane"]
    radius: float | None  # neighbours.radius; None without a neighbours block
    dt: float
    # neighbours.kind ("metric" or "topological"); None without a neighbours block
    neighbours: str | None = None


class ModelParams(Strict):
    """Base of every model's parameter block. Subclasses set `kind: Literal[...]`."""

    paper: ClassVar[str] = ""
    equations: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    # Whether the paper's neighbourhood test is |r_ij| <= r (True) or < r (False).
    paper_inclusive: ClassVar[bool] = True
    # The neighbours.kind values the model runs with (schemas/common.py `Neighbours`):
    # "metric" |r_ij| < r; "topological" the k nearest (Ballerini et al. 2008).
    neighbour_kinds: ClassVar[tuple[str, ...]] = ("metric",)
    # A line for `flocklab models` on the kinds (what topological means for the model).
    neighbours_note: ClassVar[str] = ""
    # Per-agent state the model has, a subset of ("position", "velocity", "heading").
    state_arrays: ClassVar[tuple[str, ...]] = ("position",)
    # Per-agent arrays derived from the state that the model can record, a subset of
    # DERIVED_ARRAYS ("degree": |N_i| in its interaction graph, "radius": its own R_i).
    derived_arrays: ClassVar[tuple[str, ...]] = ()
    # The observables the model reports, when it declares them (then a scenario may
    # choose among them with recording.observables); None: not declared. A name ending in
    # "_<i>" stands for one per agent: valency_<i> covers valency_0, valency_1, ...
    observables: ClassVar[tuple[str, ...] | None] = None
    # The values of space.dimension the model runs in; `dimensions_note` says which
    # variants are narrower (checked by `check_context`).
    dimensions: ClassVar[tuple[int, ...]] = (2,)
    dimensions_note: ClassVar[str] = ""
    # Units of (time, length) as the paper states them, SI symbols as H5MD's units module
    # writes them; None: the model's own dimensionless unit.
    units: ClassVar[tuple[str | None, str | None]] = (None, None)
    # The observables a picture or the viewer plots by default, in order: a run plots
    # those it recorded (a variant may record fewer).
    default_plots: ClassVar[tuple[str, ...]] = ()
    # The document that holds the family's details (the choices the papers leave open,
    # presets, observables), a path from the repository root.
    details: ClassVar[str] = ""
    # What a snapshot draws besides the agents (see `Overlay`).
    overlays: ClassVar[tuple[Overlay, ...]] = ()
    # A constant-speed model names the parameter that is every agent's speed (the H5MD
    # writer then tracks periodic images exactly); None: speeds vary.
    constant_speed: ClassVar[str | None] = None

    @classmethod
    def observables_listing(cls) -> str:
        """The declared observables for a message, a run of numbered names shortened:
        valency_hist_0 .. valency_hist_15 (flocking declares 17 histogram bins)."""
        out: list[str] = []
        run: list[str] = []  # consecutive prefix_0, prefix_1, ... being collected

        def close() -> None:
            out.extend(run if len(run) < 3 else [f"{run[0]} .. {run[-1]}"])
            run.clear()

        for name in cls.observables or ():
            head, _, index = name.rpartition("_")
            if run and index == str(len(run)) and run[0].rpartition("_")[0] == head:
                run.append(name)
                continue
            close()
            if index == "0":
                run.append(name)
            else:
                out.append(name)
        close()
        return ", ".join(out)

    @classmethod
    def reports(cls, name: str) -> bool:
        """Whether `name` is among the declared observables (a per-agent "_<i>" name
        matching its prefix and an agent index)."""
        known = cls.observables or ()
        if name in known:
            return True
        head, _, index = name.rpartition("_")
        agent = index.isascii() and index.isdigit() and str(int(index)) == index
        return agent and f"{head}_<i>" in known

    def check_context(self, ctx: ModelContext) -> None:
        """Cross-block checks (raise ValueError with a user-facing message)."""

    def scene(self) -> dict[str, Any]:
        """The overlay geometry these parameters alone give, by name: numbers (lists) or
        text. For "obstacles": obstacle_points [p, ...], disc_centres [c, ...], disc_radii
        [rho, ...], destination p; for "marked": marked [agent, ...] and marked_label.
        What only the engine builds (a fixed graph, a leader's path) is not here: the
        worker writes it into the run folder beside these (service/execute.py)."""
        return {}

    def non_increasing(self) -> dict[str, str]:
        """Observables the paper proves never increase along this model's trajectories
        (name -> where it says so). The engine reports whether a run kept each one: a
        rise means the time step does not resolve the dynamics."""
        return {}


MODELS: dict[str, type[ModelParams]] = {}


def register_model(cls: type[ModelParams]) -> type[ModelParams]:
    kind = cls.model_fields["kind"].default
    if kind in MODELS:
        raise RuntimeError(f"model kind {kind!r} registered twice")
    MODELS[kind] = cls
    return cls


def describe_models() -> list[dict[str, Any]]:
    """The catalog: every model with its parameters, defaults and equations, and its card
    (units, default plots, details document, overlays, constant speed)."""
    out = []
    for kind, cls in MODELS.items():
        params = []
        for name, f in cls.model_fields.items():
            if name == "kind":
                continue
            params.append(
                {
                    "name": name,
                    "default": None if f.is_required() else _jsonable(f.default),
                    "required": f.is_required(),
                    "description": f.description or "",
                }
            )
        out.append(
            {
                "kind": kind,
                "summary": cls.summary,
                "paper": cls.paper,
                "equations": cls.equations,
                "paper_inclusive": cls.paper_inclusive,
                "neighbour_kinds": list(cls.neighbour_kinds),
                "neighbours_note": cls.neighbours_note,
                "state": list(cls.state_arrays),
                "derived_arrays": list(cls.derived_arrays),
                "observables": None if cls.observables is None else list(cls.observables),
                "dimensions": list(cls.dimensions),
                "dimensions_note": cls.dimensions_note,
                "units": {"time": cls.units[0], "length": cls.units[1]},
                "default_plots": list(cls.default_plots),
                "details": cls.details,
                "overlays": list(cls.overlays),
                "constant_speed": cls.constant_speed,
                "parameters": params,
                "json_schema": cls.model_json_schema(),
            }
        )
    return out


def _jsonable(v: Any) -> Any:
    if isinstance(v, Strict):
        return v.model_dump(mode="json")
    if isinstance(v, tuple):
        return list(v)
    return v
