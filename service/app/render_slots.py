"""Who draws when: render slots shared fairly between clients.

A draw is a child process for up to RENDER_TIMEOUT_SECONDS; the service draws at most
`total` at once (`render_slots`). With one queue for all, a client asking for many new
pictures (a movie per option set) held every slot and everyone else waited behind it.
Each client (peer IP address) now has `per_client` slots of its own
(`render_slots_per_client`): its further draws wait on its own queue, not the shared one,
so with `total > per_client` another client's draw starts as soon as one of the remaining
slots is free, however many draws the first one has asked for.

Retry-After for a draw that could not be made is measured like the job queue's: the draws
waiting for a slot, times the mean time of the recent draws, over the slots.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

RECENT_DRAWS = 32
RETRY_AFTER_MIN, RETRY_AFTER_MAX = 1, 600


class RenderSlots:
    """Use on one event loop (the API's)."""

    def __init__(self, total: int, per_client: int):
        self.total = total
        self.per_client = min(per_client, total)
        self._shared = asyncio.Semaphore(total)
        self._clients: dict[str, tuple[asyncio.Semaphore, int]] = {}
        self._recent: deque[float] = deque(maxlen=RECENT_DRAWS)
        self.waiting = 0  # draws waiting for a shared slot (each client's first ones)

    @asynccontextmanager
    async def slot(self, client: str) -> AsyncIterator[None]:
        """Hold one of `client`'s slots and one shared slot while drawing."""
        own, users = self._clients.get(client) or (asyncio.Semaphore(self.per_client), 0)
        self._clients[client] = (own, users + 1)
        try:
            async with own:
                self.waiting += 1
                try:
                    await self._shared.acquire()
                finally:
                    self.waiting -= 1
                started = time.monotonic()
                try:
                    yield
                finally:
                    self._shared.release()
                    self._recent.append(time.monotonic() - started)
        finally:
            own, users = self._clients[client]
            if users > 1:
                self._clients[client] = (own, users - 1)
            else:
                del self._clients[client]  # forget idle clients: the map stays small

    def retry_after(self) -> int:
        """Seconds until the draws waiting now (and one more) could have started."""
        mean = sum(self._recent) / len(self._recent) if self._recent else 1.0
        wait = (self.waiting + 1) * mean / self.total
        return int(min(RETRY_AFTER_MAX, max(RETRY_AFTER_MIN, math.ceil(wait))))
