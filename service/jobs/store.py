"""The job store: one SQLite file, the single source of truth for every job's state.

Durability (R1): WAL journal with synchronous=FULL, so a commit has reached the disk
before `insert` returns and the API answers 202. Every state change is a conditional
UPDATE (`WHERE status = ...`, and for running jobs `AND lease_token = ...`), so terminal
states are final (R4) and only the holder of an attempt's lease can finish it (R5).

One connection guarded by a lock: the API's threads and the supervisor thread share it.
Writes are short transactions, so the lock is held for milliseconds.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
import uuid
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from flocklab.schemas.problems import json_safe
from flocklab.schemas.status import STATES, TERMINAL_STATES

_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS jobs (
    seq              INTEGER PRIMARY KEY AUTOINCREMENT,
    id               TEXT NOT NULL UNIQUE,
    status           TEXT NOT NULL CHECK (status IN ({", ".join(repr(s) for s in STATES)})),
    scenario         TEXT NOT NULL,
    model_kind       TEXT NOT NULL,
    n_agents         INTEGER NOT NULL,
    steps_total      INTEGER NOT NULL,
    steps_done       INTEGER NOT NULL DEFAULT 0,
    timeout_seconds  REAL NOT NULL,
    idempotency_key  TEXT UNIQUE,
    request_hash     TEXT NOT NULL,
    created_at       REAL NOT NULL,
    started_at       REAL,
    finished_at      REAL,
    attempts         INTEGER NOT NULL DEFAULT 0,
    lease_owner      TEXT,
    lease_token      TEXT,
    lease_expires    REAL,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    backend          TEXT,
    error            TEXT,
    has_results      INTEGER NOT NULL DEFAULT 0,
    results_expired  INTEGER NOT NULL DEFAULT 0,
    checksums        TEXT
);
CREATE INDEX IF NOT EXISTS jobs_by_status ON jobs (status, seq);
"""

# Columns added after the first release, each with a default that describes the rows
# written before it: a data directory made by an older version still opens (no migration
# step), its rows reading as plain jobs. Added only when missing (SQLite has no
# ADD COLUMN IF NOT EXISTS).
#   kind         'job' (one scenario) or 'sweep' (a parameter sweep: `scenario` holds the
#                canonical sweep, steps_total its runs, steps_done the runs that ended)
#   runs_failed  a sweep's runs that ended without measures so far (diverged)
#   resumed_from_step  the checkpoint's step the latest attempt went on from (a job whose
#                worker was lost; NULL: it ran from step 0)
#   resumed_runs a sweep's runs the latest attempt continued from their checkpoints: a
#                JSON object, run index -> the checkpoint's step (NULL: none)
_ADDED_COLUMNS = {
    "kind": "TEXT NOT NULL DEFAULT 'job'",
    "runs_failed": "INTEGER NOT NULL DEFAULT 0",
    "resumed_from_step": "INTEGER",
    "resumed_runs": "TEXT",
}


class QueueFull(Exception):
    """The queue already holds the configured maximum of waiting jobs."""

    def __init__(self, queued: int):
        self.queued = queued
        super().__init__(f"{queued} jobs are already queued")


class IdempotencyConflict(Exception):
    """An Idempotency-Key was reused with a different request body."""

    def __init__(self, job_id: str):
        self.job_id = job_id
        super().__init__(f"the key was already used for job {job_id} with another body")


@dataclass(frozen=True)
class Job:
    """One row of the jobs table."""

    seq: int
    id: str
    status: str
    scenario: str
    model_kind: str
    n_agents: int
    steps_total: int
    steps_done: int
    timeout_seconds: float
    idempotency_key: str | None
    request_hash: str
    created_at: float
    started_at: float | None
    finished_at: float | None
    attempts: int
    lease_owner: str | None
    lease_token: str | None
    lease_expires: float | None
    cancel_requested: int
    backend: str | None
    error: str | None
    has_results: int
    results_expired: int
    checksums: str | None
    kind: str = "job"
    runs_failed: int = 0
    resumed_from_step: int | None = None
    resumed_runs: str | None = None

    @property
    def terminal(self) -> bool:
        return self.status in TERMINAL_STATES

    @property
    def problem(self) -> dict[str, Any] | None:
        return json.loads(self.error) if self.error else None


