"""Issue 12, findings 1, 7 and 8 on a real server: GPU backends without a GPU fail
clearly and `auto` runs on the CPU and says so; client input that gave 500s is a 422; an
unexpected error keeps the connection usable; nonsense speeds, thread counts and
observable series are refused or capped."""

from __future__ import annotations

import base64
import json
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import uvicorn
from fastapi import FastAPI

from flocklab.kernels import runtime
from flocklab.service.app.problems import UnexpectedErrorMiddleware, install_problem_handlers
from flocklab.service.serve import free_port
from tests.service.jobs.test_durability import _workers
from tests.service.svc_helpers import assert_problem, scenario, submit, wait_for

TINY = {"initial": {"N": 50}, "time": {"steps": 10}}


@pytest.mark.parametrize("backend", ["cuda", "vulkan"])
def test_a_gpu_backend_without_a_gpu_fails_clearly(http, backend):
    if runtime.gpu_available(backend):
        pytest.skip(f"this machine has a working {backend} device")
    job = submit(http, {"preset": "vicsek-1995", "overrides": {**TINY, "backend": backend}})
    done = wait_for(http, job["id"])
    assert done["status"] == "failed"
    assert done["error"]["type"].endswith("backend-unavailable"), done["error"]
    assert backend in done["error"]["detail"]


def test_auto_falls_back_to_the_cpu_and_says_so(http):
    job = submit(http, {"preset": "vicsek-1995", "overrides": {**TINY, "backend": "auto"}})
    done = wait_for(http, job["id"])
    assert done["status"] == "succeeded", done["error"]
    summary = http.get(f"/v1/jobs/{job['id']}/metrics").json()["summary"]
    assert summary["backend_requested"] == "auto"
    if done["backend"] == "cpu":
        assert any("no working GPU" in note for note in summary["notes"])
    else:
        assert done["backend"] in ("cuda", "vulkan")


def test_huge_agent_indices_and_cursors_are_422(http):
    job = wait_for(http, submit(http, {"scenario": scenario()})["id"])
    assert job["status"] == "succeeded"
    url = f"/v1/jobs/{job['id']}/trajectory"
    assert_problem(http.get(url, params={"agents": "9" * 5000 + ":"}), 422, "query.agents")
    assert_problem(http.get(url, params={"agents": "1," + "9" * 5000}), 422, "query.agents")
    assert_problem(http.get(url, params={"start": "1" + "0" * 30}), 422)
    cursor = base64.urlsafe_b64encode(json.dumps({"before": 2**63}).encode()).decode()
    assert_problem(http.get("/v1/jobs", params={"cursor": cursor}), 422, "query.cursor")
    assert http.get("/healthz").status_code == 200


def _two_requests_on_one_connection(port: int, path: str) -> list[bytes]:
    """Send two GETs on one keep-alive connection; the raw heads of both answers."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        heads = []
        for _ in range(2):
            s.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\n\r\n".encode())
            raw = b""
            while b"\r\n\r\n" not in raw:
                chunk = s.recv(65536)
                assert chunk, "the server closed the connection"
                raw += chunk
            head, _, body = raw.partition(b"\r\n\r\n")
            length = next(int(v.split(b":")[1]) for v in head.split(b"\r\n")
                          if v.lower().startswith(b"content-length:"))
            while len(body) < length:
                body += s.recv(65536)
            heads.append(head)
    return heads


@pytest.fixture
def failing_app() -> Iterator[int]:
    """A real uvicorn server whose one route raises: the error path of the service's app."""
    app = FastAPI()
    install_problem_handlers(app)
    app.add_middleware(UnexpectedErrorMiddleware)

    @app.get("/boom")
    def boom() -> None:
        raise RuntimeError("an engine bug")

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port,
                                           log_level="critical"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        threading.Event().wait(0.05)
    yield port
    server.should_exit = True
    thread.join(10)


def test_an_unexpected_error_is_a_problem_and_keeps_the_connection(failing_app):
    heads = _two_requests_on_one_connection(failing_app, "/boom")
    for head in heads:
        assert head.startswith(b"HTTP/1.1 500 ")
        assert b"application/problem+json" in head
        assert b"connection: close" not in head.lower()


@pytest.mark.slow
def test_a_corrupted_result_500_keeps_the_connection(real_server, real_http):
    http = real_http
    job = wait_for(http, submit(http, {"scenario": scenario()})["id"])
    (Path(real_server.data_dir) / "results" / job["id"] / "summary.json").write_text("{not json")
    heads = _two_requests_on_one_connection(real_server.port, f"/v1/jobs/{job['id']}/metrics")
    assert all(h.startswith(b"HTTP/1.1 500 ") for h in heads)


@pytest.mark.parametrize(("override", "loc"), [
    ({"model": {"v0": 1e300}}, "model.v0"),
    ({"model": {"v0": 8.0}}, "model.v0"),  # v0 dt over the box side L = 7
    ({"time": {"dt": 1e6}}, "model.v0"),
])
def test_speeds_beyond_the_box_or_radius_are_refused(http, override, loc):
    r = http.post("/v1/jobs", json={"preset": "vicsek-1995", "overrides": override})
    assert_problem(r, 422, loc)


def test_initial_speeds_of_double_integrators_are_checked(http):
    r = http.post("/v1/jobs", json={"preset": "tjp-switching", "overrides": {
        "initial": {"speed_range": [0.0, 1e200]}}})
    assert_problem(r, 422, "initial.speed_range")


def test_observables_count_against_the_limits(make_app):
    s = make_app({"FLOCKLAB_MAX_OBSERVABLE_ROWS": "1000"})
    with s.client(timeout=30) as http:
        every_step = scenario(steps=5000, every=0)
        assert_problem(http.post("/v1/jobs", json={"scenario": every_step}), 422,
                       "recording.observables_every")
        every_step["recording"]["observables_every"] = 10
        assert http.post("/v1/jobs", json={"scenario": every_step}).status_code == 202


def test_threads_are_capped_at_the_workers_cpus_and_reported(server, http):
    job = wait_for(http, submit(http, {"scenario": scenario(threads=1024)})["id"])
    assert job["status"] == "succeeded", job["error"]
    summary = http.get(f"/v1/jobs/{job['id']}/metrics").json()["summary"]
    assert any("threads capped from 1024 to 1" in note for note in summary["notes"])
    for pid in _workers(server):  # Taichi's pool stays alive: count the worker's threads
        status = Path(f"/proc/{pid}/status").read_text()
        threads = int(status.split("Threads:")[1].split()[0])
        assert threads < 64, threads


@pytest.mark.slow
def test_long_metrics_are_streamed(real_http):
    http = real_http  # uvicorn's chunked transfer encoding
    job = wait_for(http, submit(http, {"scenario": scenario(n=10, steps=1500, every=0)})["id"])
    assert job["status"] == "succeeded"
    r = http.get(f"/v1/jobs/{job['id']}/metrics")
    assert r.status_code == 200 and r.headers.get("transfer-encoding") == "chunked"
    body = r.json()
    assert len(body["observables"]["step"]) == 1500 + 1
    assert body["observables"]["step"][-1] == 1500
    assert body["summary"]["steps"] == 1500
