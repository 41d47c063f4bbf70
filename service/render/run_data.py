"""A run folder (or a sweep folder) read back for drawing: no plotting library here.

`scenario.json` is read as plain JSON for the facts every picture needs (model kind,
N, box, neighbour radius): validating it with the pydantic schemas costs more start-up
than drawing a 10^3-agent frame. What the model's card says about drawing it (the
neighbourhood test in force, default plots, overlays and their geometry) the worker
wrote into the run folder (`RunData.drawing`, service/render/drawing.py); only a folder
written before that builds `RunData.scenario`, the validated model, to read its card.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from .drawing import Drawing, load_drawing
from .errors import RenderInputError

if TYPE_CHECKING:
    from flocklab.schemas import Scenario


@dataclass
class Frame:
    """One recorded frame in agent-id order."""

    index: int
    step: int
    time: float
    position: np.ndarray  # (N, dim)
    # 2D: (N,) radians; 3D: (N, 3) unit vectors. The recorded heading, else the
    # velocity's direction (the x axis where the velocity is zero, as atan2(0, 0) = 0).
    heading: np.ndarray
    velocity: np.ndarray | None  # (N, dim) when recorded

    @property
    def azimuth(self) -> np.ndarray:
        """(N,) the heading's angle in the x-y plane: what the colours show."""
        h = self.heading
        return h if h.ndim == 1 else np.arctan2(h[:, 1], h[:, 0])

    @property
    def directions(self) -> np.ndarray:
        """(N, dim) unit headings."""
        h = self.heading
        return np.column_stack([np.cos(h), np.sin(h)]) if h.ndim == 1 else h


