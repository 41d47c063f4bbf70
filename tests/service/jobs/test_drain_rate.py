"""Issue 28, finding 7: Retry-After of 60-427 s for a queue that drained in 2 s. The drain
rate was job starts per wall-clock minute, so time the workers sat idle before a burst
counted as slowness (and no start in the last minute gave a fixed 60 s). It is now the
workers over the mean time a recent job held one, for jobs and sweeps alike."""

from __future__ import annotations

import math
import time
from datetime import datetime

import httpx
import pytest

from tests.service.svc_helpers import assert_problem, long_scenario, scenario, submit, wait_for
from tests.service.sweeps.test_sweeps import sweep_spec

IDLE_SECONDS = 25


def _held_seconds(job: dict) -> float:
    start = datetime.fromisoformat(job["started_at"])
    end = datetime.fromisoformat(job["finished_at"]) if job.get("finished_at") else None
    return ((end or datetime.now(start.tzinfo)) - start).total_seconds()


@pytest.mark.slow
def test_retry_after_follows_how_long_jobs_hold_a_worker(make_server):
    s = make_server({"FLOCKLAB_MAX_QUEUED": "3", "FLOCKLAB_WORKERS": "1"})
    with httpx.Client(base_url=s.url, timeout=30) as http:
        quick = [submit(http, {"scenario": scenario(steps=5)}) for _ in range(3)]
        quick = [wait_for(http, job["id"]) for job in quick]
        assert {j["status"] for j in quick} == {"succeeded"}
        time.sleep(IDLE_SECONDS)  # the service sits idle; then a burst fills the queue
        blocker = submit(http, {"scenario": long_scenario()})
        wait_for(http, blocker["id"], {"running"})
        queued = [submit(http, {"scenario": scenario(steps=5)}) for _ in range(3)]
        try:
            job_429 = http.post("/v1/jobs", json={"scenario": scenario(steps=5)})
            sweep_429 = http.post("/v1/sweeps", json=sweep_spec())
            running = http.get(f"/v1/jobs/{blocker['id']}").json()
            # The reference: 3 queued jobs x the mean time the 4 recent jobs held the one
            # worker (the blocker's so far). The old rate said 3 x 25 s / 4 starts ~ 19 s.
            held = [_held_seconds(j) for j in (*quick, running)]
            expected = math.ceil(3 * sum(held) / len(held))
            for r in (job_429, sweep_429):
                body = assert_problem(r, 429)
                retry = int(r.headers["Retry-After"])
                assert body["retry_after_seconds"] == retry
                assert retry <= expected + 2, (retry, held)
                assert retry < IDLE_SECONDS / 4, (retry, held)
        finally:
            for job in (blocker, *queued):
                http.post(f"/v1/jobs/{job['id']}/cancel")
