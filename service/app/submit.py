"""The one submission path of both kinds: POST /v1/jobs and POST /v1/sweeps.

    body -> JSON object -> the kind's spec (`bodies`) -> finite numbers -> `admit`
         -> timeout -> the store (durable) -> 202 with `Location`
                                           | 429 queue full | 409 Idempotency-Key reused

The body is parsed here, not by FastAPI: FastAPI answers a body holding NaN or 1e400 with
a 500 (fastapi#459), and strict spec types (tuples) validate only from JSON. Pydantic's
JSON parser reads NaN/Infinity/1e400 as floats so that the spec's finite-number fields
name the offending field; `parse_json_strict` then refuses any non-finite number that no
field caught, so nothing non-finite is ever stored.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import pydantic_core
from fastapi import Request
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from flocklab.schemas import FieldError, Scenario, parse_json_strict
from flocklab.schemas.sweep import Sweep, SweepError
from flocklab.service.jobs import (
    IdempotencyConflict,
    JobRuntime,
    LimitError,
    NewJob,
    QueueFull,
    admit,
)

from .admission import queue_full, queue_gauge
from .bodies import read_job, read_sweep
from .problems import ProblemError, invalid
from .settings import Settings
from .views import VIEWS

# How each kind's body is read: (data, raw) -> (spec, requested timeout or None).
Reader = Callable[[dict[str, Any], bytes], tuple[Scenario | Sweep, float | None]]
READERS: dict[str, Reader] = {"job": read_job, "sweep": read_sweep}


def parse_submission(kind: str, raw: bytes, settings: Settings) -> NewJob:
    """The store's row for a body of `kind` (without its Idempotency-Key), once the body
    is valid and within this service's limits (else ProblemError: 400 not JSON, 422
    invalid or over a limit)."""
    try:
        data = pydantic_core.from_json(raw)
    except ValueError as exc:
        raise ProblemError(400, "malformed-json", "Malformed JSON", f"the body is not JSON: {exc}"
                           ) from None
    if not isinstance(data, dict):
        raise invalid([FieldError(loc="(root)", msg="the body must be a JSON object",
                                  type="object_type")])
    spec, timeout = READERS[kind](data, raw)
    try:
        parse_json_strict(raw)
    except ValueError as exc:
        raise invalid([FieldError(loc="(body)", msg=str(exc), type="finite_number")]) from None
    try:
        admitted = admit(spec, settings.limits())
    except SweepError as exc:  # an unknown path, a sweep's run whose scenario is invalid
        raise invalid(exc.errors) from None
    except LimitError as exc:
        raise ProblemError(422, "limit-exceeded", "Over this service's limits", str(exc),
                           errors=exc.errors, **exc.numbers) from None
    if timeout is None:
        timeout = settings.job_timeout_seconds
    elif timeout > settings.max_job_timeout_seconds:
        raise invalid([FieldError(
            loc="timeout_seconds", type="limit_exceeded",
            msg=f"exceeds this service's limit of {settings.max_job_timeout_seconds:g} s")])
    canonical = spec.model_dump_json()
    # A sweep's hash names its kind: a sweep and a job never share an idempotency hash.
    salt = "" if kind == "job" else f"{kind}\n"
    digest = hashlib.sha256(f"{salt}{canonical}\n{timeout!r}".encode()).hexdigest()
    return NewJob(scenario=canonical, model_kind=admitted.model_kind,
                  n_agents=admitted.n_agents, steps_total=admitted.steps_total,
                  timeout_seconds=timeout, request_hash=digest, kind=kind)


async def accept(kind: str, request: Request, runtime: JobRuntime, settings: Settings,
                 idempotency_key: str | None) -> JSONResponse:
    """Store a submission of `kind` durably and answer 202 with its view and `Location`
    (`Idempotent-Replayed: true` when the key named a stored one)."""
    if not runtime.supervisor.alive:
        raise ProblemError(503, "unavailable", "Service unavailable",
                           "the job supervisor is not running", headers={"Retry-After": "30"})
    raw = await request.body()
    new = replace(await run_in_threadpool(parse_submission, kind, raw, settings),
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
                           f"this Idempotency-Key was used for {kind} {exc.job_id} with a "
                           f"different request", job_id=exc.job_id) from None
    if created:
        runtime.supervisor.wake()
    view = VIEWS[kind](job, settings.result_ttl_seconds)
    headers = {"Location": view.links["self"]}
    if not created:
        headers["Idempotent-Replayed"] = "true"
    return JSONResponse(view.model_dump(mode="json"), status_code=202, headers=headers)
