"""Following a row of the job store over HTTP, the same for jobs and sweeps: the
long-poll of `GET …/{id}?wait=`, the Server-Sent Events of `…/events`, and the cancel
that answers 409 for a finished row.

`load(id)` reads the row (raising the route's 404), `view(row)` renders it; `hub` wakes
waiters whenever the supervisor changes the row.
"""

from __future__ import annotations

import time
from collections.abc import AsyncIterator, Callable
from typing import Any, Literal

from fastapi.responses import StreamingResponse
from pydantic import BaseModel
from starlette.concurrency import run_in_threadpool

from flocklab.service.jobs import Job, JobRuntime

from .events import ChangeHub, wait_for_change
from .problems import ProblemError

SSE_KEEPALIVE_SECONDS = 15.0
Until = Literal["finished", "change"]


async def long_poll(hub: ChangeHub, key: str, load: Callable[[], Job], wait: float,
                    until: Until) -> Job:
    """The row once it has finished (`until="change"`: at its first change), or as it is
    after `wait` seconds; at once when the server is shutting down."""
    with hub.subscribe(key) as changed:
        job = await run_in_threadpool(load)
        deadline = time.monotonic() + wait
        while not job.terminal and not hub.closing:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not await wait_for_change(changed, remaining):
                break
            job = await run_in_threadpool(load)
            if until == "change":
                break
    return job


def event_stream(hub: ChangeHub, key: str, load: Callable[[], Job],
                 view: Callable[[Job], BaseModel], name: str) -> StreamingResponse:
    """`event: <name>` with the row on every change, `event: end` once it finished,
    `event: shutdown` when the server stops (reconnect later), keep-alives between."""

    async def stream() -> AsyncIterator[str]:
        last = None
        with hub.subscribe(key) as changed:
            while True:
                job = await run_in_threadpool(load)
                body = view(job).model_dump_json()
                if body != last:
                    last = body
                    yield f"event: {name}\ndata: {body}\n\n"
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


def cancel_row(runtime: JobRuntime, load: Callable[[], Job], noun: str) -> Job:
    """Cancel a queued row at once or ask its worker to stop; a row that had finished
    before (or, racing this request, finished by other means) is a 409 `<noun>-finished`."""
    before = load()
    job: Any = before
    if not before.terminal:
        job = runtime.store.request_cancel(before.id)
        assert job is not None
    if before.terminal or (job.terminal and job.status != "cancelled"):
        raise ProblemError(409, f"{noun}-finished", f"{noun.capitalize()} already finished",
                           f"the {noun} is {job.status}; it can no longer be cancelled",
                           status_now=job.status)
    if job.status == "running":
        runtime.supervisor.cancel(job.id)
    return job
