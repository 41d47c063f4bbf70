"""The Sweep: many runs of one base scenario over a grid of parameter values, one table.

A sweep file names a base scenario (inline, or a preset with overrides), `axes` whose
product is the grid (a `zip` axis varies several paths together, e.g. N and L at fixed
density), `replicas` per grid point, and what to reduce from each run (`measure`) and to
average over replicas per grid point (`series`).

Runs are numbered point-major: grid point p (axes in file order, the last axis varying
fastest) holds runs first_p .. first_p + R_p - 1, one per replica k = 0 .. R_p - 1.

Seed rule: replica k of a grid point runs with seed = (the point's scenario seed) + k,
the point's seed being the base scenario's `seed`. Every grid point thus reuses the same
seeds (common random numbers: the same initial positions at each η, so differences
between points are not blurred by sampling), and run k of a sweep is exactly
`flocklab run BASE --set PATH=VALUE ... --set seed=<seed + k>`. An explicit `seeds` list
replaces the rule: replica k runs with seeds[k].

Every expanded run is validated as a Scenario before anything runs (`Sweep.expand`), and
`sweep_problems` lists every problem of a sweep document at once.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import (
    Discriminator,
    Field,
    SerializerFunctionWrapHandler,
    StrictStr,
    Tag,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)

from .base import NonNegativeInt, PositiveInt, PositiveReal, Strict
from .paths import PathError, check_path, merge, set_path, split_path
from .presets import PRESETS
from .problems import FieldError, field_errors
from .scenario import Scenario
from .sweep_design import Analysis, Design, design_problems

# The most runs one sweep may expand to (the CLI's only limit; a service sets its own).
MAX_RUNS = 100_000
# At most this many invalid grid points are reported (the rest are counted).
MAX_REPORTED = 20
# The pseudo-path that sets the replica count per grid point (in a plain or zip axis).
REPLICAS_PATH = "replicas"
# The most axes of a sweep, and of paths in one zip axis: 2^17 > MAX_RUNS, so at most 16
# axes can have two values or more; the bound keeps a hostile body's checks small.
MAX_AXES = 64
# The longest axis path: a scenario's deepest field (an explicit position's component) is
# far shorter; the bound keeps the overlap check linear in the body.
MAX_PATH_CHARS = 200
# Column names of runs.csv / table.csv / series.csv that a measure may not take.
RESERVED_COLUMNS = frozenset({"run", "point", "replica", "seed", "status", "step", "time"})
_MEASURE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")

Reduce = Literal["mean", "std", "final", "min", "max", "converge_time",
                 "moments", "binder", "susceptibility", "tau_int"]
# The columns a measure named m adds to runs.csv (its suffixes after m; one column, m
# itself, for the other reduces) and the quantities of table.csv (each q gives q_mean,
# q_sd, q_sem, q_count, and q_err where the runs carry an error). See docs/SWEEPS.md,
# "Transition statistics".
RUN_SUFFIXES: dict[str, tuple[str, ...]] = {
    "moments": ("_m1", "_m1_err", "_m2", "_m2_err", "_m4", "_m4_err", "_tau"),
    "binder": ("", "_err", "_m2", "_m4"),
    "susceptibility": ("", "_err", "_m1", "_m2"),
    "tau_int": ("", "_err", "_window"),
}
TABLE_QUANTITIES: dict[str, tuple[tuple[str, bool], ...]] = {  # (suffix, has an error)
    "moments": (("_m1", True), ("_m2", True), ("_m4", True), ("_tau", False)),
    "binder": (("", True),),
    "susceptibility": (("", True),),
    "tau_int": (("", True),),
}


class SweepError(ValueError):
    """A sweep that cannot run; `errors` holds every problem (field path and reason)."""

    def __init__(self, errors: list[FieldError]):
        self.errors = errors
        super().__init__("; ".join(f"{e.loc}: {e.msg}" for e in errors))


class AxisValues(Strict):
    """One swept field: a dotted path into the scenario and the values it takes."""

    path: StrictStr = Field(max_length=MAX_PATH_CHARS, description="Dotted field path "
                            "into the scenario, e.g. "
                            "'model.eta', 'initial.N', 'space.L'; or 'replicas' (replicas "
                            "per grid point).", examples=["model.eta"])
    values: list[Any] = Field(description="The values, in order (any JSON values).")

    @field_validator("path")
    @classmethod
    def _path(cls, v: str) -> str:
        split_path(v)
        if v == "seed":
            raise ValueError("'seed' cannot be an axis: use replicas (seed + k) or seeds")
        return v

    @field_validator("values")
    @classmethod
    def _not_empty(cls, v: list[Any]) -> list[Any]:
        if not v:
            raise ValueError("an axis needs at least one value")
        return v


class ZipAxis(Strict):
    """Several paths varied together: the i-th values of every list form one grid value."""

    zip: list[AxisValues] = Field(min_length=1, max_length=MAX_AXES, description="Paths "
                                  "varied together; their value lists must have equal "
                                  "lengths.")

    @model_validator(mode="after")
    def _equal_lengths(self) -> ZipAxis:
        lengths = {a.path: len(a.values) for a in self.zip}
        if len(set(lengths.values())) > 1:
            have = ", ".join(f"{p} has {n}" for p, n in lengths.items())
            raise ValueError(f"zip lists must have equal lengths: {have}")
        return self

    @property
    def length(self) -> int:
        return len(self.zip[0].values)


# Union tags; pydantic puts them in error paths, which `field_errors` drops.
_AXIS_TAGS = ("path-axis", "zip-axis")


def _axis_kind(v: Any) -> str:
    zipped = (isinstance(v, dict) and "zip" in v) or isinstance(v, ZipAxis)
    return _AXIS_TAGS[1] if zipped else _AXIS_TAGS[0]


Axis = Annotated[
    Annotated[AxisValues, Tag(_AXIS_TAGS[0])] | Annotated[ZipAxis, Tag(_AXIS_TAGS[1])],
    Discriminator(_axis_kind),
]


class Measure(Strict):
    """One number per run, reduced from an observable's time series over a step window
    [from_step, to_step] (both included; observation steps are those of
    `recording.observables_every` and the last step)."""

    observable: StrictStr = Field(description="An observable of the model, e.g. "
                                  "'polarization' (see the README's observable tables).")
    reduce: Reduce = Field(description="mean / std (population std over the window) / "
                           "final (last value in the window) / min / max / converge_time "
                           "(first time after which the value stays below `tolerance` to the "
                           "window's end; empty when it never does) / moments (<x>, <x^2>, "
                           "<x^4> with tau_int-corrected errors) / binder (G = 1 - <x^4> / "
                           "(3 <x^2>^2)) / susceptibility (chi = N (<x^2> - <x>^2)) / "
                           "tau_int (Sokal's integrated autocorrelation time, in "
                           "observation intervals). See docs/SWEEPS.md.")
    from_step: NonNegativeInt | None = Field(default=None, description="First step "
                                             "included (default: 0).")
    to_step: NonNegativeInt | None = Field(default=None, description="Last step included "
                                           "(default: the run's last).")
    tolerance: PositiveReal | None = Field(default=None, description="converge_time only: "
                                           "default the scenario's convergence.tolerance.")

    @model_validator(mode="after")
    def _window(self) -> Measure:
        if (self.from_step is not None and self.to_step is not None
                and self.to_step < self.from_step):
            raise ValueError(f"to_step = {self.to_step} < from_step = {self.from_step}")
        if self.tolerance is not None and self.reduce != "converge_time":
            raise ValueError("tolerance applies to reduce 'converge_time' only")
        return self

    def run_columns(self, name: str) -> list[str]:
        """This measure's columns of runs.csv (and keys of a run's journal record)."""
        return [name + s for s in RUN_SUFFIXES.get(self.reduce, ("",))]

    def table_quantities(self, name: str) -> list[tuple[str, bool]]:
        """(quantity, has an error) per quantity of table.csv: q_mean, q_sd, q_sem,
        [q_err,] q_count."""
        return [(name + s, e) for s, e in TABLE_QUANTITIES.get(self.reduce, (("", False),))]


@dataclass(frozen=True)
class SweepRun:
    """One run of a sweep: its place in the grid and the scenario it runs."""

    index: int
    point: int
    replica: int
    seed: int
    values: dict[str, Any]  # axis path -> value at this grid point
    scenario: Scenario


class Sweep(Strict):
    """A parameter sweep: the grid of a base scenario's variations, replicas and reductions."""

    name: StrictStr = Field(min_length=1, max_length=200, description="Label of the sweep.")
    description: StrictStr | None = Field(default=None, max_length=2000)
    base: Scenario | None = Field(default=None, description="The scenario every run starts "
                                  "from (or give `preset` and `overrides`).")
    preset: StrictStr | None = Field(default=None, description="A named scenario as the base "
                                     "(see `flocklab presets`).")
    overrides: dict[str, Any] | None = Field(default=None, description="Merged into the "
                                             "preset (objects recursively).")
    axes: list[Axis] = Field(default=[], max_length=MAX_AXES, description="The grid: the "
                             "product over entries; a `zip` entry varies its paths "
                             "together.")
    replicas: PositiveInt = Field(default=1, le=MAX_RUNS, description="Runs per grid point "
                                  "(seed + k, k = 0 .. replicas - 1), unless an axis sets "
                                  "'replicas' per point.")
    seeds: list[Annotated[NonNegativeInt, Field(lt=2**63)]] | None = Field(
        default=None, min_length=1, description="Explicit seeds: replica k runs with "
        "seeds[k] (replaces the seed + k rule; needs at least as many seeds as replicas).")
    measure: dict[str, Measure] = Field(default={}, description="Name -> a reduction of an "
                                        "observable; a column of runs.csv and table.csv.")
    series: list[StrictStr] = Field(default=[], description="Observables averaged over "
                                    "replicas per grid point and step (series.csv).")
    design: Design | None = Field(default=None, description="A sampling design (lhs, "
                                  "sobol, halton, morris) over `bounds`: its points are grid "
                                  "points (times the axes' grid, when both are given).")
    analysis: Analysis | None = Field(default=None, description="A sensitivity analysis "
                                      "(sobol, morris) of one measure over the design: "
                                      "sensitivity.csv.")
    labels: dict[StrictStr, Annotated[StrictStr, Field(min_length=1, max_length=40)]] = Field(
        default={}, description="Symbols for pictures (`flocklab render`): an axis path or "
        "a table quantity (a measure's name; for moments <m>_m1, <m>_m2, <m>_m4, <m>_tau) "
        "-> its label, e.g. {\"model.eta\": \"η\", \"space.L\": \"L\"}.")
    keep: Literal["table", "summaries", "all"] = Field(
        default="summaries", description="table: only the tables (the runs then compute only "
        "the observables the measures and series read, unless the base names its own "
        "recording.observables); summaries: also runs/<index>/summary.json; all: also each "
        "run's observables.csv and trajectory.h5.")

    @field_validator("preset")
    @classmethod
    def _known_preset(cls, v: str | None) -> str | None:
        if v is not None and v not in PRESETS:
            raise ValueError(f"unknown preset {v!r}; known: {', '.join(sorted(PRESETS))}")
        return v

    @field_validator("measure")
    @classmethod
    def _measure_names(cls, v: dict[str, Measure]) -> dict[str, Measure]:
        for name in v:
            if not _MEASURE_NAME.fullmatch(name) or name in RESERVED_COLUMNS:
                raise ValueError(f"measure name {name!r} must be an identifier other than "
                                 f"{', '.join(sorted(RESERVED_COLUMNS))}")
        owners: dict[tuple[str, str], str] = {}  # (file, column) -> the measure writing it
        for name, m in v.items():
            table = [q + s for q, e in m.table_quantities(name)
                     for s in ("_mean", "_sd", "_sem", "_count", *(("_err",) if e else ()))]
            for key in [*(("runs.csv", c) for c in m.run_columns(name)),
                        *(("table.csv", c) for c in table)]:
                if key in owners:
                    raise ValueError(f"measures {owners[key]!r} and {name!r} both write the "
                                     f"column {key[1]!r} of {key[0]}: rename one")
                owners[key] = name
        return v

    @field_validator("series")
    @classmethod
    def _unique_series(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v):
            raise ValueError("series lists an observable twice")
        return v

    @field_validator("design")
    @classmethod
    def _design_size(cls, v: Design | None) -> Design | None:
        if v is not None and v.n_points() > MAX_RUNS:  # before any point is drawn
            raise ValueError(f"{v.n_points()} points, more than the limit of {MAX_RUNS} runs")
        return v

    @field_validator("analysis")
    @classmethod
    def _analysis(cls, v: Analysis | None, info: ValidationInfo) -> Analysis | None:
        if v is None:
            return v
        measures = info.data.get("measure", {})
        quantities = {q for n, m in measures.items() for q, _ in m.table_quantities(n)}
        problems = design_problems(info.data.get("design"), v, bool(info.data.get("axes")),
                                   quantities, MAX_RUNS)
        if problems:
            raise ValueError("; ".join(problems))
        return v

    @model_validator(mode="after")
    def _label_keys(self) -> Sweep:
        if not self.labels:
            return self
        known = {a.path for a in self.axis_entries()} | {
            q for n, m in self.measure.items() for q, _ in m.table_quantities(n)}
        unknown = sorted(set(self.labels) - known)
        if unknown:
            raise ValueError(f"labels: {', '.join(map(repr, unknown))} is neither an axis "
                             f"path nor a measure's quantity (known: "
                             f"{', '.join(sorted(known)) or 'none'})")
        return self

    @model_validator(mode="after")
    def _structure(self) -> Sweep:
        if (self.base is None) == (self.preset is None):
            raise ValueError("give exactly one of 'base' (a scenario) and 'preset'")
        if self.overrides is not None and self.preset is None:
            raise ValueError("'overrides' apply to a preset only")
        overlap = _first_overlap([a.path for a in self.axis_entries()])
        if overlap:
            raise ValueError(f"axes: the paths {overlap[0]!r} and {overlap[1]!r} overlap "
                             "(each field may be swept by one axis only)")
        clash = self._column_clash()
        if clash:
            raise ValueError(clash)
        if self._replicas_axis() and "replicas" in self.model_fields_set:
            raise ValueError("give 'replicas' either as a field or as an axis, not both")
        for a in self.axis_entries():
            if a.path == REPLICAS_PATH:
                bad = [v for v in a.values if not (type(v) is int and 1 <= v <= MAX_RUNS)]
                if bad:
                    raise ValueError(f"axes: 'replicas' values must be positive integers, "
                                     f"not {json.dumps(bad[0])}")
        if self.n_points > MAX_RUNS:
            raise ValueError(f"the sweep has {self.n_points} grid points, more than the "
                             f"limit of {MAX_RUNS} runs")
        counts = self._replica_counts()
        if self.seeds is not None and len(self.seeds) < max(counts):
            raise ValueError(f"seeds has {len(self.seeds)} entries, fewer than the "
                             f"{max(counts)} replicas of a grid point")
        n = self.n_runs
        if n > MAX_RUNS:
            raise ValueError(f"the sweep expands to {n} runs, more than the limit of "
                             f"{MAX_RUNS}")
        return self

    def _column_clash(self) -> str | None:
        """Why two columns of one table would share a name (None: they do not). The
        tables' columns (service/sweeps/tables.py): runs.csv run, point, <axis paths>,
        replica, seed, status, <measures>; table.csv point, <axis paths>, <m>_mean, _sd,
        _sem, _count; series.csv point, <axis paths>, step, time, <obs>_mean, _sd. A
        top-level axis path ('name', 'time') can meet a measure or a fixed column, and a
        reader of the CSV would then take one column for the other."""
        axes = [a.path for a in self.axis_entries() if a.path != REPLICAS_PATH]
        names = list(self.measure)
        tables = {
            "runs.csv": ["run", "point", *axes, "replica", "seed", "status", *names],
            "table.csv": ["point", *axes, *(f"{n}_{s}" for n in names
                                            for s in ("mean", "sd", "sem", "count"))],
            "series.csv": ["point", *axes, "step", "time",
                           *(f"{o}_{s}" for o in self.series for s in ("mean", "sd"))]
            if self.series else [],
        }
        for file, columns in tables.items():
            seen: set[str] = set()
            for c in columns:
                if c in seen:
                    return (f"{file} would have two columns named {c!r} (an axis path, a "
                            "measure or a series named like another column): rename the "
                            "measure, or sweep a deeper path (e.g. 'time.steps')")
                seen.add(c)
        return None

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler):  # type: ignore[no-untyped-def]
        # (no return type, so pydantic keeps the fields' own serialization schema)
        """The dump leaves out the `replicas` field when an axis sets the replicas: with
        its default filled in, the stored sweep (the service's canonical form, its /spec)
        would no longer validate ("give 'replicas' either as a field or as an axis")."""
        data = handler(self)
        if isinstance(data, dict) and self._replicas_axis():
            data.pop("replicas", None)
        return data

    # -- the grid -----------------------------------------------------------------------

    def axis_entries(self) -> list[AxisValues]:
        """Every (path, values) of every axis, zip members flattened (the design's paths
        last, with the design's values)."""
        return [m for a in self._all_axes for m in (a.zip if isinstance(a, ZipAxis) else [a])]

    @functools.cached_property
    def _all_axes(self) -> list[AxisValues | ZipAxis]:
        """The axes, then the design as one more zip axis (its points vary fastest)."""
        if self.design is None:
            return list(self.axes)
        points = self.design.points(self.analysis.kind if self.analysis else None)
        return [*self.axes, ZipAxis(zip=[AxisValues(path=p, values=[x[p] for x in points])
                                         for p in self.design.bounds])]

    def _grid(self) -> Iterator[dict[str, Any]]:
        """path -> value for each grid point (the 'replicas' pseudo-path included), one
        point at a time."""
        choices = []
        for a in self._all_axes:
            members = a.zip if isinstance(a, ZipAxis) else [a]
            length = len(members[0].values)
            choices.append([{m.path: m.values[i] for m in members} for i in range(length)])
        for combo in itertools.product(*choices):
            yield dict(kv for part in combo for kv in part.items())

    @property
    def n_points(self) -> int:
        """Grid points: the product of the axes' lengths."""
        lengths = [(a.length if isinstance(a, ZipAxis) else len(a.values)) for a in self.axes]
        if self.design is not None:  # counted without drawing the points
            lengths.append(self.design.n_points(self.analysis.kind if self.analysis else None))
        return math.prod(lengths)

    def _replicas_axis(self) -> bool:
        return any(a.path == REPLICAS_PATH for a in self.axis_entries())

    def _replica_counts(self) -> list[int]:
        """Replicas per grid point (one entry for all when no axis sets them)."""
        if not self._replicas_axis():
            return [self.replicas]
        return [p[REPLICAS_PATH] for p in self._grid()]

    @property
    def n_runs(self) -> int:
        """Runs in all (grid points times their replicas)."""
        if not self._replicas_axis():
            return self.replicas * self.n_points
        return sum(self._replica_counts())

    @property
    def total_agent_steps(self) -> int:
        """Sum over runs of N x steps (one pass over the runs, none kept; raises SweepError
        if invalid)."""
        return sum(r.scenario.n_agents * r.scenario.time.steps for r in self.iter_runs())

    def grid_values(self) -> Iterator[dict[str, Any]]:
        """Each grid point's axis values (path -> value, as in its runs' `SweepRun.values`),
        in point order, one point at a time."""
        for values in self._grid():
            values.pop(REPLICAS_PATH, None)
            yield values

    @property
    def base_scenario(self) -> Scenario:
        """The base: inline, or the preset with the overrides merged (SweepError if invalid)."""
        if self.base is not None:
            return self.base
        assert self.preset is not None
        merged = merge(PRESETS[self.preset].build(), self.overrides or {})
        try:
            return Scenario.model_validate(merged)
        except ValidationError as exc:
            raise SweepError(field_errors(exc, ("overrides",))) from None

    def expand(self) -> list[SweepRun]:
        """Every run, each validated as a Scenario; raises SweepError listing every problem
        (unknown paths, invalid values naming the run and the field, measure windows)."""
        return self._expanded

    @functools.cached_property
    def _expanded(self) -> list[SweepRun]:
        return list(self.iter_runs())

    def iter_runs(self, wanted: Callable[[int], bool] | None = None) -> Iterator[SweepRun]:
        """The runs of `expand`, one grid point at a time and none kept: what holds the
        runs is the caller's (the service checks a 10^5-run sweep in bounded memory).
        Validated as they come; the SweepError of `expand` comes after the last run.
        `wanted(index)`: only those runs (a checked sweep's unfinished runs, say); a grid
        point with none of them is not even validated, so its problems go unreported."""
        base = self.base_scenario
        doc = base.model_dump(mode="json")
        errors = unknown_paths(doc, self.model_dump(mode="json")["axes"])
        for path in self.design.bounds if self.design else ():
            try:
                check_path(doc, path)
            except PathError as exc:
                errors.append(FieldError(loc=f"design.bounds.{path}", msg=str(exc),
                                         type="unknown_path"))
        if errors:
            raise SweepError(errors)
        bad_points = first = 0  # first: the index of the grid point's first run
        for p, values in enumerate(self._grid()):
            n_rep = values.pop(REPLICAS_PATH, self.replicas)
            if wanted is not None and not any(wanted(first + k) for k in range(n_rep)):
                first += n_rep
                continue
            scenario, problems = self._point_scenario(doc, values, first, n_rep)
            if scenario is None:
                bad_points += 1
                if bad_points <= MAX_REPORTED:
                    # A measure window too long for several points is reported once.
                    errors += [e for e in problems if e.loc.startswith("runs[")
                               or all(e.loc != old.loc for old in errors)]
            else:
                for k in range(n_rep):
                    seed = self.seeds[k] if self.seeds is not None else scenario.seed + k
                    if seed >= 2**63:
                        errors.append(FieldError(loc=f"runs[{first + k}].seed", msg=f"seed "
                                                 f"{seed} (base seed + {k}) >= 2^63",
                                                 type="seed_range"))
                        break
                    if wanted is not None and not wanted(first + k):
                        continue
                    yield SweepRun(first + k, p, k, seed, values,
                                   self._only_kept(scenario).model_copy(update={"seed": seed}))
            first += n_rep
        if bad_points > MAX_REPORTED:
            errors.append(FieldError(loc="runs", type="value_error",
                                     msg=f"{bad_points - MAX_REPORTED} more invalid grid "
                                     "points not listed"))
        if errors:
            raise SweepError(errors)

    def _only_kept(self, scenario: Scenario) -> Scenario:
        """The run computes only what the sweep keeps: with keep 'table' (runs leave
        nothing but their measures and series) and no `recording.observables` of its own,
        the observables its measures and series read, when the model reports them all (a
        name it does not report is left for the runner to refuse by name)."""
        rec = scenario.recording
        names = list(dict.fromkeys([*(m.observable for m in self.measure.values()),
                                    *self.series]))
        if self.keep != "table" or rec.observables is not None or not names or not all(
                type(scenario.model).reports(n) for n in names):
            return scenario
        return scenario.model_copy(update={"recording": rec.model_copy(
            update={"observables": names})})

    def _point_scenario(self, doc: dict[str, Any], values: dict[str, Any], first: int,
                        n_rep: int) -> tuple[Scenario | None, list[FieldError]]:
        """The scenario of one grid point, or None and its problems."""
        for path, value in values.items():
            doc = set_path(doc, path, value)
        where = ", ".join(f"{k}={json.dumps(v)}" for k, v in values.items()) or "the base"
        runs = f"runs[{first}]" if n_rep == 1 else f"runs[{first}..{first + n_rep - 1}]"
        try:
            scenario = Scenario.model_validate(doc)
        except ValidationError as exc:
            return None, [FieldError(loc=f"runs[{first}]" + ("" if e.loc == "(root)"
                                                            else f".{e.loc}"),
                                     type=e.type, msg=f"{e.msg} ({runs} at {where})")
                          for e in field_errors(exc)]
        problems = [
            FieldError(loc=f"measure.{name}.{field}", type="window_out_of_range",
                       msg=f"step {step} is beyond time.steps = {scenario.time.steps} of "
                       f"{runs} at {where}")
            for name, m in self.measure.items()
            for field, step in (("from_step", m.from_step), ("to_step", m.to_step))
            if step is not None and step > scenario.time.steps
        ]
        return (None if problems else scenario), problems


