"""Slices of a job's H5MD trajectory, read with h5py and streamed (R23).

The file holds `/particles/swarm/<array>/{step,time,value}` with value shaped
(frames, N, components) — or (frames, N) for scalar arrays. A slice picks frames
`start:stop:stride` and a subset of agents, and is read a block of frames at a time, so a
request never holds the whole trajectory in memory. NPZ output is written into a zip
stream as it is read; JSON is built in memory and therefore capped.
"""

from __future__ import annotations

import math
import re
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from flocklab.schemas import FieldError

from .problems import ProblemError, invalid

GROUP = "particles/swarm"
BLOCK_BYTES = 8 * 2**20  # frames read per block: about this many bytes
JSON_BYTES_PER_VALUE = 24  # a float printed as JSON, with its separator


@dataclass(frozen=True)
class Selection:
    arrays: tuple[str, ...]
    frames: slice
    agents: slice | np.ndarray


def _bad(loc: str, msg: str) -> Exception:
    return invalid([FieldError(loc=f"query.{loc}", msg=msg, type="value_error")])


def parse_agents(spec: str | None, n_agents: int) -> slice | np.ndarray:
    """`a:b[:s]` (a slice) or `i,j,k` (ids, any order, no repeats) or None (all agents)."""
    if spec is None or spec == "":
        return slice(None)
    # Python refuses to parse integers of more than 4300 digits (a ValueError that was a
    # 500); no agent index needs more than 18.
    if re.search(r"\d{19}", spec):
        raise _bad("agents", "agent indices must be below 10^18")
    m = re.fullmatch(r"(\d*):(\d*)(?::(\d+))?", spec)
    if m:
        start, stop, step = (int(g) if g else None for g in m.groups())
        if step == 0:
            raise _bad("agents", "the agent stride must be positive")
        return slice(start, stop, step)
    try:
        ids = np.array([int(s) for s in spec.split(",")], dtype=np.int64)
    except ValueError:
        raise _bad("agents", "expected 'start:stop[:stride]' or comma-separated agent ids"
                   ) from None
    if ids.size == 0 or ids.min() < 0 or ids.max() >= n_agents:
        raise _bad("agents", f"agent ids must lie in [0, {n_agents})")
    if np.unique(ids).size != ids.size:
        raise _bad("agents", "agent ids must not repeat")
    return ids


def select(f: h5py.File, arrays: str | None, start: int | None, stop: int | None,
           stride: int, agents: str | None) -> Selection:
    """Check a request against the file's contents and build the selection."""
    if GROUP not in f:
        raise ProblemError(404, "no-frames", "No frames recorded",
                           "this job recorded no frames (recording.every was 0)")
    # Recorded arrays are the groups with a `value` dataset (`box` is not one).
    have = tuple(k for k, g in f[GROUP].items() if isinstance(g, h5py.Group) and "value" in g)
    if not have:
        raise ProblemError(404, "no-frames", "No frames recorded",
                           "this job recorded no frames (recording.every was 0)")
    wanted = tuple(have if not arrays else (a.strip() for a in arrays.split(",")))
    for a in wanted:
        if a not in have:
            raise _bad("arrays", f"{a!r} was not recorded; recorded: {', '.join(have)}")
    n_agents = f[f"{GROUP}/{wanted[0]}/value"].shape[1]
    return Selection(wanted, slice(start, stop, stride), parse_agents(agents, n_agents))


def frame_indices(f: h5py.File, sel: Selection) -> np.ndarray:
    n_frames = f[f"{GROUP}/{sel.arrays[0]}/value"].shape[0]
    return np.arange(n_frames)[sel.frames]


def agent_indices(f: h5py.File, sel: Selection) -> np.ndarray:
    n_agents = f[f"{GROUP}/{sel.arrays[0]}/value"].shape[1]
    if isinstance(sel.agents, slice):
        return np.arange(n_agents)[sel.agents]
    return sel.agents