@dataclass(frozen=True)
class NewJob:
    """What the API stores for a submission."""

    scenario: str
    model_kind: str
    n_agents: int
    steps_total: int
    timeout_seconds: float
    request_hash: str
    idempotency_key: str | None = None
    kind: str = "job"


class JobStore:
    """SQLite-backed job table. Thread-safe; every method is one short transaction."""

    def __init__(self, path: Path):
        self.path = path
        self._lock = threading.RLock()
        # isolation_level=None: we issue BEGIN IMMEDIATE ourselves, so a read-then-write
        # (queue count + insert, select + claim) cannot interleave with another writer.
        self._db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute("PRAGMA busy_timeout=10000")
        self._db.executescript(_SCHEMA)
        self._add_missing_columns()

    def _add_missing_columns(self) -> None:
        with self._tx() as db:
            have = {r["name"] for r in db.execute("PRAGMA table_info(jobs)")}
            for name, ddl in _ADDED_COLUMNS.items():
                if name not in have:
                    db.execute(f"ALTER TABLE jobs ADD COLUMN {name} {ddl}")
            db.execute("CREATE INDEX IF NOT EXISTS jobs_by_kind ON jobs (kind, seq)")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")

    def _one(self, sql: str, args: Iterable[Any] = ()) -> Job | None:
        with self._lock:
            row = self._db.execute(sql, tuple(args)).fetchone()
        return Job(**row) if row else None

    # -- submission -------------------------------------------------------------------

    def insert(self, new: NewJob, *, max_queued: int) -> tuple[Job, bool]:
        """Store a queued job; committed to disk on return. Returns (job, created).

        With an idempotency key already used for the same request, returns the existing
        job and created=False; with another request, raises IdempotencyConflict. Raises
        QueueFull when `max_queued` jobs are waiting.
        """
        with self._tx() as db:
            if new.idempotency_key is not None:
                row = db.execute(
                    "SELECT * FROM jobs WHERE idempotency_key = ?", (new.idempotency_key,)
                ).fetchone()
                if row is not None:
                    if row["request_hash"] != new.request_hash:
                        raise IdempotencyConflict(row["id"])
                    return Job(**row), False
            queued = db.execute("SELECT COUNT(*) FROM jobs WHERE status = 'queued'").fetchone()[0]
            if queued >= max_queued:
                raise QueueFull(queued)
            job_id = str(uuid.uuid4())
            db.execute(
                "INSERT INTO jobs (id, status, scenario, model_kind, n_agents, steps_total,"
                " timeout_seconds, idempotency_key, request_hash, created_at, kind)"
                " VALUES (?, 'queued', ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (job_id, new.scenario, new.model_kind, new.n_agents, new.steps_total,
                 new.timeout_seconds, new.idempotency_key, new.request_hash, time.time(),
                 new.kind),
            )
            row = db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return Job(**row), True

    # -- reads -------------------------------------------------------------------------

    def get(self, job_id: str) -> Job | None:
        return self._one("SELECT * FROM jobs WHERE id = ?", (job_id,))

    def list(
        self,
        *,
        statuses: Iterable[str] = (),
        model_kind: str | None = None,
        before_seq: int | None = None,
        limit: int = 50,
        kind: str = "job",
    ) -> list[Job]:
        """Newest first; `before_seq` pages backwards from a previous page's last job.
        Jobs and sweeps are listed apart (`kind`)."""
        where, args = ["kind = ?"], [kind]
        statuses = list(statuses)
        if statuses:
            where.append(f"status IN ({', '.join('?' * len(statuses))})")
            args += statuses
        if model_kind is not None:
            where.append("model_kind = ?")
            args.append(model_kind)
        if before_seq is not None:
            where.append("seq < ?")
            args.append(before_seq)
        sql = "SELECT * FROM jobs WHERE " + " AND ".join(where)
        sql += " ORDER BY seq DESC LIMIT ?"
        args.append(limit)
        with self._lock:
            return [Job(**r) for r in self._db.execute(sql, args).fetchall()]

    def count(self, status: str) -> int:
        with self._lock:
            return self._db.execute(
                "SELECT COUNT(*) FROM jobs WHERE status = ?", (status,)
            ).fetchone()[0]

    # -- the supervisor's transitions ---------------------------------------------------

    def claim_next(self, owner: str, lease_seconds: float) -> Job | None:
        """Move the oldest queued job to running under a fresh lease, or return None."""
        now = time.time()
        with self._tx() as db:
            row = db.execute(
                "SELECT id FROM jobs WHERE status = 'queued' ORDER BY seq LIMIT 1"
            ).fetchone()
            if row is None:
                return None
            db.execute(
                "UPDATE jobs SET status = 'running', attempts = attempts + 1,"
                " lease_owner = ?, lease_token = ?, lease_expires = ?,"
                " started_at = ?, steps_done = 0, resumed_from_step = NULL, resumed_runs = NULL"
                " WHERE id = ? AND status = 'queued'",
                (owner, uuid.uuid4().hex, now + lease_seconds, now, row["id"]),
            )
            claimed = db.execute("SELECT * FROM jobs WHERE id = ?", (row["id"],)).fetchone()
        return Job(**claimed)

    def renew_leases(self, owner: str, tokens: Iterable[str], lease_seconds: float) -> None:
        """Heartbeat: extend the leases of the attempts this supervisor is running."""
        tokens = list(tokens)
        if not tokens:
            return
        with self._tx() as db:
            db.execute(
                f"UPDATE jobs SET lease_expires = ? WHERE status = 'running' AND lease_owner = ?"
                f" AND lease_token IN ({', '.join('?' * len(tokens))})",
                (time.time() + lease_seconds, owner, *tokens),
            )

    def set_progress(self, job_id: str, token: str, steps_done: int,
                     runs_failed: int | None = None) -> None:
        with self._tx() as db:
            db.execute(
                "UPDATE jobs SET steps_done = ?, runs_failed = COALESCE(?, runs_failed)"
                " WHERE id = ? AND status = 'running' AND lease_token = ?",
                (steps_done, runs_failed, job_id, token),
            )

    def set_resumed(self, job_id: str, token: str, step: int | None) -> None:
        """Record that the running attempt went on from its predecessor's checkpoint at
        `step` (None: it was refused, the attempt runs from step 0)."""
        with self._tx() as db:
            db.execute(
                "UPDATE jobs SET resumed_from_step = ?, steps_done = COALESCE(?, 0)"
                " WHERE id = ? AND status = 'running' AND lease_token = ?",
                (step, step, job_id, token),
            )

    def set_run_resumed(self, job_id: str, token: str, run: int, step: int | None) -> None:
        """Record that the running attempt of a sweep continues its run `run` from the
        run's checkpoint at `step` (None: refused after all, the run starts over)."""
        with self._tx() as db:
            row = db.execute("SELECT resumed_runs FROM jobs WHERE id = ? AND status = "
                             "'running' AND lease_token = ?", (job_id, token)).fetchone()
            if row is None:
                return
            runs = json.loads(row["resumed_runs"] or "{}")
            if step is None:
                runs.pop(str(run), None)
            else:
                runs[str(run)] = step
            db.execute("UPDATE jobs SET resumed_runs = ? WHERE id = ? AND lease_token = ?",
                       (json.dumps(runs, sort_keys=True) if runs else None, job_id, token))

    def finish(
        self,
        job_id: str,
        token: str,
        status: str,
        *,
        error: dict[str, Any] | None = None,
        backend: str | None = None,
        has_results: bool = False,
        checksums: dict[str, str] | None = None,
        steps_done: int | None = None,
        runs_failed: int | None = None,
    ) -> bool:
        """Make a running attempt terminal. False when the lease is no longer held."""
        assert status in TERMINAL_STATES
        with self._tx() as db:
            cur = db.execute(
                "UPDATE jobs SET status = ?, finished_at = ?, error = ?, backend = ?,"
                " has_results = ?, checksums = ?, steps_done = COALESCE(?, steps_done),"
                " runs_failed = COALESCE(?, runs_failed),"
                " lease_owner = NULL, lease_token = NULL, lease_expires = NULL"
                " WHERE id = ? AND status = 'running' AND lease_token = ?",
                (status, time.time(), _dump(error), backend, int(has_results),
                 _dump(checksums), steps_done, runs_failed, job_id, token),
            )
        return cur.rowcount == 1

    def requeue(self, job_id: str, token: str, *, refund_attempt: bool, note: dict | None
                ) -> bool:
        """Put a running attempt back in the queue (infrastructure failure or shutdown).

        `refund_attempt` un-counts the attempt when the job was not at fault (a graceful
        shutdown); `note` keeps the last infrastructure problem visible on the job.
        """
        with self._tx() as db:
            cur = db.execute(
                "UPDATE jobs SET status = 'queued', attempts = attempts - ?, error = ?,"
                " steps_done = 0, lease_owner = NULL, lease_token = NULL, lease_expires = NULL"
                " WHERE id = ? AND status = 'running' AND lease_token = ?",
                (int(refund_attempt), _dump(note), job_id, token),
            )
        return cur.rowcount == 1

    def request_cancel(self, job_id: str) -> Job | None:
        """Cancel a queued job at once, or flag a running one for the supervisor.

        Returns the job as it is afterwards (None when unknown); terminal jobs are left
        as they are.
        """
        with self._tx() as db:
            db.execute(
                "UPDATE jobs SET status = 'cancelled', finished_at = ?, cancel_requested = 1"
                " WHERE id = ? AND status = 'queued'",
                (time.time(), job_id),
            )
            db.execute(
                "UPDATE jobs SET cancel_requested = 1 WHERE id = ? AND status = 'running'",
                (job_id,),
            )
            row = db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return Job(**row) if row else None

    def unfinished_ids(self, kind: str) -> set[str]:
        """Ids of the queued and running rows of a kind (a sweep's partial output is kept
        for them across restarts)."""
        with self._lock:
            rows = self._db.execute(
                "SELECT id FROM jobs WHERE kind = ? AND status IN ('queued', 'running')",
                (kind,)).fetchall()
        return {r["id"] for r in rows}

    def running(self) -> list[Job]:
        with self._lock:
            rows = self._db.execute("SELECT * FROM jobs WHERE status = 'running'").fetchall()
        return [Job(**r) for r in rows]

    def expire_results(self, older_than: float) -> list[str]:
        """Mark the results of jobs finished before `older_than` expired; returns their ids.

        Marked first, deleted by the caller after: a reader sees 410 rather than a
        half-deleted directory.
        """
        with self._tx() as db:
            rows = db.execute(
                "SELECT id FROM jobs WHERE has_results = 1 AND results_expired = 0"
                " AND finished_at < ?",
                (older_than,),
            ).fetchall()
            ids = [r["id"] for r in rows]
            db.executemany("UPDATE jobs SET results_expired = 1 WHERE id = ?",
                           [(i,) for i in ids])
        return ids


def _dump(value: Any) -> str | None:
    # json_safe: an engine error may carry a NaN it detected, which JSON cannot hold.
    return None if value is None else json.dumps(json_safe(value), allow_nan=False)
