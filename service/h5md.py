"""H5MD trajectory writer (HDF5 via h5py), appended frame by frame.

Layout (H5MD 1.1, https://www.nongnu.org/h5md/h5md.html):
  /h5md                      version, author, creator
  /particles/swarm/box       dimension = D (2 or 3: space.dimension),
                             boundary = periodic|none (xD), edges = [L] * D
  /particles/swarm/<array>   step (F,), time (F,), value (F, N, D) or (F, N)
                             array: position, velocity, heading (heading is flocklab's:
                             (F, N) angles in 2D, (F, N, 3) unit vectors in 3D)
  /observables/<name>        step (T,), time (T,), value (T,)
  /parameters/flocklab       attribute `scenario`: the canonical scenario JSON
Frames are chunked one per chunk so a frame range can be read without the whole file.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
from flocklab.schemas import PeriodicBox, Scenario

VERSION = "0.1.0"


class H5MDWriter:
    """A `FrameSink` writing an H5MD file; `close(result)` adds the observables."""

    def __init__(self, path: Path, scenario: Scenario):
        self.f = h5py.File(path, "w")
        self.n = scenario.n_agents
        h5 = self.f.create_group("h5md")
        h5.attrs["version"] = np.array([1, 1], dtype=np.int32)
        h5.create_group("author").attrs["name"] = "flocklab user"
        creator = h5.create_group("creator")
        creator.attrs["name"] = "flocklab"
        creator.attrs["version"] = VERSION
        self.swarm = self.f.create_group("particles/swarm")
        box = self.swarm.create_group("box")
        dim = scenario.dimension
        box.attrs["dimension"] = dim
        if isinstance(scenario.space, PeriodicBox):
            box.attrs["boundary"] = np.array([b"periodic"] * dim)
            box.create_dataset("edges", data=np.array([scenario.space.L] * dim))
        else:
            box.attrs["boundary"] = np.array([b"none"] * dim)
        params = self.f.create_group("parameters/flocklab")
        params.attrs["scenario"] = scenario.model_dump_json()
        self.frames = 0

    def frame(self, step: int, time: float, arrays: dict[str, np.ndarray]) -> None:
        for name, value in arrays.items():
            if name not in self.swarm:
                g = self.swarm.create_group(name)
                shape = value.shape
                g.create_dataset("step", shape=(0,), maxshape=(None,), dtype=np.int64,
                                 chunks=(1024,))
                g.create_dataset("time", shape=(0,), maxshape=(None,), dtype=np.float64,
                                 chunks=(1024,))
                g.create_dataset("value", shape=(0, *shape), maxshape=(None, *shape),
                                 dtype=np.float64, chunks=(1, *shape))
            g = self.swarm[name]
            k = g["step"].shape[0]
            for key, v in (("step", step), ("time", time), ("value", value)):
                g[key].resize(k + 1, axis=0)
                g[key][k] = v
        self.frames += 1

    def write_observables(self, observables: dict[str, np.ndarray]) -> None:
        obs = self.f.create_group("observables")
        for name, value in observables.items():
            if name in ("step", "time"):
                continue
            g = obs.create_group(name)
            g.create_dataset("step", data=observables["step"].astype(np.int64))
            g.create_dataset("time", data=observables["time"])
            g.create_dataset("value", data=value)

    def close(self) -> None:
        self.f.close()
