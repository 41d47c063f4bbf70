"""One log line when a job starts and one when it ends (id, model, N, seconds, status).

The supervisor reports every change of a job through its `on_change` callback (start,
progress, end); `JobLog` wraps that callback, reads the job's row and logs the
transitions into and out of `running`, so every path that ends a job (a result, a
cancel, a timeout, a lost worker, a reaped lease) is logged without a line at each.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from .store import JobStore

log = logging.getLogger("flocklab.jobs")


class JobLog:
    """The supervisor's `on_change`, logging each attempt's start and end first."""

    def __init__(self, store: JobStore, on_change: Callable[[str], None]):
        self.store = store
        self.on_change = on_change
        self._running: dict[str, int] = {}  # job id -> the attempt logged as started

    def __call__(self, job_id: str) -> None:
        try:
            self._log(job_id)
        except Exception:  # a log line must never stop the supervisor
            log.exception("job %s: could not log its change", job_id)
        self.on_change(job_id)

    def _log(self, job_id: str) -> None:
        job = self.store.get(job_id)
        if job is None:
            return
        if job.status == "running":
            if self._running.get(job_id) != job.attempts:
                self._running[job_id] = job.attempts
                log.info("job %s started: %s %s, N = %d, %d %s, attempt %d", job.id,
                         job.kind, job.model_kind, job.n_agents, job.steps_total,
                         "runs" if job.kind == "sweep" else "steps", job.attempts)
            return
        if self._running.pop(job_id, None) is None:
            return  # not started by this service (cancelled while queued, reaped)
        seconds = (job.finished_at or 0.0) - (job.started_at or 0.0)
        if job.terminal:
            log.info("job %s ended: %s after %.3f s (%s %s, N = %d, %d of %d %s)", job.id,
                     job.status, seconds, job.kind, job.model_kind, job.n_agents,
                     job.steps_done, job.steps_total,
                     "runs" if job.kind == "sweep" else "steps")
        else:  # back in the queue: a lost worker or a graceful shutdown
            log.info("job %s attempt %d ended: re-queued (%s %s, N = %d)", job.id,
                     job.attempts, job.kind, job.model_kind, job.n_agents)
