"""/v1/sweeps: submit a parameter sweep, follow it, cancel it, fetch its tables.

A sweep is a row of the job store (kind 'sweep') run by the same supervisor and workers
as a job: stored durably before the 202, queued with the jobs (the same queue limit),
retried once when its worker is lost, continuing from the runs it had finished.
"""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, Header, Query, Request
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from starlette.concurrency import run_in_threadpool

from flocklab.schemas.status import SweepList, SweepState, SweepStatus
from flocklab.service.jobs import Job, JobRuntime
from flocklab.service.sweeps.tables import read_table

from ..bodies import EXAMPLE_SWEEP
from ..deps import HubDep, RuntimeDep, SettingsDep, get_job
from ..follow import Until, cancel_row, event_stream, list_page, long_poll
from ..problems import ProblemError
from ..submit import accept

router = APIRouter(prefix="/sweeps", tags=["sweeps"])

SweepId = Annotated[uuid.UUID, PathParam(description="The sweep's id (a UUID).",
                                         examples=["5d0c4a7e-2b1f-4f0e-9c1a-7e3d2b6a8f10"])]
_ERRORS: dict[int | str, dict] = {401: {}, 404: {}, 409: {}, 410: {}, 422: {}}
_CSV = "text/csv; charset=utf-8"


def _get(runtime: JobRuntime, sweep_id: uuid.UUID) -> Job:
    return get_job(runtime, sweep_id, kind="sweep")


@router.post(
    "",
    status_code=202,
    response_model=SweepStatus,
    summary="Submit a parameter sweep",
    description="Validates the sweep and every run it expands to (errors name the run and "
    "the field), checks this service's limits (runs per sweep, total agent-steps, and each "
    "run's own limits), stores it durably, then answers 202 with a `Location` header. The "
    "body is a `Sweep`, or a `SweepRequest` wrapping one with a `timeout_seconds`. With an "
    "`Idempotency-Key`, repeating the same request returns the same sweep; another body "
    "with the same key is a 409.",
    responses={400: {}, 401: {}, 409: {}, 413: {}, 422: {}, 429: {}, 503: {}},
    openapi_extra={"requestBody": {"required": True, "content": {"application/json": {
        "schema": {"oneOf": [{"$ref": "#/components/schemas/Sweep"},
                             {"$ref": "#/components/schemas/SweepRequest"}]},
        "examples": {
            "sweep": {"summary": "A sweep", "value": EXAMPLE_SWEEP},
            "wrapped": {"summary": "A sweep with a time limit",
                        "value": {"sweep": EXAMPLE_SWEEP, "timeout_seconds": 7200}},
        }}}}},
)
async def submit(
    request: Request,
    runtime: RuntimeDep,
    settings: SettingsDep,
    idempotency_key: Annotated[str | None, Header(
        alias="Idempotency-Key", min_length=1, max_length=200, pattern=r"^[\x21-\x7e]+$",
        description="Any unique string; retries with the same key return the same sweep.",
    )] = None,
) -> JSONResponse:
    return await accept("sweep", request, runtime, settings, idempotency_key)


@router.get("", response_model=SweepList, summary="List sweeps, newest first",
            responses={401: {}, 422: {}})
def list_sweeps(
    runtime: RuntimeDep,
    settings: SettingsDep,
    status: Annotated[list[SweepState] | None, Query(description="Only these statuses.")] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    cursor: Annotated[str | None, Query(max_length=64, description="From `next_cursor`.")
                      ] = None,
) -> SweepList:
    items, next_cursor = list_page("sweep", runtime, settings, status or (), limit, cursor)
    return SweepList(items=items, next_cursor=next_cursor)


@router.get("/{sweep_id}", response_model=SweepStatus, summary="Get a sweep",
            description="With `wait`, a long-poll: the answer comes when the sweep has "
            "finished, or after `wait` seconds with the sweep as it is then. With "
            "`until=change` it comes at its first change (status or runs done) instead.",
            responses={401: {}, 404: {}, 422: {}})
async def get_sweep(
    sweep_id: SweepId,
    runtime: RuntimeDep,
    settings: SettingsDep,
    hub: HubDep,
    wait: Annotated[float, Query(ge=0, le=60, description=(
        "Long-poll: answer as soon as the sweep is finished (or, with until=change, as "
        "soon as it changes), or after this many seconds."))] = 0,
    until: Annotated[Until, Query(description=(
        "What a long-poll waits for: the sweep's end (default) or its next change."))
    ] = "finished",
) -> SweepStatus:
    return await long_poll("sweep", sweep_id, runtime, settings, hub, wait, until)


@router.get("/{sweep_id}/spec", summary="The sweep as stored",
            description="The canonical sweep (every default filled in) that runs; submitting "
            "it again describes the same runs.",
            responses={200: {"content": {"application/json": {"schema": {
                "$ref": "#/components/schemas/Sweep"}}}}, 401: {}, 404: {}, 422: {}})
