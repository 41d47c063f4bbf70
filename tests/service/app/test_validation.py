"""Bad input is refused with 4xx problem+json naming the field; nothing is stored (R12,
R17, R18)."""

from __future__ import annotations

import json
import socket

import httpx
import pytest

from tests.service.svc_helpers import assert_problem, scenario, submit, wait_for


def _job_count(http: httpx.Client) -> int:
    return len(http.get("/v1/jobs", params={"limit": 500}).json()["items"])


def _post_raw(http: httpx.Client, raw: str | bytes) -> httpx.Response:
    return http.post("/v1/jobs", content=raw, headers={"Content-Type": "application/json"})


@pytest.mark.parametrize(
    ("mutate", "loc"),
    [
        (lambda s: s["model"].update(kind="no-such-model"), "scenario.model"),
        (lambda s: s["time"].update(steps=True), "scenario.time.steps"),
        (lambda s: s["time"].update(steps="10"), "scenario.time.steps"),
        (lambda s: s["time"].update(dt=-0.1), "scenario.time.dt"),
        (lambda s: s["time"].update(dt=0), "scenario.time.dt"),
        (lambda s: s["model"].update(eta="high"), "scenario.model.eta"),
        (lambda s: s.update(colour="red"), "scenario.colour"),
        (lambda s: s["initial"].update(N=0), "scenario.initial.N"),
        # Past int32, where a kernel argument would overflow: refused, not a failed job.
        (lambda s: s.update(recording={"observables_every": 2**31}),
         "scenario.recording.observables_every"),
    ],
    ids=["unknown-model", "bool-for-int", "string-for-int", "negative-dt", "zero-dt",
         "string-for-float", "extra-field", "zero-agents", "observables-every-past-int32"],
)
def test_invalid_scenario_is_422_naming_the_field(http, mutate, loc):
    before = _job_count(http)
    body = scenario()
    mutate(body)
    assert_problem(http.post("/v1/jobs", json={"scenario": body}), 422, loc)
    assert _job_count(http) == before


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity", "1e400", "-1e999"])
def test_non_finite_numbers_are_422_not_500(http, token):
    """FastAPI's default answers 500 to these (fastapi#459)."""
    before = _job_count(http)
    raw = json.dumps({"scenario": scenario()}).replace('"eta": 0.5', f'"eta": {token}')
    assert token in raw
    body = assert_problem(_post_raw(http, raw), 422, "scenario.model.eta")
    assert "finite" in body["errors"][0]["msg"]
    # Also in a bare scenario and in preset overrides.
    raw = json.dumps(scenario()).replace('"dt": 1.0', f'"dt": {token}')
    assert_problem(_post_raw(http, raw), 422, "time.dt")
    raw = json.dumps({"preset": "vicsek-1995", "overrides": {"space": {"L": 7}}})
    raw = raw.replace("7", token)
    assert_problem(_post_raw(http, raw), 422, "overrides.space.L")
    assert _job_count(http) == before


def test_malformed_and_non_object_bodies(http):
    assert_problem(_post_raw(http, b'{"scenario": '), 400)
    assert_problem(_post_raw(http, b"\xff\xfe"), 400)
    assert_problem(_post_raw(http, b"[1, 2]"), 422, "(root)")
    assert_problem(http.post("/v1/jobs", json={"preset": "vicsek-1995", "scenario": scenario()}),
                   422)
    assert_problem(http.post("/v1/jobs", json={"preset": "no-such-preset"}), 422, "preset")
    assert_problem(http.post("/v1/jobs", json={"scenario": scenario(), "timeout_seconds": -1}),
                   422, "timeout_seconds")


@pytest.mark.parametrize(
    ("body", "loc"),
    [
        (scenario(n=5001, every=0), "initial.N"),
        (scenario(steps=200_001, every=0), "time.steps"),
        # 5000 agents x 3 values x 8 B x 1001 frames = 120 MB > 8 MiB.
        (scenario(n=5000, steps=1000, every=1), "recording.every"),
    ],
    ids=["agents", "steps", "trajectory-bytes"],
)
def test_over_the_service_limits_is_422_naming_the_field(http, body, loc):
    before = _job_count(http)
    problem = assert_problem(http.post("/v1/jobs", json={"scenario": body}), 422, loc)
    assert problem["type"].endswith("limit-exceeded")
    assert "limit" in problem["detail"]
    assert _job_count(http) == before


