"""A job's results: metrics (JSON), trajectory slices (NPZ or JSON) and the H5MD file.

Paths come only from the job's UUID through `ResultStore` (R22). Expired results are 410.
"""

from __future__ import annotations

import base64
import csv
import json
import math
from pathlib import Path
from typing import Annotated, Any, Literal

import h5py
from fastapi import APIRouter, Query
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse
from starlette.concurrency import run_in_threadpool

from service.jobs import Job, JobRuntime

from .. import trajectory as traj
from ..deps import JobId, RuntimeDep, SettingsDep, get_job
from ..problems import ProblemError

router = APIRouter(prefix="/jobs", tags=["results"])
_ERRORS: dict[int | str, dict[str, Any]] = {401: {}, 404: {}, 409: {}, 410: {}, 422: {}}


def _results_dir(runtime: JobRuntime, job_id: JobId) -> tuple[Job, Path]:
    job = get_job(runtime, job_id)
    if job.results_expired:
        raise ProblemError(410, "results-expired", "Results expired",
                           "this job's results were deleted after the retention period")
    if not job.has_results:
        if not job.terminal:
            raise ProblemError(409, "results-pending", "Results not ready",
                               f"the job is {job.status}", status_now=job.status)
        raise ProblemError(404, "no-results", "No results",
                           f"the job ended ({job.status}) without results")
    folder = runtime.results.job_dir(job.id)
    if not folder.is_dir():  # deleted under us by the expiry sweep
        raise ProblemError(410, "results-expired", "Results expired",
                           "this job's results were deleted after the retention period")
    return job, folder


@router.get("/{job_id}/metrics", summary="Summary and observables time series",
            responses={200: {"content": {"application/json": {"example": {
                "job_id": "3f2b8e1c-8f3a-4c55-9d2e-0c6b1f8e9a41",
                "summary": {"status": "completed", "backend": "cpu", "n_agents": 300},
                "observables": {"step": [0, 1], "time": [0.0, 1.0],
                                "polarization": [0.04, 0.3]}}}}}, **_ERRORS})
def metrics(job_id: JobId, runtime: RuntimeDep) -> JSONResponse:
    job, folder = _results_dir(runtime, job_id)
    summary = json.loads((folder / "summary.json").read_text())
    return JSONResponse({"job_id": job.id, "summary": _finite(summary),
                         "observables": _read_observables(folder / "observables.csv")})


def _read_observables(path: Path) -> dict[str, list[float | None]]:
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return {}
    names, values = rows[0], rows[1:]
    return {name: [_number(r[i]) for r in values] for i, name in enumerate(names)}


def _number(s: str) -> float | None:
    try:
        v = float(s)
    except ValueError:
        return None
    return v if math.isfinite(v) else None


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
    start: Annotated[int | None, Query(description="First frame index.")] = None,
    stop: Annotated[int | None, Query(description="Frame index to stop before.")] = None,
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
        with h5py.File(path, "r") as f:
            sel = traj.select(f, arrays, start, stop, stride, agents)
            if format == "npz":
                return None
            size = traj.json_size_estimate(f, sel)
            if size > settings.max_json_bytes:
                raise ProblemError(
                    413, "slice-too-large", "Slice too large for JSON",
                    f"about {size} bytes as JSON, over the cap of {settings.max_json_bytes}; "
                    f"use format=npz, a stride, or fewer agents", estimated_bytes=size,
                    max_json_bytes=settings.max_json_bytes)
            return traj.to_json(f, sel)

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
               416: {}, **_ERRORS},
)
def trajectory_file(job_id: JobId, runtime: RuntimeDep) -> FileResponse:
    job, _ = _results_dir(runtime, job_id)
    path = runtime.results.file(job.id, "trajectory.h5")
    if not path.is_file():
        raise ProblemError(404, "no-trajectory", "No trajectory", "this job has no trajectory")
    headers = {}
    sums = json.loads(job.checksums) if job.checksums else {}
    if "trajectory.h5" in sums:
        digest = base64.b64encode(bytes.fromhex(sums["trajectory.h5"])).decode()
        headers["Repr-Digest"] = f"sha-256=:{digest}:"
    return FileResponse(path, media_type="application/x-hdf5", filename=f"{job.id}.h5",
                        headers=headers)