class RunData:
    """The artifacts of one run: scenario, summary, observables and recorded frames."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        for name in ("scenario.json", "summary.json"):
            if not (self.folder / name).is_file():
                raise RenderInputError(f"{self.folder} is not a run folder (no {name})")
        try:
            self.doc: dict[str, Any] = json.loads((self.folder / "scenario.json").read_text())
            self.summary: dict[str, Any] = json.loads((self.folder / "summary.json").read_text())
            self.kind: str = self.doc["model"]["kind"]
            initial = self.doc["initial"]
            # an explicit initial state has no N: its positions are the agents
            self.n_agents: int = (int(initial["N"]) if "N" in initial
                                  else len(initial["positions"]))
            space = self.doc["space"]
            self.box: float | None = float(space["L"]) if space["kind"] == "periodic" else None
            self.dimension: int = int(space.get("dimension", 2))
            self.name: str = self.doc.get("name") or self.kind
            nb = self.doc.get("neighbours")
            self.radius: float | None = float(nb["radius"]) if nb else None
        except (ValueError, KeyError, TypeError) as exc:
            raise RenderInputError(f"{self.folder}: unreadable run files: {exc!r}") from exc

    @cached_property
    def drawing(self) -> Drawing:
        """The card's facts for this run and its overlay geometry."""
        return load_drawing(self)

    @property
    def inclusive(self) -> bool:
        """The neighbourhood test in force (`<=` when True): the scenario's, else the
        paper's."""
        return self.drawing.inclusive

    @cached_property
    def scenario(self) -> Scenario:
        """The validated scenario: an older folder's card is read through it."""
        from pydantic import ValidationError

        from flocklab.schemas import Scenario

        try:
            return Scenario.model_validate(self.doc)
        except ValidationError as exc:
            raise RenderInputError(f"{self.folder}: unreadable scenario.json: {exc}") from exc

    # -- observables ----------------------------------------------------------------------

    @cached_property
    def observables(self) -> dict[str, np.ndarray]:
        """Every observable's time series by name (with `step` and `time`)."""
        path = self.folder / "observables.csv"
        if not path.is_file():
            return {}
        with path.open(newline="") as f:
            rows = list(csv.reader(f))
        if not rows:
            return {}
        names, values = rows[0], rows[1:]
        table = np.array([[_number(v) for v in r] for r in values], dtype=np.float64)
        table = table.reshape(len(values), len(names))
        return {name: table[:, i] for i, name in enumerate(names)}

    @property
    def convergence(self) -> dict[str, float]:
        """{quantity: time after which it stays below tolerance}, converged ones only."""
        conv = self.summary.get("convergence") or {}
        return {k: float(v) for k, v in conv.items() if isinstance(v, int | float)}

    # -- frames ---------------------------------------------------------------------------

    @property
    def trajectory_path(self) -> Path:
        return self.folder / "trajectory.h5"

    @cached_property
    def frame_index(self) -> tuple[np.ndarray, np.ndarray]:
        """(steps, times) of the recorded frames."""
        if not self.trajectory_path.is_file():
            return np.zeros(0, np.int64), np.zeros(0)
        with h5py.File(self.trajectory_path, "r") as f:
            g = f.get("particles/swarm/position")
            if g is None:
                return np.zeros(0, np.int64), np.zeros(0)
            return g["step"][:], g["time"][:]

    @property
    def n_frames(self) -> int:
        return len(self.frame_index[0])

    def pick_frame(self, frame: int | None = None, time: float | None = None) -> int:
        """A frame index from `--frame K` (negative counts from the end) or `--time T`
        (the last frame at or before T); default the last frame."""
        n = self.n_frames
        if n == 0:
            raise RenderInputError(f"{self.folder.name}: no frames were recorded in "
                                   "trajectory.h5 (recording.every = 0, no position array, "
                                   "or recording.format gsd alone)", status=404)
        if frame is not None and time is not None:
            raise RenderInputError("give a frame or a time, not both", loc="time")
        if time is not None:
            times = self.frame_index[1]
            if not math.isfinite(time) or time < times[0]:
                raise RenderInputError(f"time {time} is before the first frame "
                                       f"(t = {times[0]:g})", loc="time")
            return int(np.searchsorted(times, time, side="right") - 1)
        if frame is None:
            return n - 1
        k = frame + n if frame < 0 else frame
        if not 0 <= k < n:
            raise RenderInputError(f"frame {frame} out of range: {n} frames recorded "
                                   f"(0..{n - 1}, or negative from the end)", loc="frame")
        return k

    def frame(self, k: int) -> Frame:
        """Frame k (an index from `pick_frame`)."""
        steps, times = self.frame_index
        with h5py.File(self.trajectory_path, "r") as f:
            swarm = f["particles/swarm"]
            pos = swarm["position/value"][k]
            vel = swarm["velocity/value"][k] if "velocity" in swarm else None
            heading = swarm["heading/value"][k] if "heading" in swarm else None
        if heading is None:
            heading = _direction(vel) if vel is not None else _direction(np.zeros_like(pos))
        return Frame(k, int(steps[k]), float(times[k]), pos, heading, vel)

    def positions(self, start: int, stop: int, stride: int = 1,
                  agents: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Positions of frames start:stop:stride, (F, n, dim), for trails."""
        with h5py.File(self.trajectory_path, "r") as f:
            value = f["particles/swarm/position/value"]
            return np.stack([value[k][agents] for k in range(start, stop, stride)])


def _direction(v: np.ndarray) -> np.ndarray:
    """A frame's headings from its velocities: the angle in 2D, the unit vector in 3D
    (the x axis for a zero velocity in both)."""
    if v.shape[1] == 2:
        return np.arctan2(v[:, 1], v[:, 0])
    speed = np.sqrt((v * v).sum(axis=1))
    out = np.zeros_like(v)
    out[:, 0] = 1.0
    moving = speed > 0
    out[moving] = v[moving] / speed[moving, None]
    return out


def _number(s: str) -> float:
    try:
        return float(s)
    except ValueError:
        return math.nan


# -- sweeps -------------------------------------------------------------------------------


@dataclass
class SweepData:
    """A sweep folder: `table.csv` (axis columns, then <measure>_mean/_sd/_sem/_count)
    and `sweep.json` (the spec, whose `axes` name the axis paths in order)."""

    folder: Path
    spec: dict[str, Any]
    axes: list[str]
    columns: dict[str, np.ndarray] = field(repr=False)  # numbers (NaN where not one)
    text: dict[str, list[str]] = field(repr=False)  # the cells as written

    @property
    def name(self) -> str:
        for doc in (self.spec, self.spec.get("sweep")):
            if isinstance(doc, dict) and isinstance(doc.get("name"), str):
                return doc["name"]
        return self.folder.name

    @property
    def measures(self) -> list[str]:
        return [c.removesuffix("_mean") for c in self.columns if c.endswith("_mean")]

    def label(self, name: str) -> str:
        """The symbol of an axis path or a table quantity: the sweep's `labels`, else the
        literature's for a binder (G), susceptibility (chi) or tau_int measure, else the
        name itself."""
        sweep = self.spec.get("sweep")
        sweep = sweep if isinstance(sweep, dict) else {}
        labels = sweep.get("labels")
        if isinstance(labels, dict) and isinstance(labels.get(name), str):
            return labels[name]
        measure = (sweep.get("measure") or {}).get(name) if isinstance(
            sweep.get("measure"), dict) else None
        reduce = measure.get("reduce") if isinstance(measure, dict) else None
        return REDUCE_SYMBOLS.get(reduce, name) if isinstance(reduce, str) else name


# The usual symbols of the transition statistics (docs/SWEEPS.md).
REDUCE_SYMBOLS = {"binder": "G", "susceptibility": "χ", "tau_int": "τ_int"}


def is_sweep_dir(folder: Path) -> bool:
    return (Path(folder) / "table.csv").is_file() and (Path(folder) / "sweep.json").is_file()


def read_csv_columns(path: Path) -> tuple[dict[str, list[str]], dict[str, np.ndarray]]:
    """A CSV of the sweep folder by column: the cells as written, and as numbers (NaN
    where a cell is not one); RenderInputError when unreadable or empty."""
    try:
        with Path(path).open(newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, ValueError) as exc:
        raise RenderInputError(f"{path}: unreadable: {exc}") from exc
    if not rows:
        raise RenderInputError(f"{path}: empty")
    text = {n: [r[i] if i < len(r) else "" for r in rows[1:]] for i, n in enumerate(rows[0])}
    return text, {n: np.array([_number(v) for v in vals]) for n, vals in text.items()}


def load_sweep(folder: Path) -> SweepData:
    folder = Path(folder)
    try:
        spec = json.loads((folder / "sweep.json").read_text())
    except (OSError, ValueError) as exc:
        raise RenderInputError(f"{folder}: unreadable sweep files: {exc}") from exc
    text, columns = read_csv_columns(folder / "table.csv")
    axes = [_axis_name(a) for a in spec.get("axes", [])] if isinstance(spec, dict) else []
    if not next(iter(text.values()), []) or not axes:
        raise RenderInputError(f"{folder}: the sweep has no rows or no axes")
    missing = [a for a in axes if a not in text]
    if missing:
        raise RenderInputError(f"{folder}/table.csv has no column for the axes {missing}")
    return SweepData(folder, spec, axes, columns, text)


def _axis_name(axis: Any) -> str:
    """An axis is its path, or an object holding it under `path` (or `name`)."""
    if isinstance(axis, str):
        return axis
    if isinstance(axis, dict):
        for key in ("path", "name", "field"):
            if isinstance(axis.get(key), str):
                return axis[key]
    raise RenderInputError(f"sweep.json: cannot read the axis {axis!r}")
