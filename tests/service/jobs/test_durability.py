"""Durability: kill -9 and restart of a real `flocklab serve`, killed workers of the
in-process app, final states (R1-R5, R9, R16)."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import httpx
import pytest

from flocklab.service.serve import ServerProcess
from tests.service.svc_helpers import scenario, submit, wait_for

# About 2-4 s of work on one thread: long enough to be killed in the middle.
MEDIUM = {"scenario": scenario(n=1000, steps=400, every=100)}


def _workers(server: ServerProcess) -> list[int]:
    pids = []
    for pid in server.children():
        try:
            if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes():
                pids.append(pid)
        except OSError:
            pass
    return pids


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat").read_text()
    return stat.split(")")[1].split()[0] != "Z"


def _wait_running(http: httpx.Client, job_id: str) -> dict:
    """Until the job runs and has made progress (the worker is inside the engine)."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        job = http.get(f"/v1/jobs/{job_id}", params={"wait": 1, "until": "change"}).json()
        if job["status"] == "running" and job["steps_done"] > 0:
            return job
        assert job["status"] in ("queued", "running"), job
    raise AssertionError("job never made progress")


@pytest.mark.slow
def test_kill_9_mid_job_then_restart_loses_and_duplicates_nothing(make_server, tmp_path):
    data = tmp_path / "data"
    s1 = make_server(data_dir=data)
    with httpx.Client(base_url=s1.url, timeout=30) as http:
        running = submit(http, MEDIUM)
        queued = submit(http, {"scenario": scenario(steps=10)})
        _wait_running(http, running["id"])
        workers = _workers(s1)
    assert len(workers) == 1
    s1.kill()
    # The orphaned worker notices its parent is gone and stops by itself.
    deadline = time.monotonic() + 10
    while _alive(workers[0]) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(workers[0])

    s2 = make_server(data_dir=data)
    with httpx.Client(base_url=s2.url, timeout=30) as http:
        done = wait_for(http, running["id"], timeout=120)
        assert done["status"] == "succeeded"
        assert done["attempts"] == 2  # the interrupted attempt counted, the re-run finished
        assert done["results"] == "available"
        assert wait_for(http, queued["id"])["status"] == "succeeded"
        items = http.get("/v1/jobs", params={"limit": 500}).json()["items"]
        assert sorted(j["id"] for j in items) == sorted([running["id"], queued["id"]])
        assert not [j for j in items if j["status"] in ("queued", "running")]
        metrics = http.get(f"/v1/jobs/{running['id']}/metrics").json()
        assert metrics["summary"]["steps"] == 400
    assert list((data / "results" / ".attempts").iterdir()) == []


def test_a_second_service_on_the_same_data_dir_is_refused(make_app, tmp_path):
    data = tmp_path / "data"
    make_app(data_dir=data)  # the first service holds the lock (in this process)
    second = ServerProcess(data, env={"FLOCKLAB_WARMUP_PRESET": ""})
    with pytest.raises(RuntimeError, match="exited"):
        second.start(timeout=30)
    assert "another flocklab service" in second.log_path.read_text()


@pytest.mark.slow
def test_graceful_restart_requeues_without_using_an_attempt(make_server, tmp_path):
    data = tmp_path / "data"
    s1 = make_server(data_dir=data)
    with httpx.Client(base_url=s1.url, timeout=30) as http:
        job = submit(http, MEDIUM)
        _wait_running(http, job["id"])
    # uvicorn re-raises SIGTERM after its graceful shutdown, hence -SIGTERM.
    assert s1.stop() in (0, -signal.SIGTERM)
    assert "Application shutdown complete" in s1.log_path.read_text()
    s2 = make_server(data_dir=data)
    with httpx.Client(base_url=s2.url, timeout=30) as http:
        done = wait_for(http, job["id"], timeout=120)
    assert done["status"] == "succeeded" and done["attempts"] == 1


@pytest.mark.slow
def test_a_killed_worker_is_retried_once_then_fails_and_the_pool_recovers(server, http):
    job = submit(http, MEDIUM)
    _wait_running(http, job["id"])
    os.kill(_workers(server)[0], signal.SIGKILL)
    done = wait_for(http, job["id"], timeout=120)
    assert done["status"] == "succeeded" and done["attempts"] == 2

    job = submit(http, MEDIUM)
    for attempt in (1, 2):
        running = _wait_running(http, job["id"])
        assert running["attempts"] == attempt
        os.kill(_workers(server)[0], signal.SIGKILL)
        if attempt == 1:
            requeued = wait_for(http, job["id"], {"queued", "running"}, timeout=30)
            assert requeued["error"]["type"].endswith("worker-lost")
    failed = wait_for(http, job["id"], timeout=60)
    assert failed["status"] == "failed" and failed["attempts"] == 2
    assert failed["error"]["type"].endswith("worker-lost")
    assert "SIGKILL" in failed["error"]["detail"]

    after = submit(http, {"scenario": scenario()})
    assert wait_for(http, after["id"], timeout=120)["status"] == "succeeded"


@pytest.mark.slow_cases("0.9", "1.2")
@pytest.mark.parametrize("delay", [0.0, 0.3, 0.6, 0.9, 1.2])
def test_cancel_racing_completion_leaves_one_final_state(http, delay):
    job = submit(http, {"scenario": scenario(n=300, steps=60, every=0)})
    time.sleep(delay)
    r = http.post(f"/v1/jobs/{job['id']}/cancel")
    assert r.status_code in (202, 409)
    done = wait_for(http, job["id"])
    assert done["status"] in ("succeeded", "cancelled")
    if r.status_code == 409:
        assert done["status"] == "succeeded"
    time.sleep(0.3)
    again = http.get(f"/v1/jobs/{job['id']}").json()
    assert again["status"] == done["status"] and again["finished_at"] == done["finished_at"]
