"""How full the queue is and how fast it drains, read cheaply enough to refuse a burst.

A refusal must not wait behind the acceptances: the store serializes its writes (each an
fsync'd transaction) behind one lock, so the gauge reads the SQLite file through a
connection of its own (WAL readers never wait for the writer) and caches what it read for
a moment, so a burst of a thousand submissions costs a handful of queries.
"""

from __future__ import annotations

import math
import sqlite3
import threading
import time
from pathlib import Path

QUEUED_TTL_SECONDS = 0.1
RATE_TTL_SECONDS = 1.0
# Recent jobs (and sweeps) read to measure how long one holds a worker: the newest
# finished rows by sequence number, plus the rows running now.
RATE_SAMPLE = 256
RETRY_AFTER_MIN, RETRY_AFTER_MAX = 1, 600


class QueueGauge:
    """Thread-safe; opens its read-only connection on first use. `workers` is how many
    jobs run at once (the supervisor's worker processes)."""

    def __init__(self, db_path: Path, workers: int = 1):
        self._path = db_path
        self._workers = max(1, workers)
        self._db: sqlite3.Connection | None = None
        self._lock = threading.Lock()
        self._queued: tuple[float, int] = (-math.inf, 0)
        self._rate: tuple[float, float | None] = (-math.inf, None)

    def _conn(self) -> sqlite3.Connection:
        if self._db is None:
            self._db = sqlite3.connect(f"file:{self._path}?mode=ro", uri=True,
                                       check_same_thread=False)
            self._db.execute("PRAGMA busy_timeout=1000")
        return self._db

    def queued(self) -> int:
        """Jobs waiting (at most QUEUED_TTL_SECONDS old)."""
        with self._lock:
            now = time.monotonic()
            if now - self._queued[0] >= QUEUED_TTL_SECONDS:
                n = self._conn().execute(
                    "SELECT COUNT(*) FROM jobs WHERE status = 'queued'").fetchone()[0]
                self._queued = (now, n)
            return self._queued[1]

    def drain_rate(self) -> float | None:
        """Queued jobs started per second while the workers are busy: workers / the mean
        time a recent job held a worker; None when no job has run yet."""
        with self._lock:
            now = time.monotonic()
            if now - self._rate[0] >= RATE_TTL_SECONDS:
                self._rate = (now, self._measure())
            return self._rate[1]

    def _measure(self) -> float | None:
        """workers / mean(seconds a job held a worker), over the newest finished jobs and
        the running ones (their time so far, a lower bound). Time with the workers idle
        does not count: a queue of 10 ms jobs drains at 100 per second per worker however
        long the service sat idle before it filled (counting starts per wall-clock window
        did, and said 60-427 s for a queue that drained in 2 s)."""
        wall = time.time()
        rows = self._conn().execute(
            "SELECT started_at, finished_at FROM jobs WHERE started_at IS NOT NULL AND "
            "finished_at IS NOT NULL ORDER BY seq DESC LIMIT ?", (RATE_SAMPLE,)).fetchall()
        rows += self._conn().execute(
            "SELECT started_at, NULL FROM jobs WHERE status = 'running' AND "
            "started_at IS NOT NULL").fetchall()
        held = [max(0.0, (end if end is not None else wall) - start) for start, end in rows]
        if not held:
            return None
        # A floor of 1 ms a job: a rate, never a division by zero.
        return self._workers / max(1e-3, sum(held) / len(held))

    def retry_after(self, queued: int) -> int:
        """Seconds until the `queued` jobs now waiting have started, at the measured rate
        (RETRY_AFTER_MIN when nothing has run yet: the workers are about to take them)."""
        rate = self.drain_rate()
        if rate is None:
            return RETRY_AFTER_MIN
        return int(min(RETRY_AFTER_MAX, max(RETRY_AFTER_MIN, math.ceil(queued / rate))))
