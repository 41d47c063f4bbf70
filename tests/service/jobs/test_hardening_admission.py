"""Issue 12, findings 5 and 6: bodies must be JSON (415 otherwise, the CSRF guard);
a full queue refuses a burst at once, with a Retry-After measured from the drain rate."""

from __future__ import annotations

import statistics
import threading
import time

import httpx
import pytest

from tests.service.svc_helpers import assert_problem, long_scenario, scenario, submit, wait_for

BODY = b'{"scenario": {"model": {"kind": "vicsek"}, "initial": {"kind": "random", "N": 10}}}'


@pytest.mark.parametrize("content_type", [
    "text/plain", "application/x-www-form-urlencoded", "multipart/form-data; boundary=x",
    None,
])
def test_non_json_bodies_are_refused_with_415(http, content_type):
    headers = {"Content-Type": content_type} if content_type else {}
    before = http.get("/v1/jobs", params={"limit": 500}).json()["items"]
    r = http.post("/v1/jobs", content=BODY, headers=headers)
    body = assert_problem(r, 415)
    assert body["type"].endswith("unsupported-media-type")
    assert r.headers["Accept-Post"] == "application/json"
    assert len(http.get("/v1/jobs", params={"limit": 500}).json()["items"]) == len(before)


def test_json_with_parameters_and_bodiless_posts_pass(http):
    job = submit(http, {"scenario": scenario(steps=5)})
    r = http.post("/v1/jobs", content=BODY.replace(b"10}", b"10}, \"time\": {\"steps\": 3}"),
                  headers={"Content-Type": "application/json; charset=utf-8"})
    assert r.status_code in (202, 422), r.text  # reached the route (not 415)
    assert r.status_code != 415
    # Cancel carries no body: it needs no content type.
    r = http.post(f"/v1/jobs/{job['id']}/cancel")
    assert "content-type" not in r.request.headers
    assert r.status_code in (202, 409), r.text


def _burst(url: str, n: int) -> list[tuple[int, float, str | None]]:
    """n concurrent submissions; (status, seconds, Retry-After) of each."""
    out: list[tuple[int, float, str | None]] = []
    lock = threading.Lock()
    go = threading.Event()

    def one() -> None:
        with httpx.Client(timeout=60) as c:
            go.wait()
            t0 = time.monotonic()
            r = c.post(f"{url}/v1/jobs", json={"scenario": scenario(steps=5)})
            with lock:
                out.append((r.status_code, time.monotonic() - t0, r.headers.get("Retry-After")))

    threads = [threading.Thread(target=one) for _ in range(n)]
    for t in threads:
        t.start()
    time.sleep(0.5)
    go.set()
    for t in threads:
        t.join()
    return out


@pytest.mark.slow
def test_a_full_queue_refuses_a_burst_at_once_with_a_measured_retry_after(make_server):
    s = make_server({"FLOCKLAB_MAX_QUEUED": "3"})
    with httpx.Client(base_url=s.url, timeout=30) as http:
        # Measure a drain rate: a few short jobs start within a second or two.
        quick = [submit(http, {"scenario": scenario(steps=5)}) for _ in range(3)]
        for job in quick:
            assert wait_for(http, job["id"])["status"] == "succeeded"
        running = submit(http, {"scenario": long_scenario()})
        queued = [submit(http, {"scenario": long_scenario()}) for _ in range(3)]
        try:
            results = _burst(s.url, 40)
            assert {status for status, _, _ in results} == {429}
            times = sorted(t for _, t, _ in results)
            # Refused before parsing or touching the store's write lock.
            assert statistics.median(times) < 1.0 and times[-1] < 5.0, times
            retry = {int(r) for _, _, r in results}
            # 3 queued jobs at the rate the quick jobs started (several per second): a
            # few seconds, not the old fixed 60.
            assert max(retry) <= 15, retry
            r = http.post("/v1/jobs", json={"scenario": scenario()})
            body = assert_problem(r, 429)
            assert body["retry_after_seconds"] == int(r.headers["Retry-After"])
            # A retry with an Idempotency-Key of a stored job still gets its job.
            key = {"Idempotency-Key": "burst-replay"}
            http.post(f"/v1/jobs/{queued[0]['id']}/cancel")
            first = http.post("/v1/jobs", json={"scenario": scenario(steps=5)}, headers=key)
            assert first.status_code == 202
            again = http.post("/v1/jobs", json={"scenario": scenario(steps=5)}, headers=key)
            assert again.status_code == 202 and again.json()["id"] == first.json()["id"]
        finally:
            for job in (running, *queued):
                http.post(f"/v1/jobs/{job['id']}/cancel")