def test_the_trajectory_limit_counts_float32_frames_and_the_image(http):
    # 81 frames x 4000 agents x (position + heading, + the int32 x 2 periodic image):
    # 32 B a row in float64 = 10.4 MB > 8 MiB; 20 B in float32 = 6.5 MB, under it.
    body = scenario(n=4000, steps=80, every=1)
    problem = assert_problem(http.post("/v1/jobs", json={"scenario": body}), 422,
                             "recording.every")
    assert "9.9 MiB" in problem["detail"], problem["detail"]
    body["recording"]["precision"] = "float32"
    assert http.post("/v1/jobs", json={"scenario": body}).status_code == 202


def test_oversized_body_is_413_before_parsing(http, server):
    before = _job_count(http)
    big = b'{"scenario": {"name": "' + b"x" * 300_000 + b'"}}'
    body = assert_problem(_post_raw(http, big), 413)
    assert body["max_bytes"] == 256 * 1024

    # Chunked (no Content-Length): counted while streaming.
    def chunks():
        yield b'{"scenario": {"name": "'
        for _ in range(40):
            yield b"x" * 10_000
        yield b'"}}'

    r = http.post("/v1/jobs", content=chunks(), headers={"Content-Type": "application/json"})
    assert "content-length" not in r.request.headers
    assert_problem(r, 413)
    assert _job_count(http) == before


def test_a_lying_content_length_is_refused_without_reading_the_body(real_server):
    """A huge declared length is answered at once, before any body byte is sent."""
    with socket.create_connection(("127.0.0.1", real_server.port), timeout=10) as sock:
        sock.sendall(b"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                     b"Content-Length: 10000000000\r\n\r\n")
        reply = sock.recv(4096).decode()
    assert reply.startswith("HTTP/1.1 413"), reply
    assert "application/problem+json" in reply


def test_query_and_path_errors_are_problems(http):
    assert_problem(http.get("/v1/jobs/not-a-uuid"), 422, "path.job_id")
    assert_problem(http.get("/v1/jobs", params={"limit": 0}), 422, "query.limit")
    assert_problem(http.get("/v1/jobs", params={"status": "exploded"}), 422, "query.status.0")
    assert_problem(http.get("/v1/jobs", params={"cursor": "not-a-cursor"}), 422, "query.cursor")
    assert_problem(http.get("/no/such/route"), 404)
    assert_problem(http.delete("/v1/models"), 405)


def test_observables_a_model_does_not_report_are_422_naming_them(http):
    """recording.observables through the service: a flocking run naming M3's radius_min or
    a formation run naming Vicsek's polarization is refused before anything is stored."""
    before = _job_count(http)
    for preset, bad, kind in (("tjp-switching", "radius_min", "flocking"),
                              ("xi-abed-sim3", "polarization", "formation")):
        body = assert_problem(http.post("/v1/jobs", json={
            "preset": preset, "overrides": {"recording": {"observables": ["components", bad]}}}),
            422)
        assert f"{bad} not reported by model {kind}" in json.dumps(body)
    assert _job_count(http) == before


@pytest.mark.slow
def test_a_run_reports_the_observables_it_names(http):
    """A formation F2 job naming three observables (D3 left out) returns those alone."""
    job = submit(http, {"preset": "xi-abed-sim3", "overrides": {
        "time": {"steps": 40}, "recording": {"every": 0, "observables": ["V2", "D1", "D2"]}}})
    assert wait_for(http, job["id"])["status"] == "succeeded"
    obs = http.get(f"/v1/jobs/{job['id']}/metrics").json()["observables"]
    assert set(obs) == {"step", "time", "V2", "D1", "D2"}
    assert len(obs["V2"]) == len(obs["step"]) > 1
