"""GSD trajectory writer (HOOMD-blue's schema, through the `gsd` package), and the H5MD to
GSD conversion of `flocklab convert`.

One GSD frame per recorded frame (https://gsd.readthedocs.io/en/stable/schema-hoomd.html):
  configuration/step        the frame's step (its time, step * dt, is log/flocklab/time)
  configuration/dimensions  2 or 3 (space.dimension)
  configuration/box         [Lx, Ly, Lz, 0, 0, 0], centred on the origin as HOOMD's boxes are;
                            Lz = 0 in 2D (HOOMD's 2D box). Periodic runs: Lx = Ly (= Lz) =
                            L. Unbounded runs: a square (cube) of side 4 max|x_ik| over the
                            frame (1 for a frame all at the origin), per frame: it holds
                            the frame, and since every coordinate difference is at most
                            2 max|x_ik|, half the side, each pair's minimum-image separation
                            is its true one, so periodic readers (freud, OVITO) see the
                            unbounded swarm as it is
  particles/N, types, typeid   N agents of one type "A"
  particles/position        float32 (N, 3), z = 0 in 2D; a periodic run's shifted by -L/2
                            into HOOMD's [-L/2, L/2)^D (flocklab wraps into [0, L)^D)
  particles/velocity        float32 (N, 3), z = 0 in 2D: when velocity is recorded
  particles/orientation     float32 (N, 4) unit quaternions (w, x, y, z): when heading is
                            recorded, the rotation taking the body's x axis to the heading:
                            2D by the angle theta about z, (cos theta/2, 0, 0, sin theta/2);
                            3D the shortest arc from x to the unit heading h (no roll about
                            h: flocklab's 3D agents have none), `orientation`
  particles/image           int32 (N, 3): the periodic image, as trajectory.h5's `image`
                            (unwrapped = position + image * L; written when it is exact)
  log/particles/<name>      the derived per-agent arrays degree (int32) and radius (float32)
                            when recorded (OVITO reads them as particle properties)
  log/flocklab/time         float64 (1,): the frame's time
Floats are float32 whatever `recording.precision` says: HOOMD's schema types, which every
GSD reader takes.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import TYPE_CHECKING

import gsd.hoomd
import h5py
import numpy as np

from .h5md import PeriodicImages, image_is_exact

if TYPE_CHECKING:
    from flocklab.schemas import Scenario

GSD_FILE = "trajectory.gsd"
TYPES = ["A"]
# The per-agent arrays with no HOOMD field: HOOMD's per-particle log quantities.
LOGGED = {"degree": np.int32, "radius": np.float32}


class ConvertError(ValueError):
    """A run folder that cannot be converted; the message says why."""


def orientation(heading: np.ndarray, dimension: int) -> np.ndarray:
    """Unit quaternions (N, 4), (w, x, y, z), rotating the x axis onto each heading: the
    angles theta (N,) in 2D, the unit vectors h (N, 3) in 3D. 3D: q = (1 + x.h, x cross h)
    normalised = (1 + h_x, 0, -h_z, h_y) / sqrt(2 (1 + h_x)); a heading along -x (where
    that vanishes) takes the half turn about z, (0, 0, 0, 1)."""
    h = np.asarray(heading, dtype=np.float64)
    if dimension == 2:
        half = h / 2
        zero = np.zeros_like(half)
        return np.column_stack([np.cos(half), zero, zero, np.sin(half)])
    w = 1.0 + h[:, 0]
    q = np.column_stack([w, np.zeros_like(w), -h[:, 2], h[:, 1]])
    opposite = w <= 1e-12
    q[opposite] = (0.0, 0.0, 0.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def frame_box(position: np.ndarray, dimension: int, L: float | None) -> list[float]:
    """configuration/box of a frame: the periodic box of side L, or for an unbounded run
    (L None) the origin-centred square (cube) of side 4 max|x_ik| (see the module's
    docstring)."""
    if L is None:
        m = float(np.max(np.abs(position))) if position.size else 0.0
        L = 4.0 * m if m > 0 else 1.0
    return [L, L, L if dimension == 3 else 0.0, 0.0, 0.0, 0.0]


def _xyz(a: np.ndarray, dtype: type) -> np.ndarray:
    """(N, D) as (N, 3) of `dtype`, z = 0 in 2D."""
    out = np.zeros((a.shape[0], 3), dtype=dtype)
    out[:, : a.shape[1]] = a
    return out


class GSDWriter:
    """A `FrameSink` appending HOOMD frames to a GSD file (see the module's docstring).

    `L`: the periodic box's side (None: unbounded); `images`: the image tracker of a run
    whose images are exact (a frame's own "image" array, as the converter passes it, is
    written as it is)."""

    def __init__(self, path: Path, dimension: int, L: float | None,
                 images: PeriodicImages | None = None):
        self.traj = gsd.hoomd.open(path, "w")
        self.dimension, self.L, self.images = dimension, L, images
        self.frames = 0

    @classmethod
    def for_scenario(cls, path: Path, scenario: Scenario) -> GSDWriter:
        L = scenario.space.L if scenario.space.kind == "periodic" else None
        images = PeriodicImages(scenario.space.L) if image_is_exact(scenario) else None
        return cls(path, scenario.dimension, L, images)

    def frame(self, step: int, time: float, arrays: dict[str, np.ndarray]) -> None:
        position = np.asarray(arrays["position"], dtype=np.float64)
        f = gsd.hoomd.Frame()
        f.configuration.step = step
        f.configuration.dimensions = self.dimension
        f.configuration.box = frame_box(position, self.dimension, self.L)
        f.particles.N = len(position)
        f.particles.types = TYPES
        f.particles.typeid = np.zeros(len(position), dtype=np.uint32)
        # HOOMD's box spans [-L/2, L/2); flocklab's periodic box [0, L).
        shift = self.L / 2 if self.L is not None else 0.0
        f.particles.position = _xyz(position - shift, np.float32)
        if "velocity" in arrays:
            f.particles.velocity = _xyz(arrays["velocity"], np.float32)
        if "heading" in arrays:
            f.particles.orientation = orientation(arrays["heading"], self.dimension
                                                  ).astype(np.float32)
        image = arrays.get("image")
        if image is None and self.images is not None:
            image = self.images(position)
        if image is not None:
            f.particles.image = _xyz(image, np.int32)
        for name, dtype in LOGGED.items():
            if name in arrays:
                f.log[f"particles/{name}"] = np.asarray(arrays[name], dtype=dtype)
        f.log["flocklab/time"] = np.array([time], dtype=np.float64)
        self.traj.append(f)
        self.frames += 1

    def close(self) -> None:
        self.traj.close()


def convert_run(run_dir: Path, *, overwrite: bool = False) -> tuple[Path, int]:
    """Write RUN_DIR/trajectory.gsd from RUN_DIR/trajectory.h5's frames (the file a run
    with recording.format gsd writes, frame for frame); returns its path and its number of
    frames. The file appears whole or not at all (written aside, then renamed)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ConvertError(f"{run_dir}: no such run folder")
    source = run_dir / "trajectory.h5"
    if not source.is_file():
        raise ConvertError(f"{run_dir} has no trajectory.h5 (not a run folder of "
                           "`flocklab run --out`, a job's results, or a sweep's runs/<i>)")
    target = run_dir / GSD_FILE
    if target.exists() and not overwrite:
        raise ConvertError(f"{target} exists (--overwrite replaces it)")
    tmp = run_dir / f".{GSD_FILE}.partial-{uuid.uuid4().hex[:8]}"
    try:
        with _open_h5(source) as f:
            frames = _convert(f, source, tmp)
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    return target, frames


