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
Frames are chunked one per chunk so a frame range can be read without the whole file;
`recording.precision` and `recording.compression` choose float32 and gzip for them.
Units follow the H5MD units module (`/h5md/modules/units`, a `unit` attribute on `time`
and `value`) where the model's paper states them (see `UNITS`); quantities in the
model's own dimensionless units carry none, as the module allows.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from flocklab.schemas import PeriodicBox, Scenario

VERSION = "0.1.0"

# Units of (time, length) per model family, as the papers state them: papers 000 and
# 002 use metres and seconds, paper 003 seconds (its lengths have no unit), the Vicsek
# model neither. A missing unit means the model's own dimensionless unit.
UNITS: dict[str, tuple[str | None, str | None]] = {
    "flocking": ("s", "m"),
    "flocking_obstacles": ("s", "m"),
    "formation": ("s", None),
    "vicsek": (None, None),
}


def image_is_exact(scenario: Scenario) -> bool:
    """Whether the periodic images can be tracked exactly from the recorded frames: an
    agent must move less than L/2 between two frames, which holds for the constant-speed
    Vicsek family when v0 dt every < L/2 (no other model runs in a periodic box)."""
    space, model, every = scenario.space, scenario.model, scenario.recording.every
    if not isinstance(space, PeriodicBox) or every == 0 or model.kind != "vicsek":
        return False
    return model.v0 * scenario.time.dt * every < space.L / 2


class H5MDWriter:
    """A `FrameSink` writing an H5MD file; `close(result)` adds the observables."""

    def __init__(self, path: Path, scenario: Scenario):
        self.f = h5py.File(path, "w")
        self.n = scenario.n_agents
        rec = scenario.recording
        self.dtype = np.float32 if rec.precision == "float32" else np.float64
        self.compression = ({"compression": "gzip", "compression_opts": 4, "shuffle": True}
                            if rec.compression == "gzip" else {})
        self.time_unit, self.length_unit = UNITS.get(scenario.model.kind, (None, None))
        # Periodic images: the box side, the last wrapped positions and their images.
        self.L = scenario.space.L if image_is_exact(scenario) else None
        self._last: np.ndarray | None = None
        self._image: np.ndarray | None = None
        h5 = self.f.create_group("h5md")
        h5.attrs["version"] = np.array([1, 1], dtype=np.int32)
        h5.create_group("author").attrs["name"] = "flocklab user"
        creator = h5.create_group("creator")
        creator.attrs["name"] = "flocklab"
        creator.attrs["version"] = VERSION
        if self.time_unit or self.length_unit:
            units = h5.create_group("modules/units")
            units.attrs["version"] = np.array([1, 0], dtype=np.int32)
            units.attrs["system"] = "SI"
        self.swarm = self.f.create_group("particles/swarm")
        box = self.swarm.create_group("box")
        dim = scenario.dimension
        box.attrs["dimension"] = dim
        if isinstance(scenario.space, PeriodicBox):
            box.attrs["boundary"] = np.array([b"periodic"] * dim)
            edges = box.create_dataset("edges", data=np.array([scenario.space.L] * dim))
            self._unit(edges, self.length_unit)
        else:
            box.attrs["boundary"] = np.array([b"none"] * dim)
        params = self.f.create_group("parameters/flocklab")
        params.attrs["scenario"] = scenario.model_dump_json()
        self.frames = 0

    def frame(self, step: int, time: float, arrays: dict[str, np.ndarray]) -> None:
        if self.L is not None and "position" in arrays:
            arrays = {**arrays, "image": self._track_image(arrays["position"])}
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

    def _track_image(self, position: np.ndarray) -> np.ndarray:
        """The image of each agent: a jump of more than L/2 between consecutive frames is
        a crossing of the box's edge (exact while agents move less than L/2 per frame)."""
        assert self.L is not None
        if self._last is None or self._image is None:
            self._image = np.zeros(position.shape, dtype=np.int32)
        else:
            self._image -= np.rint((position - self._last) / self.L).astype(np.int32)
        self._last = np.array(position, dtype=np.float64)
        return self._image.copy()

    def write_observables(self, observables: dict[str, np.ndarray]) -> None:
        obs = self.f.create_group("observables")
        for name, value in observables.items():
            if name in ("step", "time"):
                continue
            g = obs.create_group(name)
            g.create_dataset("step", data=observables["step"].astype(np.int64))
            self._unit(g.create_dataset("time", data=observables["time"]), self.time_unit)
            g.create_dataset("value", data=value)

    def close(self) -> None:
        self.f.close()
