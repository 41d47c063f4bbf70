"""/v1/jobs: submit, get (with long-poll), list, cancel, and follow progress as SSE."""

from __future__ import annotations

import base64
import json
from typing import Annotated

from fastapi import APIRouter, Header, Query, Request
from fastapi.responses import JSONResponse, StreamingResponse
from starlette.concurrency import run_in_threadpool

from flocklab.schemas import FieldError
from flocklab.schemas.status import JobList, JobState, JobView
from flocklab.service.jobs import IdempotencyConflict, NewJob, QueueFull

from ..admission import queue_full, queue_gauge
from ..deps import HubDep, JobId, RuntimeDep, SettingsDep, get_job
from ..follow import Until, cancel_row, event_stream, long_poll
from ..problems import ProblemError, invalid
from ..submission import parse_submission
from ..wire import EXAMPLE_SCENARIO, job_view

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
    if not runtime.supervisor.alive:
        raise ProblemError(503, "unavailable", "Service unavailable",
                           "the job supervisor is not running", headers={"Retry-After": "30"})
    raw = await request.body()
    sub = await run_in_threadpool(parse_submission, raw, settings)
    new = NewJob(scenario=sub.canonical, model_kind=sub.scenario.model.kind,
                 n_agents=sub.scenario.n_agents, steps_total=sub.scenario.time.steps,
                 timeout_seconds=sub.timeout_seconds, request_hash=sub.request_hash,
                 idempotency_key=idempotency_key)
    try:
        job, created = await run_in_threadpool(runtime.store.insert, new,
                                               max_queued=settings.max_queued)
    except QueueFull as exc:
        gauge = queue_gauge(request.app)
        assert gauge is not None  # the runtime exists: the store just answered
        body, headers = queue_full(exc.queued, settings.max_queued, gauge)
        raise ProblemError(429, "queue-full", body["title"], body["detail"],
                           headers=headers, retry_after_seconds=body["retry_after_seconds"]
                           ) from None
    except IdempotencyConflict as exc:
        raise ProblemError(409, "idempotency-conflict", "Idempotency key reused",
                           f"this Idempotency-Key was used for job {exc.job_id} with a "
                           f"different request", job_id=exc.job_id) from None
    if created:
        runtime.supervisor.wake()
    view = job_view(job, settings.result_ttl_seconds)
    headers = {"Location": view.links["self"]}
    if not created:
        headers["Idempotent-Replayed"] = "true"
    return JSONResponse(view.model_dump(mode="json"), status_code=202, headers=headers)


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
    jobs = runtime.store.list(statuses=status or (), model_kind=model,
                              before_seq=_decode_cursor(cursor), limit=limit)
    next_cursor = _encode_cursor(jobs[-1].seq) if len(jobs) == limit else None
    return JobList(items=[job_view(j, settings.result_ttl_seconds) for j in jobs],
                   next_cursor=next_cursor)


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
    job = await long_poll(hub, str(job_id), lambda: get_job(runtime, job_id), wait, until)
    return job_view(job, settings.result_ttl_seconds)


@router.post("/{job_id}/cancel", status_code=202, response_model=JobView,
             summary="Cancel a job",
             description="A queued job is cancelled at once; a running one is asked to stop "
             "and is killed if it has not stopped after the grace period (cancelling it "
             "again while it stops is a no-op). A finished job (succeeded, failed, "
             "cancelled or timed out) gives 409 `job-finished` with `status_now`.",
             responses={401: {}, 404: {}, 409: {}, 422: {}})
def cancel(job_id: JobId, runtime: RuntimeDep, settings: SettingsDep) -> JobView:
    job = cancel_row(runtime, lambda: get_job(runtime, job_id), "job")
    return job_view(job, settings.result_ttl_seconds)


@router.get("/{job_id}/events", summary="Follow a job as Server-Sent Events",
            response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {"schema": {"type": "string"}},
                                         "application/json": None},
                             "description": "`event: job` with the job as JSON on every "
                             "change; `event: end` after the job finished."},
                       401: {}, 404: {}, 422: {}})
async def events(job_id: JobId, runtime: RuntimeDep, settings: SettingsDep, hub: HubDep
                 ) -> StreamingResponse:
    await run_in_threadpool(get_job, runtime, job_id)
    return event_stream(hub, str(job_id), lambda: get_job(runtime, job_id),
                        lambda j: job_view(j, settings.result_ttl_seconds), "job")


def _encode_cursor(seq: int) -> str:
    return base64.urlsafe_b64encode(json.dumps({"before": seq}).encode()).decode().rstrip("=")


def _decode_cursor(cursor: str | None) -> int | None:
    if cursor is None:
        return None
    try:
        data = json.loads(base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)))
        seq = data["before"]
        # SQLite integers are 64-bit: a larger one is an OverflowError, not a row.
        if not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq < 2**63:
            raise ValueError
        return seq
    except (ValueError, KeyError, TypeError):
        raise invalid([FieldError(loc="query.cursor", msg="not a cursor this service issued",
                                  type="value_error")]) from None