def _open_h5(source: Path) -> h5py.File:
    try:
        return h5py.File(source, "r")
    except OSError as exc:
        raise ConvertError(f"{source} is not a readable HDF5 file ({exc})") from None


def _convert(f: h5py.File, source: Path, tmp: Path) -> int:
    """Copy the frames of an open trajectory.h5 into the GSD file `tmp`."""
    try:
        swarm = f["particles/swarm"]
        box = swarm["box"]
        dimension = int(box.attrs["dimension"])
        periodic = box.attrs["boundary"][0] in (b"periodic", "periodic")
        L = float(box["edges"][0]) if periodic else None
    except KeyError as exc:
        raise ConvertError(f"{source} is not flocklab's H5MD file (no {exc.args[0]})") from None
    if "position" not in swarm or swarm["position/step"].shape[0] == 0:
        raise ConvertError(f"{source} holds no frames of positions (recorded with "
                           "recording.every 0, without position, or with recording.format "
                           "gsd alone)")
    steps = swarm["position/step"][:]
    times = swarm["position/time"][:]
    # Every array is recorded at the position frames (service/h5md.py).
    names = [n for n in ("position", "velocity", "heading", "image", *LOGGED)
             if n in swarm and np.array_equal(swarm[f"{n}/step"][:], steps)]
    writer = GSDWriter(tmp, dimension, L)
    try:
        for k, (step, time) in enumerate(zip(steps, times, strict=True)):
            writer.frame(int(step), float(time),
                         {n: swarm[f"{n}/value"][k] for n in names})
    finally:
        writer.close()
    return writer.frames
