"""A job's results: metrics (JSON), trajectory slices (NPZ or JSON), the H5MD and GSD files.

Paths come only from the job's UUID through `ResultStore` (R22). Expired results are 410
`results-expired`; a results folder deleted behind the service's back is 410
`results-missing`; a result file that cannot be read is 500 `results-corrupted` (never a
generic 500, never the file's path).
"""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Annotated, Any, Literal

import h5py
from fastapi import APIRouter, Header, Query
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse
from starlette.concurrency import run_in_threadpool

from flocklab.service.jobs import Job, JobRuntime

from .. import trajectory as traj
from ..deps import JobId, RuntimeDep, SettingsDep, results_dir
from ..observables import CorruptObservables, read_header, stream_metrics
from ..problems import ProblemError
from ..ranges import check_range

router = APIRouter(prefix="/jobs", tags=["results"])
_ERRORS: dict[int | str, dict[str, Any]] = {401: {}, 404: {}, 409: {}, 410: {}, 422: {},
                                             500: {}}


def corrupted(name: str) -> ProblemError:
    """A result file exists but cannot be read (damaged on disk)."""
    return ProblemError(500, "results-corrupted", "Results corrupted",
                        f"the job's {name} is damaged on the server and cannot be read; "
                        f"run the job again", file=name)


def _results_dir(runtime: JobRuntime, job_id: JobId) -> tuple[Job, Path]:
    return results_dir(runtime, job_id)


@router.get("/{job_id}/metrics", summary="Summary and observables time series",
            responses={200: {"content": {"application/json": {"example": {
                "job_id": "3f2b8e1c-8f3a-4c55-9d2e-0c6b1f8e9a41",
                "summary": {"status": "completed", "backend": "cpu", "n_agents": 300},
                "observables": {"step": [0, 1], "time": [0.0, 1.0],
                                "polarization": [0.04, 0.3]}}}}}, **_ERRORS})
def metrics(job_id: JobId, runtime: RuntimeDep) -> StreamingResponse:
    job, folder = _results_dir(runtime, job_id)
    try:
        summary = json.loads((folder / "summary.json").read_bytes())
    except (OSError, ValueError):
        raise corrupted("summary.json") from None
    csv_path = folder / "observables.csv"
    try:
        names = read_header(csv_path)
    except (OSError, CorruptObservables):
        raise corrupted("observables.csv") from None
    head = {"job_id": job.id, "summary": _finite(summary)}
    return StreamingResponse(stream_metrics(head, csv_path, names),
                             media_type="application/json")