def spec(sweep_id: SweepId, runtime: RuntimeDep) -> Response:
    return Response(_get(runtime, sweep_id).scenario, media_type="application/json")


@router.post("/{sweep_id}/cancel", status_code=202, response_model=SweepStatus,
             summary="Cancel a sweep",
             description="A queued sweep is cancelled at once; a running one stops after "
             "its current runs, keeping the runs it finished (their table can be fetched); "
             "cancelling it again while it stops is a no-op. A finished sweep (succeeded, "
             "failed, cancelled or timed out) gives 409 `sweep-finished` with `status_now`.",
             responses={401: {}, 404: {}, 409: {}, 422: {}})
def cancel(sweep_id: SweepId, runtime: RuntimeDep, settings: SettingsDep) -> SweepStatus:
    return cancel_row("sweep", sweep_id, runtime, settings)


@router.get("/{sweep_id}/events", summary="Follow a sweep as Server-Sent Events",
            response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {"schema": {"type": "string"}},
                                         "application/json": None},
                             "description": "`event: sweep` with the sweep as JSON on every "
                             "change (runs done, status); `event: end` after it finished."},
                       401: {}, 404: {}, 422: {}})
async def events(sweep_id: SweepId, runtime: RuntimeDep, settings: SettingsDep, hub: HubDep
                 ) -> StreamingResponse:
    return await event_stream("sweep", sweep_id, runtime, settings, hub)


Format = Annotated[Literal["csv", "json"] | None, Query(
    description="csv or json; default: json when the Accept header asks for "
    "application/json, else csv.")]


def _table_route(name: str, summary: str, description: str) -> None:
    """Register GET /{sweep_id}/<name>: one of the sweep's CSV files, as CSV or JSON."""
    filename = f"{name}.csv"

    async def route(sweep_id: SweepId, runtime: RuntimeDep, request: Request,
                    format: Format = None) -> Response:
        job, folder = await run_in_threadpool(_results_dir, runtime, sweep_id)
        path = folder / filename
        if not path.is_file():
            raise ProblemError(404, "no-results", "No results",
                               f"the sweep ended ({job.status}) without a {filename}")
        if (format or _negotiate(request)) == "json":
            body = await run_in_threadpool(read_table, folder, "json", name)
            assert isinstance(body, dict)
            return JSONResponse({"sweep_id": job.id, **body})
        return FileResponse(path, media_type=_CSV, filename=f"{job.id}-{filename}")

    router.add_api_route(
        f"/{{sweep_id}}/{name}", route, methods=["GET"], summary=summary,
        description=description + " JSON: `{\"sweep_id\", \"columns\": [...], \"data\": "
        "[[...], ...]}`, numbers as numbers, axis values as in the sweep, empty cells (a "
        "missing value) as null.",
        response_class=Response, response_model=None, tags=["sweeps"],
        responses={200: {"content": {"text/csv": {"schema": {"type": "string"}},
                                     "application/json": {"schema": {"type": "object"}}}},
                   **_ERRORS})


def _negotiate(request: Request) -> str:
    """json when Accept names application/json before (or without) text/csv."""
    accept = request.headers.get("accept", "").lower()
    j, c = accept.find("application/json"), accept.find("text/csv")
    return "json" if j >= 0 and (c < 0 or j < c) else "csv"


def _results_dir(runtime: JobRuntime, sweep_id: uuid.UUID) -> tuple[Job, Path]:
    job = _get(runtime, sweep_id)
    if job.results_expired:
        raise ProblemError(410, "results-expired", "Results expired",
                           "this sweep's results were deleted after the retention period")
    if not job.has_results:
        if not job.terminal:
            raise ProblemError(409, "results-pending", "Results not ready",
                               f"the sweep is {job.status}", status_now=job.status)
        raise ProblemError(404, "no-results", "No results",
                           f"the sweep ended ({job.status}) without results")
    folder = runtime.results.job_dir(job.id)
    if not folder.is_dir():  # deleted under us by the expiry sweep
        raise ProblemError(410, "results-expired", "Results expired",
                           "this sweep's results were deleted after the retention period")
    return job, folder


_table_route("table", "The sweep's table: one row per grid point",
             "table.csv: the axes' values, then each measure's mean, sd, sem and count over "
             "the grid point's replicas.")
_table_route("runs", "The sweep's runs: one row per run",
             "runs.csv: run index, each axis path, replica, seed, status and every measure.")
_table_route("series", "The sweep's time series averaged over replicas",
             "series.csv: per grid point and observation step, the mean and sd over "
             "replicas of each observable named in the sweep's `series`.")
_table_route("sensitivity", "The sweep's sensitivity analysis",
             "sensitivity.csv (a sweep with an `analysis`, once every run has finished): "
             "per design parameter, Sobol' S1, S1_conf, ST, ST_conf or Morris mu, mu_star, "
             "sigma, mu_star_conf, then points and points_missing.")
