"""Job-change notifications from the supervisor thread to waiting requests.

Long-polls (`GET /v1/jobs/{id}?wait=`) and Server-Sent Events wait on an asyncio.Event
that the supervisor sets (through the event loop) whenever it changes that job, instead
of polling the store.

On shutdown (SIGTERM) `close` wakes every waiter at once: a long-poll answers the job as
it is and a stream ends, so the server need not wait out its grace period for them (and
then cancel them into 500s).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager


class ChangeHub:
    def __init__(self, loop: asyncio.AbstractEventLoop):
        self._loop = loop
        self._waiters: defaultdict[str, set[asyncio.Event]] = defaultdict(set)
        self.closing = False

    def publish_threadsafe(self, job_id: str) -> None:
        """Called from the supervisor thread."""
        # A closed loop means the service is shutting down: nobody is waiting.
        with contextlib.suppress(RuntimeError):
            self._loop.call_soon_threadsafe(self._fire, job_id)

    def publish(self, job_id: str) -> None:
        """Called on the event loop (e.g. after a cancel request)."""
        self._fire(job_id)

    def _fire(self, job_id: str) -> None:
        for event in self._waiters.get(job_id, ()):
            event.set()

    def close_threadsafe(self) -> None:
        """The server is shutting down: release every waiter, now and from now on."""
        with contextlib.suppress(RuntimeError):
            self._loop.call_soon_threadsafe(self._close)

    def _close(self) -> None:
        self.closing = True
        for events in self._waiters.values():
            for event in events:
                event.set()

    @contextmanager
    def subscribe(self, job_id: str) -> Iterator[asyncio.Event]:
        """An event set on every change of the job while the block runs. Subscribe before
        reading the job's state, so no change falls between the read and the wait."""
        event = asyncio.Event()
        if self.closing:
            event.set()
        self._waiters[job_id].add(event)
        try:
            yield event
        finally:
            waiters = self._waiters[job_id]
            waiters.discard(event)
            if not waiters:
                del self._waiters[job_id]


async def wait_for_change(event: asyncio.Event, timeout: float) -> bool:
    """True when the event fired within `timeout` seconds (and re-arm it)."""
    try:
        await asyncio.wait_for(event.wait(), timeout)
    except asyncio.TimeoutError:
        return False
    event.clear()
    return True
