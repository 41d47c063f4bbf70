"""Waiting on a job (long-poll until the end, or until a change), cancelling a finished
job, following its events from the client, listing with a limit, and the service's log
line at each job's start and end: the real app in-process with a real worker."""

from __future__ import annotations

import logging
import re
import time

import httpx
import pytest

from flocklab import clients
from tests.service.svc_helpers import assert_problem, long_scenario, scenario, submit, wait_for


def medium_scenario() -> dict:
    """A run of a second or two that reports progress on the way (N = 1000, 1000 steps)."""
    return scenario(n=1000, steps=1000, every=0)


@pytest.mark.slow
def test_wait_answers_when_the_job_has_finished(http: httpx.Client):
    job = submit(http, {"scenario": medium_scenario()})
    t0 = time.monotonic()
    r = http.get(f"/v1/jobs/{job['id']}", params={"wait": 60}, timeout=90)
    assert r.status_code == 200
    # Progress changed many times on the way; the long-poll still waited for the end.
    assert r.json()["status"] == "succeeded", r.json()
    assert time.monotonic() - t0 < 60
    # A finished job answers at once, whatever the wait.
    t1 = time.monotonic()
    assert http.get(f"/v1/jobs/{job['id']}", params={"wait": 30}).json()["status"] == "succeeded"
    assert time.monotonic() - t1 < 5


@pytest.mark.slow
def test_wait_until_change_answers_at_the_first_change(http: httpx.Client):
    job = submit(http, {"scenario": long_scenario()})
    try:
        wait_for(http, job["id"], {"running"})
        first = http.get(f"/v1/jobs/{job['id']}").json()
        t0 = time.monotonic()
        changed = http.get(f"/v1/jobs/{job['id']}", params={"wait": 30, "until": "change"},
                           timeout=60).json()
        assert time.monotonic() - t0 < 25  # progress is saved every second or so
        assert changed["status"] == "running"
        assert changed["steps_done"] > first["steps_done"]
        # Without a change before the deadline, the job comes back as it is.
        t1 = time.monotonic()
        still = http.get(f"/v1/jobs/{job['id']}", params={"wait": 1.5}, timeout=30).json()
        assert still["status"] == "running" and 1.4 <= time.monotonic() - t1 < 10
        bad = http.get(f"/v1/jobs/{job['id']}", params={"wait": 1, "until": "soon"})
        assert_problem(bad, 422, "query.until")
    finally:
        http.post(f"/v1/jobs/{job['id']}/cancel")
    wait_for(http, job["id"])


def test_cancelling_any_finished_job_is_409(http: httpx.Client):
    job = submit(http, {"scenario": long_scenario()})
    wait_for(http, job["id"], {"running"})
    first = http.post(f"/v1/jobs/{job['id']}/cancel")
    assert first.status_code == 202 and first.json()["cancel_requested"]
    again = http.post(f"/v1/jobs/{job['id']}/cancel")  # still stopping: a no-op
    assert again.status_code in (202, 409)
    assert wait_for(http, job["id"], timeout=30)["status"] == "cancelled"
    body = assert_problem(http.post(f"/v1/jobs/{job['id']}/cancel"), 409)
    assert body["type"].endswith(":job-finished") and body["status_now"] == "cancelled"
    assert http.get(f"/v1/jobs/{job['id']}").json()["status"] == "cancelled"


@pytest.mark.slow
def test_client_events_limit_and_the_job_log(server, caplog):
    caplog.set_level(logging.INFO, logger="flocklab.jobs")
    with clients.Client(server.url, transport=server.transport) as c:
        job = c.submit(medium_scenario())
        states = list(job.events())
        assert states, "no events"
        assert states[-1]["status"] == "succeeded" and job.status == "succeeded"
        progress = [s["progress"] for s in states]
        assert progress == sorted(progress) and progress[-1] == 1.0
        assert {s["id"] for s in states} == {job.id}
        # The stream of a finished job: its final state, then the end.
        assert [s["status"] for s in c.job(job.id).events()] == ["succeeded"]

        for _ in range(2):
            c.submit(scenario(steps=2)).wait(120)
        newest = list(c.jobs(limit=2))
        assert len(newest) == 2
        every = [j.id for j in c.jobs(page_size=1)]
        assert [j.id for j in newest] == every[:2] and len(every) >= 4
        assert [j.id for j in c.jobs(limit=3, page_size=2)] == every[:3]
        with pytest.raises(ValueError):
            list(c.jobs(limit=0))

    log = caplog.text
    started = re.search(rf"job {job.id} started: job vicsek, N = 1000, 1000 steps, "
                        r"attempt 1", log)
    ended = re.search(rf"job {job.id} ended: succeeded after (\d+\.\d+) s \(job vicsek, "
                      r"N = 1000, 1000 of 1000 steps\)", log)
    assert started and ended, log[-3000:]
    assert 0 < float(ended.group(1)) < 120


def test_async_client_events(server):
    import asyncio

    async def main() -> list[dict]:
        async with clients.AsyncClient(server.url, transport=server.async_transport) as c:
            job = await c.submit(scenario(steps=200))
            states = [s async for s in job.events()]
            assert [j.id async for j in c.jobs(limit=1)] == [job.id]
            return states

    states = asyncio.run(main())
    assert states[-1]["status"] == "succeeded"