def _read(ds: h5py.Dataset, frames: np.ndarray, agents: np.ndarray) -> np.ndarray:
    """ds[frames][:, agents] for evenly spaced frames, as one strided hyperslab read.

    Agent ids are applied in memory: h5py fancy-indexes only increasing ids, and a block
    is bounded by BLOCK_BYTES anyway.
    """
    if frames.size == 0 or agents.size == 0:
        return np.empty((frames.size, agents.size, *ds.shape[2:]), dtype=ds.dtype)
    step = int(frames[1] - frames[0]) if frames.size > 1 else 1
    block = ds[int(frames[0]):int(frames[-1]) + 1:step]
    return block[:, agents]


def _blocks(ds: h5py.Dataset, frames: np.ndarray, agents: np.ndarray) -> Iterator[np.ndarray]:
    """The slice a block of frames at a time (at least one block, maybe empty)."""
    per_frame = max(1, ds.shape[1] * int(np.prod(ds.shape[2:], dtype=np.int64))
                    * ds.dtype.itemsize)
    n = max(1, BLOCK_BYTES // per_frame)
    yield _read(ds, frames[:n], agents)
    for i in range(n, frames.size, n):
        yield _read(ds, frames[i:i + n], agents)


def json_size_estimate(f: h5py.File, sel: Selection) -> int:
    frames, agents = frame_indices(f, sel), agent_indices(f, sel)
    values = 0
    for a in sel.arrays:
        ds = f[f"{GROUP}/{a}/value"]
        values += frames.size * agents.size * int(np.prod(ds.shape[2:], dtype=np.int64))
    return values * JSON_BYTES_PER_VALUE


def to_json(f: h5py.File, sel: Selection) -> dict[str, object]:
    frames, agents = frame_indices(f, sel), agent_indices(f, sel)
    first = f[f"{GROUP}/{sel.arrays[0]}"]
    out: dict[str, object] = {
        "step": first["step"][:][frames].tolist(),
        "time": first["time"][:][frames].tolist(),
        "agents": agents.tolist(),
    }
    for a in sel.arrays:
        value = np.concatenate(list(_blocks(f[f"{GROUP}/{a}/value"], frames, agents)))
        # Non-finite values (a diverged run's last frames) have no JSON form: null.
        out[a] = _nan_to_none(value.tolist())
    return out


def _nan_to_none(x: object) -> object:
    if isinstance(x, list):
        return [_nan_to_none(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x


class _ZipSink:
    """A write-only, non-seekable file for zipfile that hands the bytes on as chunks."""

    def __init__(self) -> None:
        self._chunks: list[bytes] = []
        self._pos = 0

    def write(self, b: bytes) -> int:
        self._chunks.append(bytes(b))
        self._pos += len(b)
        return len(b)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def take(self) -> bytes:
        out = b"".join(self._chunks)
        self._chunks.clear()
        return out


def stream_npz(path: Path, arrays: str | None, start: int | None, stop: int | None,
               stride: int, agents: str | None) -> Iterator[bytes]:
    """An NPZ (zip of .npy) of the slice, produced block by block.

    The caller validates the request first with `select` (so errors become a 422
    before the response starts); this generator re-opens the file to stream it.
    """
    sink = _ZipSink()
    with h5py.File(path, "r") as f:
        sel = select(f, arrays, start, stop, stride, agents)
        frames, agent_ids = frame_indices(f, sel), agent_indices(f, sel)
        first = f[f"{GROUP}/{sel.arrays[0]}"]
        with zipfile.ZipFile(sink, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as z:
            small = {"step": first["step"][:][frames], "time": first["time"][:][frames],
                     "agents": agent_ids}
            for name, arr in small.items():
                with z.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.ascontiguousarray(arr),
                                              allow_pickle=False)
                yield sink.take()
            for a in sel.arrays:
                ds = f[f"{GROUP}/{a}/value"]
                shape = (frames.size, agent_ids.size, *ds.shape[2:])
                header = {"descr": np.lib.format.dtype_to_descr(ds.dtype),
                          "fortran_order": False, "shape": shape}
                with z.open(f"{a}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array_header_2_0(member, header)
                    for block in _blocks(ds, frames, agent_ids):
                        member.write(np.ascontiguousarray(block).tobytes())
                        yield sink.take()
                yield sink.take()
        yield sink.take()
