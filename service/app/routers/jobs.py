"""/v1/jobs: submit, get (with long-poll), list, cancel, and follow progress as SSE."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Request
from fastapi.responses import JSONResponse, StreamingResponse

from flocklab.schemas.status import JobList, JobState, JobView

from ..bodies import EXAMPLE_SCENARIO
from ..deps import HubDep, JobId, RuntimeDep, SettingsDep
from ..follow import Until, cancel_row, event_stream, list_page, long_poll
from ..submit import accept

router = APIRouter(prefix="/jobs", tags=["jobs"])


@router.post(
    "",
    status_code=202,
    response_model=JobView,
    summary="Submit a scenario or a preset",
    description="Stores the job durably, then answers 202 with a `Location` header. The "
    "body is a `JobRequest` or a bare `Scenario`. With an `Idempotency-Key`, repeating "
    "the same request returns the same job; another body with the same key is a 409.",
    responses={400: {}, 401: {}, 409: {}, 413: {}, 422: {}, 429: {}, 503: {}},
    openapi_extra={"requestBody": {"required": True, "content": {"application/json": {
        "schema": {"oneOf": [{"$ref": "#/components/schemas/JobRequest"},
                             {"$ref": "#/components/schemas/Scenario"}]},
        "examples": {
            "scenario": {"summary": "A full scenario", "value": {"scenario": EXAMPLE_SCENARIO}},
            "preset": {"summary": "A preset with overrides", "value": {
                "preset": "vicsek-1995", "overrides": {"initial": {"N": 1000}}}},
            "bare": {"summary": "A bare scenario", "value": EXAMPLE_SCENARIO},
        }}}}},
)
async def submit(
    request: Request,
    runtime: RuntimeDep,
    settings: SettingsDep,
    idempotency_key: Annotated[str | None, Header(
        alias="Idempotency-Key", min_length=1, max_length=200, pattern=r"^[\x21-\x7e]+$",
        description="Any unique string; retries with the same key return the same job.",
    )] = None,
) -> JSONResponse:
    return await accept("job", request, runtime, settings, idempotency_key)


@router.get("", response_model=JobList, summary="List jobs, newest first",
            responses={401: {}, 422: {}})
def list_jobs(
    runtime: RuntimeDep,
    settings: SettingsDep,
    status: Annotated[list[JobState] | None, Query(description="Only these statuses.")] = None,
    model: Annotated[str | None, Query(max_length=100, description="Only this model kind.")
                     ] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    cursor: Annotated[str | None, Query(max_length=64, description="From `next_cursor`.")
                      ] = None,
) -> JobList:
    items, next_cursor = list_page("job", runtime, settings, status or (), limit, cursor,
                                   model)
    return JobList(items=items, next_cursor=next_cursor)


@router.get("/{job_id}", response_model=JobView, summary="Get a job",
            description="With `wait`, a long-poll: the answer comes when the job has "
            "finished, or after `wait` seconds with the job as it is then. With "
            "`until=change` it comes at the job's first change (status or progress) "
            "instead: what a progress display polls with.",
            responses={401: {}, 404: {}, 422: {}})
async def get_job_route(
    job_id: JobId,
    runtime: RuntimeDep,
    settings: SettingsDep,
    hub: HubDep,
    wait: Annotated[float, Query(ge=0, le=60, description=(
        "Long-poll: answer as soon as the job is finished (or, with until=change, as soon "
        "as it changes), or after this many seconds."))] = 0,
    until: Annotated[Until, Query(description=(
        "What a long-poll waits for: the job's end (default) or its next change."))
    ] = "finished",
) -> JobView:
    return await long_poll("job", job_id, runtime, settings, hub, wait, until)


@router.post("/{job_id}/cancel", status_code=202, response_model=JobView,
             summary="Cancel a job",
             description="A queued job is cancelled at once; a running one is asked to stop "
             "and is killed if it has not stopped after the grace period (cancelling it "
             "again while it stops is a no-op). A finished job (succeeded, failed, "
             "cancelled or timed out) gives 409 `job-finished` with `status_now`.",
             responses={401: {}, 404: {}, 409: {}, 422: {}})
def cancel(job_id: JobId, runtime: RuntimeDep, settings: SettingsDep) -> JobView:
    return cancel_row("job", job_id, runtime, settings)


@router.get("/{job_id}/events", summary="Follow a job as Server-Sent Events",
            response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {"schema": {"type": "string"}},
                                         "application/json": None},
                             "description": "`event: job` with the job as JSON on every "
                             "change; `event: end` after the job finished."},
                       401: {}, 404: {}, 422: {}})
async def events(job_id: JobId, runtime: RuntimeDep, settings: SettingsDep, hub: HubDep
                 ) -> StreamingResponse:
    return await event_stream("job", job_id, runtime, settings, hub)
