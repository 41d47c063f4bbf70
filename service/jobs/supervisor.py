"""The supervisor: one thread in the API process that owns the worker processes.

It claims queued jobs, hands them to idle workers, relays progress into the store,
renews the leases of running attempts (a worker busy inside a Taichi kernel cannot
heartbeat for itself), enforces cancellation and per-job timeouts from outside the worker
(cooperative stop first, then SIGKILL after a grace period), re-queues jobs whose worker
died (once: infrastructure failures only, R9) and reaps jobs whose lease expired (R2).
A re-queued job whose run left a checkpoint (docs/CHECKPOINTS.md) goes on from it: the
next attempt takes over the lost one's folder and the worker reports the step it resumed
from (`resumed_from_step`); a sweep's attempt takes over the whole sweep folder, and its
worker reports each run it continues from that run's checkpoint (`resumed_runs`). Every
transition goes through the store's conditional UPDATEs.

All state below is touched only by the supervisor thread; the API talks to it through
`wake()` and `cancel()`, which are thread-safe.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import signal
import socket
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from ..sweeps.executors import ExecutorConfig
from ..sweeps.tables import rebuild_tables
from .disk import free_bytes
from .joblog import JobLog
from .limits import Limits
from .problems import problem
from .results import SWEEP_FILES, ResultStore, checksums
from .store import Job, JobStore
from .worker import worker_main

log = logging.getLogger("flocklab.supervisor")

# How often the loop wakes with nothing to do: bounds how late a timeout or lease
# expiry is noticed, not how fast jobs start (submissions wake the loop at once).
TICK_SECONDS = 0.25
PROGRESS_WRITE_INTERVAL = 0.25
REAP_INTERVAL = 1.0
# How often a job held back by a full disk is reported in the log.
DISK_LOG_INTERVAL = 60.0


@dataclass(frozen=True)
class SupervisorConfig:
    workers: int
    threads_per_worker: int | None
    limits: Limits
    lease_seconds: float = 30.0
    max_attempts: int = 2
    cancel_grace_seconds: float = 5.0
    result_ttl_seconds: float = 7 * 24 * 3600.0
    worker_max_jobs: int = 500
    worker_max_rss_bytes: int = 0
    warmup_preset: str | None = None
    executor: ExecutorConfig = field(default_factory=ExecutorConfig)
    # Jobs wait in the queue while the results disk has less free space than this.
    min_free_bytes: int = 0


@dataclass
class _Attempt:
    job_id: str
    token: str
    deadline: float  # time.monotonic()
    timeout_seconds: float
    steps_done: int = 0
    progress_saved: float = 0.0
    stop_reason: str | None = None  # "cancel" | "timeout"
    kill_at: float | None = None
    kind: str = "job"  # "sweep": steps_done counts the runs that ended
    runs_failed: int | None = None


@dataclass
class _Worker:
    process: Any  # multiprocessing.context.SpawnProcess
    conn: Connection
    cancel_flag: Any  # shared c_int
    ready: bool = False
    attempt: _Attempt | None = None
    jobs_done: int = 0
    retiring: bool = False
    rss: int = 0
    started: float = field(default_factory=time.monotonic)


class Supervisor:
    def __init__(self, store: JobStore, results: ResultStore, config: SupervisorConfig,
                 scratch_dir: Path, on_change: Callable[[str], None] = lambda job_id: None):
        self.store = store
        self.results = results
        self.config = config
        self.scratch_dir = scratch_dir
        self.on_change = JobLog(store, on_change)  # logs each job's start and end
        self.owner = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self._ctx = mp.get_context("spawn")
        self._workers: list[_Worker] = []
        self._cancels: set[str] = set()
        self._cancels_lock = threading.Lock()
        self._stopping = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._thread = threading.Thread(target=self._run, name="flocklab-supervisor",
                                        daemon=True)
        self._spawn_after = 0.0
        self._spawn_backoff = 0.0
        self._last = {"heartbeat": 0.0, "reap": 0.0, "expire": 0.0, "disk_log": -1e9}

    # -- the API side (thread-safe) -------------------------------------------------------

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the loop, re-queue running attempts (without counting them) and end workers."""
        self._stopping.set()
        self.wake()
        self._thread.join(timeout)
        # Forget the descriptors before closing them: a late wake() must not write into
        # whatever file reuses the number.
        fds, self._wake_r, self._wake_w = (self._wake_r, self._wake_w), -1, -1
        for fd in fds:
            os.close(fd)

    def wake(self) -> None:
        """Ask the loop to look at the queue now (called after a submission)."""
        # A full pipe already holds a wake-up; a closed one means we are shutting down.
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"\0")

    def cancel(self, job_id: str) -> None:
        """Stop a running job of this supervisor (the store already has the request)."""
        with self._cancels_lock:
            self._cancels.add(job_id)
        self.wake()

    def worker_pids(self) -> list[int]:
        return [w.process.pid for w in self._workers if w.process.pid is not None]

    @property
    def _resumes_jobs(self) -> bool:
        """Whether a job's next attempt resumes from its lost one's checkpoint: on local
        workers (a Ray task runs on a node that may be gone, and starts over)."""
        return self.config.executor.kind == "local"

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    # -- the loop -----------------------------------------------------------------------

    def _run(self) -> None:
        self.results.sweep_attempts(keep=self.store.unfinished_ids("sweep"),
                                    keep_checkpoints=self.store.unfinished_ids("job")
                                    if self._resumes_jobs else ())
        self._reap(startup=True)
        while not self._stopping.is_set():
            try:
                self._iteration()
            except Exception:  # keep supervising whatever one iteration hit
                log.exception("supervisor iteration failed")
                time.sleep(TICK_SECONDS)
        self._shutdown()

    def _iteration(self) -> None:
        self._ensure_workers()
        waitables: list[Any] = [self._wake_r]
        for w in self._workers:
            waitables += [w.conn, w.process.sentinel]
        for ready in wait(waitables, timeout=TICK_SECONDS):
            if ready == self._wake_r:
                self._drain_wakeups()
        for w in list(self._workers):
            self._poll(w)
        self._apply_cancels()
        self._enforce_deadlines()
        self._dispatch()
        now = time.monotonic()
        if now - self._last["heartbeat"] >= self.config.lease_seconds / 3:
            self._last["heartbeat"] = now
            tokens = [w.attempt.token for w in self._workers if w.attempt]
            self.store.renew_leases(self.owner, tokens, self.config.lease_seconds)
        if now - self._last["reap"] >= REAP_INTERVAL:
            self._last["reap"] = now
            self._reap(startup=False)
        if now - self._last["expire"] >= min(60.0, self.config.result_ttl_seconds / 4):
            self._last["expire"] = now
            self._expire_results()

    def _drain_wakeups(self) -> None:
        try:
            while os.read(self._wake_r, 4096):
                pass
        except BlockingIOError:
            pass

    # -- workers --------------------------------------------------------------------------

    def _ensure_workers(self) -> None:
        live = [w for w in self._workers if not w.retiring]
        if len(live) >= self.config.workers or time.monotonic() < self._spawn_after:
            return
        for _ in range(self.config.workers - len(live)):
            self._workers.append(self._spawn())

    def _spawn(self) -> _Worker:
        parent_conn, child_conn = self._ctx.Pipe()
        flag = self._ctx.RawValue("i", 0)
        cfg = {"warmup_preset": self.config.warmup_preset, "scratch_dir": str(self.scratch_dir)}
        proc = self._ctx.Process(target=worker_main, args=(child_conn, flag, cfg),
                                 name="flocklab-worker", daemon=True)
        proc.start()
        child_conn.close()
        return _Worker(process=proc, conn=parent_conn, cancel_flag=flag)

    def _poll(self, w: _Worker) -> None:
        """Handle every message a worker sent, then notice whether it died."""
        try:
            while w.conn.poll():
                self._handle(w, w.conn.recv())
        except (EOFError, OSError):
            pass  # the worker is gone; its exit code tells the rest
        if not w.process.is_alive():
            self._lost(w)

    def _handle(self, w: _Worker, msg: tuple) -> None:
        kind = msg[0]
        if kind == "ready":
            w.ready = True
            self._spawn_backoff = 0.0
        elif kind == "progress" and w.attempt and msg[1] == w.attempt.token:
            a = w.attempt
            a.steps_done = msg[2]
            if len(msg) > 4:  # a sweep's progress also counts its failed runs
                a.runs_failed = msg[4]
            now = time.monotonic()
            if now - a.progress_saved >= PROGRESS_WRITE_INTERVAL:
                a.progress_saved = now
                self.store.set_progress(a.job_id, a.token, a.steps_done, a.runs_failed)
                self.on_change(a.job_id)
        elif kind == "resumed" and w.attempt and msg[1] == w.attempt.token:
            a = w.attempt
            a.steps_done = msg[2] or 0
            self.store.set_resumed(a.job_id, a.token, msg[2])
            if msg[2] is not None:
                log.info("job %s: resumed from its checkpoint at step %d", a.job_id, msg[2])
            self.on_change(a.job_id)
        elif kind == "run_resumed" and w.attempt and msg[1] == w.attempt.token:
            # A sweep's run going on from its checkpoint (msg[3] None: refused, step 0).
            a = w.attempt
            self.store.set_run_resumed(a.job_id, a.token, msg[2], msg[3])
            if msg[3] is not None:
                log.info("sweep %s: run %d resumed from its checkpoint at step %d",
                         a.job_id, msg[2], msg[3])
            self.on_change(a.job_id)
        elif kind == "result" and w.attempt and msg[1] == w.attempt.token:
            outcome = msg[2]
            w.rss = outcome.get("rss", 0)
            self._finish(w.attempt, outcome)
            w.attempt = None
            w.jobs_done += 1
            cfg = self.config
            if w.jobs_done >= cfg.worker_max_jobs or (
                cfg.worker_max_rss_bytes and w.rss > cfg.worker_max_rss_bytes
            ):
                self._retire(w)

    def _retire(self, w: _Worker) -> None:
        """Recycle a worker (job count or memory): it finishes and a fresh one starts."""
        w.retiring = True
        try:
            w.conn.send(("stop",))
        except OSError:
            w.process.kill()

    def _lost(self, w: _Worker) -> None:
        """A worker exited: settle its attempt and forget it (a new one is spawned)."""
        w.process.join(0.1)
        self._workers.remove(w)
        w.conn.close()
        if not w.ready and not w.retiring:
            # Died before it could take work: back off so a broken install cannot spin.
            self._spawn_backoff = min(30.0, max(1.0, 2 * self._spawn_backoff))
            self._spawn_after = time.monotonic() + self._spawn_backoff
            log.error("worker exited during start-up (exit code %s); retrying in %.0f s",
                      w.process.exitcode, self._spawn_backoff)
        a = w.attempt
        if a is None:
            return
        job = self.store.get(a.job_id)
        retried = (a.stop_reason is None and job is not None and not job.cancel_requested
                   and job.attempts < self.config.max_attempts)
        # A sweep's retry resumes from its finished runs, a job's from its checkpoint.
        kept: dict[str, Any] = {}
        if not retried:
            kept = self._settle_output(a)
        elif a.kind != "sweep":
            self.results.discard_attempt(a.job_id, a.token,
                                         keep_checkpoint=self._resumes_jobs)
        if a.stop_reason is not None:
            self._finish_stopped(a, **kept)
            return
        if job is not None and job.cancel_requested:
            # Cancelled before the supervisor could pass the request on: never re-run it.
            self.store.finish(a.job_id, a.token, "cancelled", steps_done=a.steps_done,
                              **kept)
            self.on_change(a.job_id)
            return
        note = problem("worker-lost", "Worker process lost", 500,
                       f"the worker running this job {_describe_exit(w.process.exitcode)} "
                       f"during attempt {job.attempts if job else '?'}",
                       attempt=job.attempts if job else None)
        log.warning("job %s: %s", a.job_id, note["detail"])
        if job is not None and job.attempts < self.config.max_attempts:
            self.store.requeue(a.job_id, a.token, refund_attempt=False, note=note)
        else:
            self.store.finish(a.job_id, a.token, "failed", error=note, steps_done=a.steps_done,
                              **kept)
        self.on_change(a.job_id)

    def _settle_output(self, a: _Attempt) -> dict[str, Any]:
        """The output of an attempt that ends its job without a result of its own (its
        worker killed or lost for the last time, or a problem): a job's is deleted; a
        sweep's finished runs are kept, each once (the tables rebuilt from its journal),
        so a cancel, a worker death or one failing run never throws them away. Returns
        the store.finish arguments for the results."""
        if a.kind == "sweep":
            folder = self.results.attempt_dir(a.job_id, a.token)
            try:
                kept = rebuild_tables(folder)
            except Exception:  # the runs stay lost, but the sweep still ends
                log.exception("sweep %s: could not rebuild its tables", a.job_id)
                kept = False
            if kept and self.results.commit(a.job_id, a.token):
                return {"has_results": True,
                        "checksums": checksums(self.results.job_dir(a.job_id), SWEEP_FILES)}
        self.results.discard_attempt(a.job_id, a.token)
        return {}

    # -- jobs -----------------------------------------------------------------------------

    def _disk_has_room(self) -> bool:
        """Whether a job may start: the results disk keeps the configured reserve free."""
        if self.config.min_free_bytes <= 0:
            return True
        free = free_bytes(self.results.root)
        if free >= self.config.min_free_bytes:
            return True
        now = time.monotonic()
        if now - self._last["disk_log"] >= DISK_LOG_INTERVAL:
            self._last["disk_log"] = now
            log.warning("%d bytes free on the results disk, under the reserve of %d: queued "
                        "jobs wait", free, self.config.min_free_bytes)
        return False

    def _dispatch(self) -> None:
        idle = [w for w in self._workers
                if w.ready and not w.retiring and w.attempt is None]
        if not idle or not self._disk_has_room():
            return
        for w in idle:
            job = self.store.claim_next(self.owner, self.config.lease_seconds)
            if job is None:
                return
            self._assign(w, job)

    def _assign(self, w: _Worker, job: Job) -> None:
        assert job.lease_token is not None
        w.cancel_flag.value = 0
        w.attempt = _Attempt(job_id=job.id, token=job.lease_token,
                             deadline=time.monotonic() + job.timeout_seconds,
                             timeout_seconds=job.timeout_seconds, kind=job.kind)
        # A sweep's attempt continues in the folder of its lost predecessor, if any; a
        # job's from its predecessor's checkpoint (local workers only: a Ray task starts
        # over, docs/CHECKPOINTS.md).
        resume = False
        if job.kind == "sweep":
            out_dir = self.results.adopt_attempt(job.id, job.lease_token)
        else:
            out_dir = self.results.attempt_dir(job.id, job.lease_token)
            if self._resumes_jobs:
                resume = self.results.adopt_checkpoint(job.id, job.lease_token)
        order = {
            "job_id": job.id,
            "kind": job.kind,
            "token": job.lease_token,
            "scenario": job.scenario,
            "out_dir": str(out_dir),
            "resume": resume,
            "limits": self.config.limits.to_dict(),
            "threads": self.config.threads_per_worker,
            "executor": self.config.executor.to_dict(),
        }
        # If the worker just died, _poll sees it and re-queues the attempt.
        with contextlib.suppress(OSError):
            w.conn.send(("run", order))
        self.on_change(job.id)

    def _finish(self, a: _Attempt, outcome: dict[str, Any]) -> None:
        """Record a worker's result. Only the holder of the attempt's lease commits (R5)."""
        job = self.store.get(a.job_id)
        if job is None or job.status != "running" or job.lease_token != a.token:
            log.warning("job %s: dropping the result of a superseded attempt", a.job_id)
            self.results.discard_attempt(a.job_id, a.token)
            return
        if "problem" in outcome:
            self.store.finish(a.job_id, a.token, "failed", error=outcome["problem"],
                              steps_done=a.steps_done, **self._settle_output(a))
            self.on_change(a.job_id)
            return
        summary = outcome["summary"]
        status, error = _job_status(summary, a)
        has_results = self.results.commit(a.job_id, a.token)
        done = summary.get("runs_ended" if a.kind == "sweep" else "steps", a.steps_done)
        self.store.finish(a.job_id, a.token, status, error=error, backend=summary.get("backend"),
                          has_results=has_results, checksums=outcome.get("checksums"),
                          steps_done=done, runs_failed=summary.get("runs_failed"))
        self.on_change(a.job_id)

    def _finish_stopped(self, a: _Attempt, **kept: Any) -> None:
        """A cancelled or timed-out attempt whose worker had to be killed (`kept`: its
        results, see _settle_output)."""
        status = "timed_out" if a.stop_reason == "timeout" else "cancelled"
        error = _timeout_problem(a) if status == "timed_out" else None
        self.store.finish(a.job_id, a.token, status, error=error, steps_done=a.steps_done,
                          **kept)
        self.on_change(a.job_id)

    def _apply_cancels(self) -> None:
        with self._cancels_lock:
            ids, self._cancels = self._cancels, set()
        for w in self._workers:
            if w.attempt and w.attempt.job_id in ids:
                self._stop_attempt(w, "cancel")

    def _stop_attempt(self, w: _Worker, reason: str) -> None:
        a = w.attempt
        if a is None or a.stop_reason is not None:
            return
        a.stop_reason = reason
        a.kill_at = time.monotonic() + self.config.cancel_grace_seconds
        w.cancel_flag.value = 1

    def _enforce_deadlines(self) -> None:
        now = time.monotonic()
        for w in self._workers:
            a = w.attempt
            if a is None:
                continue
            if a.stop_reason is None and now >= a.deadline:
                self._stop_attempt(w, "timeout")
            elif a.kill_at is not None and now >= a.kill_at and w.process.is_alive():
                log.warning("job %s: worker ignored the stop request; killing it", a.job_id)
                w.process.kill()  # _poll then settles the attempt as cancelled/timed out

    def _reap(self, *, startup: bool) -> None:
        """Settle running jobs nobody is running: an expired lease, or (at start-up, when
        this process holds the data directory's lock) any lease of a previous process.
        Also forwards cancel requests the store holds for our own attempts."""
        mine = {w.attempt.token: w for w in self._workers if w.attempt}
        now = time.time()
        for job in self.store.running():
            w = mine.get(job.lease_token or "")
            if w is not None:
                if job.cancel_requested:
                    self._stop_attempt(w, "cancel")
                continue
            expired = job.lease_expires is None or job.lease_expires < now
            if not (startup or job.lease_owner == self.owner or expired):
                continue
            assert job.lease_token is not None
            if job.kind == "job" and (job.attempts >= self.config.max_attempts
                                      or job.cancel_requested):
                # No attempt follows: nothing will resume from the checkpoint it left.
                self.results.discard_attempt(job.id, job.lease_token)
            if job.cancel_requested:
                self.store.finish(job.id, job.lease_token, "cancelled")
            elif job.attempts < self.config.max_attempts:
                note = problem("attempt-interrupted", "Attempt interrupted", 500,
                               "the service stopped or lost the worker during attempt "
                               f"{job.attempts}; the job was re-queued", attempt=job.attempts)
                self.store.requeue(job.id, job.lease_token, refund_attempt=False, note=note)
            else:
                self.store.finish(job.id, job.lease_token, "failed", error=problem(
                    "worker-lost", "Worker process lost", 500,
                    f"the job's lease expired during its last allowed attempt ({job.attempts})",
                    attempt=job.attempts))
            log.warning("reaped job %s (lease owner %s)", job.id, job.lease_owner)
            self.on_change(job.id)

    def _expire_results(self) -> None:
        cutoff = time.time() - self.config.result_ttl_seconds
        for job_id in self.store.expire_results(cutoff):
            self.results.delete(job_id)
            self.on_change(job_id)

    def _shutdown(self) -> None:
        for w in self._workers:
            if w.attempt is not None:
                # Not the job's fault: it goes back to the queue without using an attempt.
                self.store.requeue(w.attempt.job_id, w.attempt.token, refund_attempt=True,
                                   note=None)
                w.process.kill()
            else:
                with contextlib.suppress(OSError):
                    w.conn.send(("stop",))
        deadline = time.monotonic() + 5.0
        for w in self._workers:
            w.process.join(max(0.0, deadline - time.monotonic()))
            if w.process.is_alive():
                w.process.kill()
                w.process.join(1.0)
            w.conn.close()
            if w.attempt is not None and w.attempt.kind != "sweep":
                # The killed run's partial output: the job re-runs from its checkpoint if
                # it left one, else from scratch (a sweep keeps its folder, which its
                # next attempt adopts to skip finished runs).
                self.results.discard_attempt(w.attempt.job_id, w.attempt.token,
                                             keep_checkpoint=self._resumes_jobs)
        self._workers.clear()


def _job_status(summary: dict[str, Any], a: _Attempt) -> tuple[str, dict[str, Any] | None]:
    """Map the engine's run status to the job's terminal status and problem."""
    status = summary.get("status")
    if status == "completed":
        return "succeeded", None
    if status == "cancelled":
        if a.stop_reason == "timeout":
            return "timed_out", _timeout_problem(a)
        return "cancelled", None
    if status == "diverged":
        err = summary.get("error") or {}
        return "failed", problem(
            "diverged", "Simulation diverged", 422,
            err.get("message", "the simulation produced non-finite or runaway values"),
            **{k: err[k] for k in ("step", "quantity", "cause") if k in err})
    return "failed", problem("internal-error", "Internal error", 500,
                             f"the engine returned an unknown status {status!r}")


def _timeout_problem(a: _Attempt) -> dict[str, Any]:
    return problem("timeout", "Job timed out", 504,
                   f"the job ran longer than its limit of {a.timeout_seconds:g} s",
                   timeout_seconds=a.timeout_seconds)


def _describe_exit(code: int | None) -> str:
    if code is None:
        return "stopped responding"
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    return f"exited with status {code}"
