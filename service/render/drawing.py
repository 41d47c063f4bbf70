"""What a run folder says about drawing its model, read without the schemas or the engine.

The worker writes it into trajectory.h5's drawing group (service/h5md.py): the model
card's facts resolved for the run (the neighbourhood test in force, units, default plots,
overlays) and the overlay geometry by name (obstacles from the parameters; a fixed graph,
the leader's path and the virtual leaders' offsets from the engine). A folder written
before that group existed is read from what it has, through the model's card in the
schemas (pydantic, imported only then): its parameters' overlays, and the leader's path
as the observables `leader_x`, `leader_y` (`leader_z`) sampled it (no fixed graph and no
virtual leaders: the engine built those and they were not written down).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import h5py
import numpy as np

from ..h5md import DRAWING


class RunFolder(Protocol):
    """What the drawing reads of a run folder (run_data.RunData, which builds on this)."""

    trajectory_path: Path
    scenario: Any  # the run's Scenario
    observables: dict[str, np.ndarray]
    dimension: int
    frame_index: tuple[np.ndarray, np.ndarray]  # (steps, times) of the frames


@dataclass
class Drawing:
    """The facts and overlay geometry of one run (see service/h5md.py for the names)."""

    inclusive: bool  # the neighbourhood test in force: |r_ij| <= r when True
    units: dict[str, str | None]  # "time", "length": None in the model's own units
    default_plots: list[str]
    overlays: list[str]  # of "edges", "obstacles", "leaders", "marked"
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    labels: dict[str, str] = field(default_factory=dict)  # text beside them ("marked_label")
    graph_edges_left_out: int = 0  # a fixed graph too large to keep in the folder

    def has(self, overlay: str, *names: str) -> bool:
        """Whether the model draws `overlay` and the folder holds the arrays it needs."""
        return overlay in self.overlays and all(n in self.arrays for n in names)


def load_drawing(run: RunFolder) -> Drawing:
    """The run's drawing group, else the same facts rebuilt from an older folder."""
    if run.trajectory_path.is_file():
        with h5py.File(run.trajectory_path, "r") as f:
            group = f.get(DRAWING)
            if group is not None and "facts" in group.attrs:
                return _read(group)
    return _rebuilt(run)


def _read(group: h5py.Group) -> Drawing:
    facts: dict[str, Any] = json.loads(group.attrs["facts"])
    labels = {k: str(v) for k, v in group.attrs.items() if k != "facts"}
    arrays = {name: ds[()] for name, ds in group.items()}
    return Drawing(bool(facts["inclusive"]), facts["units"], facts["default_plots"],
                   facts["overlays"], arrays, labels, int(facts.get("graph_edges_left_out", 0)))


def _rebuilt(run: RunFolder) -> Drawing:
    """An older folder's facts from its model's card (the schemas), and its overlays from
    what it recorded."""
    model = run.scenario.model
    card = type(model)
    arrays: dict[str, np.ndarray] = {}
    labels: dict[str, str] = {}
    for name, value in model.scene().items():
        if isinstance(value, str):
            labels[name] = value
        else:
            arrays[name] = np.asarray(value)
    if "leaders" in card.overlays:
        arrays.update(_leader_from_observables(run))
    return Drawing(run.scenario.inclusive, {"time": card.units[0], "length": card.units[1]},
                   list(card.default_plots), list(card.overlays), arrays, labels)


def _leader_from_observables(run: RunFolder) -> dict[str, np.ndarray]:
    """The leader's path as observed (`leader_x` ...), and its place at each frame (read
    off the observations between which the frame falls)."""
    obs = run.observables
    columns = [f"leader_{c}" for c in "xyz"[:run.dimension]]
    if not all(c in obs and len(obs[c]) for c in columns):
        return {}
    path = np.column_stack([obs[c] for c in columns])
    times = run.frame_index[1]
    leader = np.column_stack([np.interp(times, obs["time"], obs[c]) for c in columns])
    return {"leader_path": path, "leader": leader}
