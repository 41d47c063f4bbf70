"""The job store with sweeps in it: an old data directory still opens, sweeps and jobs
are listed apart, and a sweep's attempt folder is handed to its retry."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from flocklab.service.jobs import JobStore, NewJob
from flocklab.service.jobs.results import ResultStore

# The jobs table as the first release created it (before sweeps).
OLD_SCHEMA = """
CREATE TABLE jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT NOT NULL UNIQUE, status TEXT NOT NULL,
    scenario TEXT NOT NULL, model_kind TEXT NOT NULL, n_agents INTEGER NOT NULL,
    steps_total INTEGER NOT NULL, steps_done INTEGER NOT NULL DEFAULT 0,
    timeout_seconds REAL NOT NULL, idempotency_key TEXT UNIQUE, request_hash TEXT NOT NULL,
    created_at REAL NOT NULL, started_at REAL, finished_at REAL,
    attempts INTEGER NOT NULL DEFAULT 0, lease_owner TEXT, lease_token TEXT,
    lease_expires REAL, cancel_requested INTEGER NOT NULL DEFAULT 0, backend TEXT,
    error TEXT, has_results INTEGER NOT NULL DEFAULT 0,
    results_expired INTEGER NOT NULL DEFAULT 0, checksums TEXT
);
"""


def _new(kind: str, key: str | None = None) -> NewJob:
    return NewJob(scenario='{"name": "x"}', model_kind="vicsek", n_agents=10, steps_total=4,
                  timeout_seconds=60.0, request_hash=f"h-{kind}", idempotency_key=key,
                  kind=kind)


def test_an_old_data_directory_opens_and_its_rows_are_jobs(tmp_path: Path):
    path = tmp_path / "jobs.sqlite3"
    db = sqlite3.connect(path)
    db.executescript(OLD_SCHEMA)
    db.execute("INSERT INTO jobs (id, status, scenario, model_kind, n_agents, steps_total,"
               " timeout_seconds, request_hash, created_at) VALUES"
               " ('00000000-0000-4000-8000-000000000001', 'succeeded', '{}', 'vicsek', 5,"
               " 10, 60, 'h', 1.0)")
    db.commit()
    db.close()

    store = JobStore(path)
    try:
        old = store.get("00000000-0000-4000-8000-000000000001")
        assert old is not None and old.kind == "job" and old.runs_failed == 0
        sweep, created = store.insert(_new("sweep"), max_queued=10)
        assert created and sweep.kind == "sweep"
        assert [j.id for j in store.list()] == [old.id]
        assert [j.id for j in store.list(kind="sweep")] == [sweep.id]
        assert store.unfinished_ids("sweep") == {sweep.id}
    finally:
        store.close()
    # Opening it again (the columns now exist) changes nothing.
    store = JobStore(path)
    try:
        assert store.get(sweep.id).kind == "sweep"  # type: ignore[union-attr]
    finally:
        store.close()


def test_progress_and_finish_record_failed_runs(tmp_path: Path):
    store = JobStore(tmp_path / "jobs.sqlite3")
    try:
        store.insert(_new("sweep"), max_queued=10)
        claimed = store.claim_next("me", 30.0)
        assert claimed is not None and claimed.lease_token
        store.set_progress(claimed.id, claimed.lease_token, 3, runs_failed=1)
        assert store.get(claimed.id).runs_failed == 1  # type: ignore[union-attr]
        assert store.finish(claimed.id, claimed.lease_token, "succeeded", steps_done=4,
                            runs_failed=2)
        done = store.get(claimed.id)
        assert done is not None and (done.steps_done, done.runs_failed) == (4, 2)
    finally:
        store.close()


def test_a_retry_adopts_the_lost_attempts_folder(tmp_path: Path):
    results = ResultStore(tmp_path / "results")
    job_id = "00000000-0000-4000-8000-0000000000aa"
    first = results.attempt_dir(job_id, "aaaa")
    (first / "runs").mkdir(parents=True)
    (first / "runs.jsonl").write_text('{"run": 0}\n')
    other = results.attempt_dir("00000000-0000-4000-8000-0000000000bb", "cccc")
    other.mkdir()

    results.sweep_attempts(keep={job_id})  # start-up: unfinished sweeps keep theirs
    assert first.is_dir() and not other.exists()
    second = results.adopt_attempt(job_id, "bbbb")
    assert second == results.attempt_dir(job_id, "bbbb")
    assert (second / "runs.jsonl").read_text() == '{"run": 0}\n'
    assert not first.exists()
    # A job with no earlier attempt gets a fresh (absent) folder.
    fresh = results.adopt_attempt("00000000-0000-4000-8000-0000000000cc", "dddd")
    assert not fresh.exists()