def _first_overlap(paths: list[str]) -> tuple[str, str] | None:
    """The first pair (earlier, later) of paths naming the same field or one inside the
    other ('model' and 'model.eta'), or None. Hashes each path's prefixes, so the cost is
    linear in the paths' total length times their depth (bounded by MAX_PATH_CHARS),
    where comparing every pair took 92 s for a 1.1 MB body."""
    seen: set[str] = set()
    under: dict[str, str] = {}  # a proper prefix -> the first path below it
    for p in paths:
        cuts = [i for i, c in enumerate(p) if c == "."]
        for q in (p, *(p[:i] for i in cuts)):
            if q in seen:
                return q, p
        if p in under:
            return under[p], p
        seen.add(p)
        for i in cuts:
            under.setdefault(p[:i], p)
    return None


def unknown_paths(doc: dict[str, Any], axes: Any) -> list[FieldError]:
    """An error for each axis path (in raw JSON `axes`) that names no field of `doc`, the
    base scenario with its defaults filled in."""
    errors = []
    unlisted = 0
    for i, axis in enumerate(axes if isinstance(axes, list) else []):
        zipped = isinstance(axis, dict) and isinstance(axis.get("zip"), list)
        members = [(f"axes.{i}.zip.{j}", m) for j, m in enumerate(axis["zip"])] if zipped \
            else [(f"axes.{i}", axis)]
        for loc, m in members:
            path = m.get("path") if isinstance(m, dict) else None
            if not isinstance(path, str) or path in (REPLICAS_PATH, "seed"):
                continue
            try:
                check_path(doc, path)
            except PathError as exc:
                if len(errors) < MAX_REPORTED:
                    errors.append(FieldError(loc=f"{loc}.path", msg=str(exc),
                                             type="unknown_path"))
                else:
                    unlisted += 1
    if unlisted:
        errors.append(FieldError(loc="axes", type="unknown_path",
                                 msg=f"{unlisted} more unknown paths not listed"))
    return errors


