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
# Job starts over this window measure the drain rate.
RATE_WINDOW_SECONDS = 60.0
# Recent starts read to measure it (the newest jobs by sequence number).
RATE_SAMPLE = 256
RETRY_AFTER_MIN, RETRY_AFTER_MAX = 1, 600
# Retry-After when no job started within the window (a long job holds every worker).
RETRY_AFTER_UNMEASURED = 60


class QueueGauge:
    """Thread-safe; opens its read-only connection on first use."""

    def __init__(self, db_path: Path):
        self._path = db_path
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
        """Jobs started per second over the last RATE_WINDOW_SECONDS; None when none did."""
        with self._lock:
            now = time.monotonic()
            if now - self._rate[0] >= RATE_TTL_SECONDS:
                self._rate = (now, self._measure())
            return self._rate[1]

    def _measure(self) -> float | None:
        # Jobs start in sequence order, so the newest starts are among the newest rows.
        rows = self._conn().execute(
            "SELECT started_at FROM jobs WHERE started_at IS NOT NULL ORDER BY seq DESC "
            "LIMIT ?", (RATE_SAMPLE,)).fetchall()
        wall = time.time()
        starts = sorted(t for (t,) in rows if t >= wall - RATE_WINDOW_SECONDS)
        if not starts:
            return None
        span = max(1.0, wall - starts[0])
        return len(starts) / span

    def retry_after(self, queued: int) -> int:
        """Seconds until the `queued` jobs now waiting have started, at the measured rate."""
        rate = self.drain_rate()
        if rate is None:
            return RETRY_AFTER_UNMEASURED
        return int(min(RETRY_AFTER_MAX, max(RETRY_AFTER_MIN, math.ceil(queued / rate))))