def _finite(x: Any) -> Any:
    """JSON has no NaN/Infinity: a diverged run's summary may hold them; they become null."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return x


@router.get(
    "/{job_id}/trajectory",
    summary="A slice of the trajectory as NPZ or JSON",
    description="Frames `start:stop:stride` (frame indices, Python slice rules) of the "
    "recorded arrays for a subset of agents. NPZ (`numpy.load`) holds `step`, `time`, "
    "`agents` and one array per recorded quantity, shaped (frames, agents[, components]); "
    "it is streamed. JSON holds the same as lists and is refused with 413 above the "
    "service's size cap (use NPZ, a stride or fewer agents).",
    response_class=StreamingResponse,
    response_model=None,
    responses={200: {"content": {"application/x-npz": {"schema": {"type": "string",
                                                                   "format": "binary"}},
                                 "application/json": {"schema": {"type": "object"}}}},
               413: {}, **_ERRORS},
)
async def trajectory(
    job_id: JobId,
    runtime: RuntimeDep,
    settings: SettingsDep,
    format: Annotated[Literal["npz", "json"], Query(description="Output format.")] = "npz",
    start: Annotated[int | None, Query(ge=-2**62, le=2**62, description="First frame index."
                                       )] = None,
    stop: Annotated[int | None, Query(ge=-2**62, le=2**62,
                                      description="Frame index to stop before.")] = None,
    stride: Annotated[int, Query(ge=1, le=2**31, description="Take every k-th frame.")] = 1,
    agents: Annotated[str | None, Query(
        max_length=100_000, pattern=r"^[0-9:,]*$",
        description="'a:b[:s]' or comma-separated agent ids; default: all.")] = None,
    arrays: Annotated[str | None, Query(
        max_length=200, description="Comma-separated arrays; default: all recorded.")] = None,
) -> StreamingResponse | JSONResponse:
    job, folder = await run_in_threadpool(_results_dir, runtime, job_id)
    path = folder / "trajectory.h5"

    def check() -> dict[str, Any] | None:
        try:
            with h5py.File(path, "r") as f:
                sel = traj.select(f, arrays, start, stop, stride, agents)
                if format == "npz":
                    return None
                size = traj.json_size_estimate(f, sel)
                if size > settings.max_json_bytes:
                    raise ProblemError(
                        413, "slice-too-large", "Slice too large for JSON",
                        f"about {size} bytes as JSON, over the cap of "
                        f"{settings.max_json_bytes}; use format=npz, a stride, or fewer "
                        f"agents", estimated_bytes=size, max_json_bytes=settings.max_json_bytes)
                return traj.to_json(f, sel)
        except (OSError, KeyError):  # not HDF5, truncated, or missing its datasets
            raise corrupted("trajectory.h5") from None

    body = await run_in_threadpool(check)
    if body is not None:
        return JSONResponse({"job_id": job.id, **body})
    return StreamingResponse(
        traj.stream_npz(path, arrays, start, stop, stride, agents),
        media_type="application/x-npz",
        headers={"Content-Disposition": f'attachment; filename="{job.id}.npz"'},
    )


@router.get(
    "/{job_id}/trajectory.h5",
    summary="The whole H5MD trajectory file",
    description="Streamed from disk; supports `Range` requests. `Repr-Digest` carries the "
    "file's sha-256 (RFC 9530).",
    response_class=FileResponse,
    responses={200: {"content": {"application/x-hdf5": {"schema": {"type": "string",
                                                                    "format": "binary"}}}},
               206: {"description": "Partial Content (a Range request)."},
               400: {}, 416: {}, **_ERRORS},
)
def trajectory_file(job_id: JobId, runtime: RuntimeDep,
                    range_: Annotated[str | None, Header(alias="Range", include_in_schema=False)
                                      ] = None) -> FileResponse:
    return _whole_file(runtime, job_id, range_, "trajectory.h5", "application/x-hdf5")


@router.get(
    "/{job_id}/trajectory.gsd",
    summary="The whole GSD trajectory file (HOOMD's schema)",
    description="A job whose scenario's `recording.format` names gsd has it (404 "
    "`no-trajectory` otherwise); OVITO, freud and MDAnalysis open it. Streamed from disk; "
    "supports `Range` requests. `Repr-Digest` carries the file's sha-256 (RFC 9530).",
    response_class=FileResponse,
    responses={200: {"content": {"application/octet-stream": {
                   "schema": {"type": "string", "format": "binary"}}}},
               206: {"description": "Partial Content (a Range request)."},
               400: {}, 416: {}, **_ERRORS},
)
def trajectory_gsd_file(job_id: JobId, runtime: RuntimeDep,
                        range_: Annotated[str | None, Header(alias="Range",
                                                             include_in_schema=False)] = None
                        ) -> FileResponse:
    return _whole_file(runtime, job_id, range_, "trajectory.gsd", "application/octet-stream")


def _whole_file(runtime: JobRuntime, job_id: JobId, range_: str | None, name: str,
                media_type: str) -> FileResponse:
    """A job's result file `name`, downloaded as <job id><its suffix>."""
    job, _ = _results_dir(runtime, job_id)
    path = runtime.results.file(job.id, name)
    if not path.is_file():
        raise ProblemError(404, "no-trajectory", "No trajectory",
                           f"this job has no {name}")
    check_range(range_, path)
    headers = {}
    sums = json.loads(job.checksums) if job.checksums else {}
    if name in sums:
        digest = base64.b64encode(bytes.fromhex(sums[name])).decode()
        headers["Repr-Digest"] = f"sha-256=:{digest}:"
    return FileResponse(path, media_type=media_type, filename=f"{job.id}{path.suffix}",
                        headers=headers)
