"""H5MD trajectory writer (HDF5 via h5py), appended frame by frame.

Layout (H5MD 1.1, https://www.nongnu.org/h5md/h5md.html):
  /h5md                      version, author, creator
  /particles/swarm/box       dimension = D (2 or 3: space.dimension),
                             boundary = periodic|none (xD), edges = [L] * D
  /particles/swarm/<array>   step (F,), time (F,), value (F, N, D) or (F, N)
                             array: position, velocity, heading (heading is flocklab's:
                             (F, N) angles in 2D, (F, N, 3) unit vectors in 3D), and
                             the derived per-agent arrays degree (F, N) int32 and
                             radius (F, N) (flocklab's, docs/TRAJECTORIES.md)
  /particles/swarm/image     step, time, value (F, N, D) int32: periodic image of each
                             agent, so position + image * edges is its unwrapped track
                             (written when exact: see `image_is_exact`)
  /observables/<name>        step (T,), time (T,), value (T,)
  /parameters/flocklab       attribute `scenario`: the canonical scenario JSON
  /parameters/flocklab/drawing   what drawing the run needs (flocklab's; see `DRAWING`):
                             attribute `facts` (JSON: the resolved neighbourhood test,
                             the units, default plots and overlays of the model's card),
                             attributes for labels, and a dataset per overlay array (the
                             parameters' obstacles; the engine's fixed graph, leader path
                             and virtual-leader offsets: kernels/overlays.py)
Frames are chunked one per chunk so a frame range can be read without the whole file;
`recording.precision` and `recording.compression` choose float32 and gzip for them.
Units follow the H5MD units module (`/h5md/modules/units`, a `unit` attribute on `time`
and `value`) where the model's paper states them (its card's `units`); quantities in the
model's own dimensionless units carry none, as the module allows.

The module imports no pydantic at run time: the renderer reads the layout names below.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

if TYPE_CHECKING:
    from flocklab.schemas import Scenario

DRAWING = "parameters/flocklab/drawing"  # the group of what drawing the run needs
# A fixed graph with more edges than this is left out of the run folder (10^6 edges are
# 8 MB, and already a blur in any picture); `facts["graph_edges_left_out"]` counts them.
MAX_STORED_EDGES = 1_000_000


def image_is_exact(scenario: Scenario) -> bool:
    """Whether the periodic images can be tracked exactly from the recorded frames: an
    agent must move less than L/2 between two frames, which holds for a constant-speed
    model (its card names the speed parameter) when speed dt every < L/2."""
    space, model, every = scenario.space, scenario.model, scenario.recording.every
    speed = type(model).constant_speed
    if space.kind != "periodic" or every == 0 or speed is None:
        return False
    return getattr(model, speed) * scenario.time.dt * every < space.L / 2


class PeriodicImages:
    """The periodic image of each agent, counted from one recorded frame to the next: a
    jump of more than L/2 between consecutive frames is a crossing of the box's edge
    (exact while agents move less than L/2 per frame: `image_is_exact`)."""

    def __init__(self, L: float):
        self.L = L
        self._last: np.ndarray | None = None
        self._image: np.ndarray | None = None

    def __call__(self, position: np.ndarray) -> np.ndarray:
        """The images (N, D) int32 at this frame, given its wrapped positions."""
        if self._last is None or self._image is None:
            self._image = np.zeros(position.shape, dtype=np.int32)
        else:
            self._image -= np.rint((position - self._last) / self.L).astype(np.int32)
        self._last = np.array(position, dtype=np.float64)
        return self._image.copy()


def drawing_facts(scenario: Scenario) -> dict[str, Any]:
    """The card's facts about drawing this run, resolved for its scenario."""
    card = type(scenario.model)
    return {"inclusive": scenario.inclusive,
            "units": {"time": card.units[0], "length": card.units[1]},
            "default_plots": list(card.default_plots), "overlays": list(card.overlays)}


