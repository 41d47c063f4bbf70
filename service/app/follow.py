"""Reading and following rows of the job store over HTTP, the same for jobs and sweeps:
the pages of `GET …` (newest first, with a cursor), the long-poll of `GET …/{id}?wait=`,
the Server-Sent Events of `…/events`, and the cancel that answers 409 for a finished row.

Each takes the row's `kind` ("job", "sweep"): `deps.get_job` reads the row (a 404 for
another kind's id), `views.VIEWS[kind]` renders it; `hub` wakes waiters whenever the
supervisor changes the row.
"""

from __future__ import annotations

import base64
import json
import time
import uuid
from collections.abc import AsyncIterator, Sequence
from typing import Any, Literal

from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from flocklab.schemas import FieldError
from flocklab.schemas.status import LifecycleView
from flocklab.service.jobs import Job, JobRuntime

from .deps import get_job
from .events import ChangeHub, wait_for_change
from .problems import ProblemError, invalid
from .settings import Settings
from .views import VIEWS

SSE_KEEPALIVE_SECONDS = 15.0
Until = Literal["finished", "change"]


def list_page(kind: str, runtime: JobRuntime, settings: Settings, statuses: Sequence[str],
              limit: int, cursor: str | None, model: str | None = None
              ) -> tuple[list[LifecycleView], str | None]:
    """One page of the rows of `kind`, newest first, and the cursor of the next page
    (None on the last one)."""
    rows = runtime.store.list(statuses=statuses, model_kind=model,
                              before_seq=_decode_cursor(cursor), limit=limit, kind=kind)
    next_cursor = _encode_cursor(rows[-1].seq) if len(rows) == limit else None
    return [VIEWS[kind](j, settings.result_ttl_seconds) for j in rows], next_cursor


async def long_poll(kind: str, row_id: uuid.UUID, runtime: JobRuntime, settings: Settings,
                    hub: ChangeHub, wait: float, until: Until) -> LifecycleView:
    """The row once it has finished (`until="change"`: at its first change), or as it is
    after `wait` seconds; at once when the server is shutting down."""

    def load() -> Job:
        return get_job(runtime, row_id, kind)

    with hub.subscribe(str(row_id)) as changed:
        job = await run_in_threadpool(load)
        deadline = time.monotonic() + wait
        while not job.terminal and not hub.closing:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not await wait_for_change(changed, remaining):
                break
            job = await run_in_threadpool(load)
            if until == "change":
                break
    return VIEWS[kind](job, settings.result_ttl_seconds)


async def event_stream(kind: str, row_id: uuid.UUID, runtime: JobRuntime,
                       settings: Settings, hub: ChangeHub) -> StreamingResponse:
    """`event: <kind>` with the row on every change, `event: end` once it finished,
    `event: shutdown` when the server stops (reconnect later), keep-alives between; a
    404 before the stream starts when there is no such row."""
    await run_in_threadpool(get_job, runtime, row_id, kind)

    async def stream() -> AsyncIterator[str]:
        last = None
        with hub.subscribe(str(row_id)) as changed:
            while True:
                job = await run_in_threadpool(get_job, runtime, row_id, kind)
                body = VIEWS[kind](job, settings.result_ttl_seconds).model_dump_json()
                if body != last:
                    last = body
                    yield f"event: {kind}\ndata: {body}\n\n"
                if job.terminal:
                    yield "event: end\ndata: {}\n\n"
                    return
                if hub.closing:
                    yield "event: shutdown\ndata: {}\n\n"
                    return
                if not await wait_for_change(changed, SSE_KEEPALIVE_SECONDS):
                    yield f": keep-alive {time.time():.0f}\n\n"

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})


def cancel_row(kind: str, row_id: uuid.UUID, runtime: JobRuntime, settings: Settings
               ) -> LifecycleView:
    """Cancel a queued row at once or ask its worker to stop; a row that had finished
    before (or, racing this request, finished by other means) is a 409 `<kind>-finished`."""
    before = get_job(runtime, row_id, kind)
    job: Any = before
    if not before.terminal:
        job = runtime.store.request_cancel(before.id)
        assert job is not None
    if before.terminal or (job.terminal and job.status != "cancelled"):
        raise ProblemError(409, f"{kind}-finished", f"{kind.capitalize()} already finished",
                           f"the {kind} is {job.status}; it can no longer be cancelled",
                           status_now=job.status)
    if job.status == "running":
        runtime.supervisor.cancel(job.id)
    return VIEWS[kind](job, settings.result_ttl_seconds)


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

