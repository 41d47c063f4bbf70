"""Service policies on servers with tight settings: a bounded queue (R11), result expiry
(R10), killing a worker that cannot stop (R7, R8), API-key auth (R19) and CORS
(R20)."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from tests.service.svc_helpers import assert_problem, long_scenario, scenario, submit, wait_for


@pytest.fixture(scope="module")
def tight(tmp_path_factory):
    """Two queued jobs at most, results kept 2 s, 0.05 s between stop request and kill."""
    from tests.service.conftest import TEST_ENV
    from tests.service.inproc import InProcessServer

    s = InProcessServer(tmp_path_factory.mktemp("tight") / "data", env={
        **TEST_ENV, "FLOCKLAB_MAX_QUEUED": "2", "FLOCKLAB_RESULT_TTL_SECONDS": "2",
        "FLOCKLAB_CANCEL_GRACE_SECONDS": "0.05"}).start()
    yield s
    s.stop()


@pytest.mark.slow
def test_a_full_queue_answers_429_with_retry_after(tight):
    with tight.client(timeout=30) as http:
        running = submit(http, {"scenario": long_scenario()})
        wait_for(http, running["id"], {"running"})
        queued = [submit(http, {"scenario": scenario()}) for _ in range(2)]
        r = http.post("/v1/jobs", json={"scenario": scenario()})
        body = assert_problem(r, 429)
        assert int(r.headers["retry-after"]) >= 1 and body["type"].endswith("queue-full")
        assert len(http.get("/v1/jobs").json()["items"]) == 3  # the refused one was not stored
        http.post(f"/v1/jobs/{running['id']}/cancel")
        for j in queued:
            assert wait_for(http, j["id"])["status"] == "succeeded"


def _worker(server) -> int:
    pids = [p for p in server.children()
            if b"spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes()]
    assert len(pids) == 1, pids
    return pids[0]


@pytest.mark.slow_cases("timeout")
@pytest.mark.parametrize("stop", ["cancel", "timeout"])
def test_a_hung_worker_is_killed_after_the_grace_period(tight, stop):
    """SIGSTOP the worker mid-job so it cannot stop by itself: the supervisor must kill it
    (cancel or timeout enforced from outside, R7/R8), and a new worker takes the next job."""
    with tight.client(timeout=30) as http:
        body = {"scenario": long_scenario()}
        if stop == "timeout":
            body["timeout_seconds"] = 2.0
        job = submit(http, body)
        wait_for(http, job["id"], {"running"})
        hung = _worker(tight)
        os.kill(hung, signal.SIGSTOP)
        t0 = time.monotonic()
        if stop == "cancel":
            http.post(f"/v1/jobs/{job['id']}/cancel")
        done = wait_for(http, job["id"], timeout=15)
        assert done["status"] == ("cancelled" if stop == "cancel" else "timed_out")
        assert time.monotonic() - t0 < 5
        assert done["results"] == "none"  # killed: nothing was committed
        deadline = time.monotonic() + 5
        while Path(f"/proc/{hung}").exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not Path(f"/proc/{hung}").exists()
        after = submit(http, {"scenario": scenario()})
        assert wait_for(http, after["id"], timeout=120)["status"] == "succeeded"
        assert _worker(tight) != hung


@pytest.mark.slow
def test_results_expire_after_the_ttl_with_410(tight):
    with tight.client(timeout=30) as http:
        job = submit(http, {"scenario": scenario()})
        done = wait_for(http, job["id"], timeout=120)
        assert done["results"] == "available"
        deadline = time.monotonic() + 10
        while http.get(f"/v1/jobs/{job['id']}").json()["results"] != "expired":
            assert time.monotonic() < deadline
            time.sleep(0.2)
        for suffix in ("metrics", "trajectory", "trajectory.h5"):
            assert_problem(http.get(f"/v1/jobs/{job['id']}/{suffix}"), 410)
        assert not (tight.data_dir / "results" / job["id"]).exists()
        # The job record itself stays.
        assert http.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"


def test_api_key_is_required_on_every_route_but_healthz(make_app):
    s = make_app({"FLOCKLAB_API_KEY": "s3cret-key"})
    with s.client(timeout=30) as http:
        assert http.get("/healthz").status_code == 200
        for method, path in [("GET", "/v1/jobs"), ("POST", "/v1/jobs"), ("GET", "/v1/models"),
                             ("GET", "/v1/presets"), ("GET", "/v1/models/vicsek"),
                             ("GET", "/v1/jobs/00000000-0000-4000-8000-000000000000"),
                             ("POST", "/v1/jobs/00000000-0000-4000-8000-000000000000/cancel")]:
            r = http.request(method, path, json={"scenario": scenario()})
            assert_problem(r, 401)
            assert r.headers["www-authenticate"] == "Bearer"
        assert_problem(http.get("/v1/jobs", headers={"Authorization": "Bearer wrong"}), 401)
        assert_problem(http.get("/v1/jobs", headers={"X-API-Key": "s3cret-ke"}), 401)
        assert http.get("/v1/jobs", headers={"Authorization": "Bearer s3cret-key"}
                        ).status_code == 200
        r = http.post("/v1/jobs", json={"scenario": scenario()},
                      headers={"X-API-Key": "s3cret-key"})
        assert r.status_code == 202
        assert len(http.get("/v1/jobs", headers={"X-API-Key": "s3cret-key"}).json()["items"]) == 1
        # The API description needs the key too; the browser UIs are off.
        assert_problem(http.get("/openapi.json"), 401)
        spec = http.get("/openapi.json", headers={"X-API-Key": "s3cret-key"}).json()
        assert "/v1/jobs" in spec["paths"]
        assert http.get("/docs").status_code == 404


def test_cors_allows_only_listed_origins(make_app):
    s = make_app({"FLOCKLAB_CORS_ORIGINS": '["https://lab.example"]'})
    with s.client(timeout=30) as http:
        ok = http.get("/v1/models", headers={"Origin": "https://lab.example"})
        assert ok.headers["access-control-allow-origin"] == "https://lab.example"
        other = http.get("/v1/models", headers={"Origin": "https://evil.example"})
        assert "access-control-allow-origin" not in other.headers