class H5MDWriter:
    """A `FrameSink` writing an H5MD file; `write_observables` adds the observables and
    `write_overlays` the engine's overlay geometry once the run is over."""

    def __init__(self, path: Path, scenario: Scenario):
        self.f = h5py.File(path, "w")
        self.n = scenario.n_agents
        rec = scenario.recording
        self.dtype = np.float32 if rec.precision == "float32" else np.float64
        self.compression = ({"compression": "gzip", "compression_opts": 4, "shuffle": True}
                            if rec.compression == "gzip" else {})
        self.time_unit, self.length_unit = type(scenario.model).units
        self.images = PeriodicImages(scenario.space.L) if image_is_exact(scenario) else None
        h5 = self.f.create_group("h5md")
        h5.attrs["version"] = np.array([1, 1], dtype=np.int32)
        h5.create_group("author").attrs["name"] = "flocklab user"
        creator = h5.create_group("creator")
        creator.attrs["name"] = "flocklab"
        # Imported here: the module itself stays free of pydantic (the renderer reads it).
        from flocklab.schemas.version import version

        creator.attrs["version"] = version()
        if self.time_unit or self.length_unit:
            units = h5.create_group("modules/units")
            units.attrs["version"] = np.array([1, 0], dtype=np.int32)
            units.attrs["system"] = "SI"
        self.swarm = self.f.create_group("particles/swarm")
        box = self.swarm.create_group("box")
        dim = scenario.dimension
        box.attrs["dimension"] = dim
        if scenario.space.kind == "periodic":
            box.attrs["boundary"] = np.array([b"periodic"] * dim)
            edges = box.create_dataset("edges", data=np.array([scenario.space.L] * dim))
            self._unit(edges, self.length_unit)
        else:
            box.attrs["boundary"] = np.array([b"none"] * dim)
        params = self.f.create_group("parameters/flocklab")
        params.attrs["scenario"] = scenario.model_dump_json()
        self.drawing = self.f.create_group(DRAWING)
        self.facts = drawing_facts(scenario)
        self.write_overlays(scenario.model.scene())
        self.frames = 0
        self.frame_times: list[float] = []  # of the position frames, for the overlays

    def frame(self, step: int, time: float, arrays: dict[str, np.ndarray]) -> None:
        if "position" in arrays:
            self.frame_times.append(time)
        if self.images is not None and "position" in arrays:
            arrays = {**arrays, "image": self.images(arrays["position"])}
        for name, value in arrays.items():
            if name not in self.swarm:
                self._create(name, value)
            g = self.swarm[name]
            k = g["step"].shape[0]
            for key, v in (("step", step), ("time", time), ("value", value)):
                g[key].resize(k + 1, axis=0)
                g[key][k] = v
        self.frames += 1

    def _create(self, name: str, value: np.ndarray) -> None:
        g = self.swarm.create_group(name)
        shape = value.shape
        g.create_dataset("step", shape=(0,), maxshape=(None,), dtype=np.int64,
                         chunks=(1024,))
        self._unit(g.create_dataset("time", shape=(0,), maxshape=(None,), dtype=np.float64,
                                    chunks=(1024,)), self.time_unit)
        # Counts are integers: the image and the degree (whatever recording.precision).
        dtype = np.int32 if name in ("image", "degree") else self.dtype
        ds = g.create_dataset("value", shape=(0, *shape), maxshape=(None, *shape),
                              dtype=dtype, chunks=(1, *shape), **self.compression)
        # A 3D heading is a unit vector, without a unit.
        unit = {"position": self.length_unit, "heading": "rad" if value.ndim == 1 else None,
                "velocity": self._velocity_unit(), "radius": self.length_unit}.get(name)
        self._unit(ds, unit)

    def _velocity_unit(self) -> str | None:
        if self.length_unit and self.time_unit:
            return f"{self.length_unit} {self.time_unit}-1"
        return None

    @staticmethod
    def _unit(ds: h5py.Dataset, unit: str | None) -> None:
        if unit:
            ds.attrs["unit"] = unit

    def write_observables(self, observables: dict[str, np.ndarray]) -> None:
        obs = self.f.create_group("observables")
        for name, value in observables.items():
            if name in ("step", "time"):
                continue
            g = obs.create_group(name)
            g.create_dataset("step", data=observables["step"].astype(np.int64))
            self._unit(g.create_dataset("time", data=observables["time"]), self.time_unit)
            g.create_dataset("value", data=value)

    def write_overlays(self, overlays: dict[str, Any]) -> None:
        """Overlay geometry into the drawing group: text as attributes, numbers as
        datasets (a fixed graph past MAX_STORED_EDGES left out, and counted)."""
        for name, value in overlays.items():
            if isinstance(value, str):
                self.drawing.attrs[name] = value
            elif name == "graph_edges" and len(value) > MAX_STORED_EDGES:
                self.facts["graph_edges_left_out"] = len(value)
            else:
                data = np.asarray(value)
                if data.dtype.kind in "iu":  # agent ids (< MAX_AGENTS)
                    data = data.astype(np.int32)
                self.drawing.create_dataset(name, data=data)

    def close(self) -> None:
        self.drawing.attrs["facts"] = json.dumps(self.facts)
        self.f.close()
