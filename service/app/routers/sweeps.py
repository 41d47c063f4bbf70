"""/v1/sweeps: submit a parameter sweep, follow it, cancel it, fetch its tables.

A sweep is a row of the job store (kind 'sweep') run by the same supervisor and workers
as a job: stored durably before the 202, queued with the jobs (the same queue limit),
retried once when its worker is lost, continuing from the runs it had finished. Its
submit, list, get, cancel and events routes are those of every kind (`resource`); this
module gives a sweep's names and words, and adds its spec and its tables.
"""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Request
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, JSONResponse, Response
from starlette.concurrency import run_in_threadpool

from flocklab.schemas.status import SweepList, SweepState, SweepStatus
from flocklab.service.jobs import Job, JobRuntime
from flocklab.service.sweeps.tables import read_table

from ..bodies import EXAMPLE_SWEEP
from ..deps import RuntimeDep, get_job, results_dir
from ..problems import ProblemError
from .resource import Resource, add_routes

router = APIRouter(prefix="/sweeps", tags=["sweeps"])

SweepId = Annotated[uuid.UUID, PathParam(description="The sweep's id (a UUID).",
                                         examples=["5d0c4a7e-2b1f-4f0e-9c1a-7e3d2b6a8f10"])]
_ERRORS: dict[int | str, dict] = {401: {}, 404: {}, 409: {}, 410: {}, 422: {}}
_CSV = "text/csv; charset=utf-8"


SWEEPS = Resource(
    kind="sweep", id_name="sweep_id", id_type=SweepId, state_type=SweepState,
    view=SweepStatus, page=SweepList, get_name="get_sweep",
    submit_summary="Submit a parameter sweep",
    submit_description="Validates the sweep and every run it expands to (errors name the "
    "run and the field), checks this service's limits (runs per sweep, total agent-steps, "
    "and each run's own limits), stores it durably, then answers 202 with a `Location` "
    "header. The body is a `Sweep`, or a `SweepRequest` wrapping one with a "
    "`timeout_seconds`. With an `Idempotency-Key`, repeating the same request returns the "
    "same sweep; another body with the same key is a 409.",
    body_schemas=("Sweep", "SweepRequest"),
    body_examples={
        "sweep": {"summary": "A sweep", "value": EXAMPLE_SWEEP},
        "wrapped": {"summary": "A sweep with a time limit",
                    "value": {"sweep": EXAMPLE_SWEEP, "timeout_seconds": 7200}},
    },
    get_description="With `wait`, a long-poll: the answer comes when the sweep has "
    "finished, or after `wait` seconds with the sweep as it is then. With `until=change` "
    "it comes at its first change (status or runs done) instead.",
    cancel_description="A queued sweep is cancelled at once; a running one stops after its "
    "current runs, keeping the runs it finished (their table can be fetched); cancelling "
    "it again while it stops is a no-op. A finished sweep (succeeded, failed, cancelled or "
    "timed out) gives 409 `sweep-finished` with `status_now`.",
    events_description="`event: sweep` with the sweep as JSON on every change (runs done, "
    "status); `event: end` after it finished.",
)
add_routes(router, SWEEPS)


def _get(runtime: JobRuntime, sweep_id: uuid.UUID) -> Job:
    return get_job(runtime, sweep_id, kind="sweep")


@router.get("/{sweep_id}/spec", summary="The sweep as stored",
            description="The canonical sweep (every default filled in) that runs; submitting "
            "it again describes the same runs.",
            responses={200: {"content": {"application/json": {"schema": {
                "$ref": "#/components/schemas/Sweep"}}}}, 401: {}, 404: {}, 422: {}})
def spec(sweep_id: SweepId, runtime: RuntimeDep) -> Response:
    return Response(_get(runtime, sweep_id).scenario, media_type="application/json")


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
    return results_dir(runtime, sweep_id, "sweep")


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