def _raw_base(data: dict[str, Any]) -> dict[str, Any] | None:
    """The base scenario of a raw sweep document, when it is valid (else None)."""
    try:
        if isinstance(data.get("base"), dict):
            return Scenario.model_validate(data["base"]).model_dump(mode="json")
        if data.get("preset") in PRESETS:
            merged = merge(PRESETS[data["preset"]].build(), data.get("overrides") or {})
            return Scenario.model_validate(merged).model_dump(mode="json")
    except (ValidationError, AttributeError, TypeError):
        pass
    return None


def sweep_problems(data: Any) -> list[FieldError]:
    """Every problem of a sweep document (empty: it is valid and every run validates)."""
    try:
        load_sweep(data)
    except SweepError as exc:
        return exc.errors
    return []


def load_sweep(data: Any) -> Sweep:
    """A Sweep from a JSON-ready dict, fully checked (its `expand()` cannot fail);
    raises SweepError with every problem."""
    try:
        sweep = Sweep.model_validate(data)
    except ValidationError as exc:
        errors = field_errors(exc)  # (it drops the axis union tags from the paths)
        # Unknown paths too, when the base is valid: every problem in one report.
        base = _raw_base(data) if isinstance(data, dict) else None
        if base is not None:
            seen = {e.loc for e in errors}
            errors += [e for e in unknown_paths(base, data.get("axes")) if e.loc not in seen]
        raise SweepError(errors) from None
    for _ in sweep.iter_runs():  # every run checked, none kept (expand() would cache them)
        pass
    return sweep


def is_sweep_document(data: Any) -> bool:
    """Whether a parsed JSON document is a sweep (rather than a scenario)."""
    return isinstance(data, dict) and "model" not in data and bool(
        {"axes", "base", "preset", "replicas", "measure", "series", "design"} & set(data))


def describe_sweep() -> dict[str, Any]:
    """The sweep file's catalog entry, shaped like a model's (for `flocklab models`)."""
    return {
        "kind": "sweep",
        "summary": "A sweep file (flocklab sweep): a base scenario, axes, replicas, measures.",
        "paper": "",
        "equations": "",
        "paper_inclusive": None,
        "state": [],
        "parameters": [
            {"name": name, "default": None if f.is_required() else _jsonable(f.default),
             "required": f.is_required(), "description": f.description or ""}
            for name, f in Sweep.model_fields.items()
        ],
        "json_schema": Sweep.model_json_schema(),
    }


def _jsonable(v: Any) -> Any:
    return v.model_dump(mode="json") if isinstance(v, Strict) else v
