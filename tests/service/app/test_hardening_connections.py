"""Issue 12, finding 2: connections that never finish a request are closed (408), a cap on
open connections answers 503, /healthz stays reachable, and the log stays small. Raw
sockets on loopback against a real server with short timeouts and a small cap."""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator

import httpx
import pytest

from flocklab.service.app.connections import RESERVED_FDS, connection_cap
from flocklab.service.serve import ServerProcess
from tests.service.conftest import TEST_ENV, _serve
from tests.service.svc_helpers import long_scenario, submit

CAP = 16
TIMEOUT = 1.0


@pytest.fixture(scope="module")
def guarded(tmp_path_factory) -> Iterator[ServerProcess]:
    """One real server for the module (the limits are uvicorn's, on a socket); the first
    test reads its log, before the others add to it."""
    yield from _serve(tmp_path_factory.mktemp("guarded") / "data", {
        **TEST_ENV, "FLOCKLAB_HEADER_TIMEOUT_SECONDS": str(TIMEOUT),
        "FLOCKLAB_BODY_TIMEOUT_SECONDS": str(TIMEOUT), "FLOCKLAB_MAX_CONNECTIONS": str(CAP)})


def _connect(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    s.settimeout(10)
    return s


def _read_all(s: socket.socket) -> bytes:
    """Everything until the server closes the connection."""
    out = b""
    while chunk := s.recv(65536):
        out += chunk
    return out


def _read_response(s: socket.socket) -> bytes:
    """One response with a Content-Length body, leaving the connection open."""
    raw = b""
    while b"\r\n\r\n" not in raw:
        raw += s.recv(65536)
    head, _, body = raw.partition(b"\r\n\r\n")
    length = next(int(line.split(b":")[1]) for line in head.split(b"\r\n")
                  if line.lower().startswith(b"content-length:"))
    while len(body) < length:
        body += s.recv(65536)
    return head + b"\r\n\r\n" + body


def _problem(raw: bytes, status: int) -> dict:
    head, _, body = raw.partition(b"\r\n\r\n")
    assert head.startswith(f"HTTP/1.1 {status} ".encode()), raw[:200]
    assert b"content-type: application/problem+json" in head.lower()
    problem = json.loads(body)
    assert problem["status"] == status
    return problem


@pytest.mark.slow
def test_slow_headers_get_408_and_the_cap_answers_503(guarded):
    socks = [_connect(guarded.port) for _ in range(CAP - 1)]
    try:
        for s in socks:  # a request line and half a header, never finished
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        time.sleep(0.3)
        # One connection below the cap is left: a full request on it is served.
        with _connect(guarded.port) as ok:
            ok.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            assert _read_all(ok).startswith(b"HTTP/1.1 200 ")
        # Over the cap: refused at once with a problem, before sending anything.
        held = _connect(guarded.port)
        socks.append(held)
        time.sleep(0.2)
        with _connect(guarded.port) as over:
            body = _problem(_read_all(over), 503)
            assert body["type"].endswith("too-many-connections")
        # Within the timeout (plus slack for a loaded machine) every slow one is closed.
        started = time.monotonic()
        for s in socks:
            raw = _read_all(s)
            assert _problem(raw, 408)["type"].endswith("request-timeout")
        assert time.monotonic() - started < TIMEOUT + 5
    finally:
        for s in socks:
            s.close()
    assert httpx.get(f"{guarded.url}/healthz", timeout=10).status_code == 200
    # One line per kind of event and interval, not one per connection.
    log = guarded.log_path.read_text()
    assert 1 <= log.count("did not arrive in time") <= 2, log[-2000:]
    assert log.count("over the cap") == 1


def test_a_slow_body_gets_408(guarded):
    with _connect(guarded.port) as s:
        s.sendall(b"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                  b"Content-Length: 1000\r\n\r\n{\"preset\": ")
        started = time.monotonic()
        body = _problem(_read_all(s), 408)
        assert "body" in body["detail"]
        assert time.monotonic() - started < TIMEOUT + 5


def test_keep_alive_then_a_stalled_second_request_is_closed(guarded):
    with _connect(guarded.port) as s:
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        assert _read_response(s).startswith(b"HTTP/1.1 200 ")
        s.sendall(b"GET /healthz HTTP/1.1\r\nHo")  # the next request stalls mid-header
        assert _problem(_read_all(s), 408)["type"].endswith("request-timeout")


@pytest.mark.slow
def test_idle_keep_alive_is_bounded_by_keep_alive_not_the_header_timeout(guarded):
    """Between requests the keep-alive setting (5 s) applies, not the 1 s header limit."""
    with _connect(guarded.port) as s:
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        assert _read_response(s).startswith(b"HTTP/1.1 200 ")
        time.sleep(TIMEOUT + 0.5)
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        assert _read_response(s).startswith(b"HTTP/1.1 200 ")


@pytest.mark.slow
def test_a_stream_outlives_the_request_timeouts(guarded):
    """The deadlines bound a request's arrival, never its response."""
    with httpx.Client(base_url=guarded.url, timeout=30) as http:
        job = submit(http, {"scenario": long_scenario()})
        try:
            events = 0
            started = time.monotonic()
            with http.stream("GET", f"/v1/jobs/{job['id']}/events") as r:
                for line in r.iter_lines():
                    events += line.startswith("event: job")
                    if time.monotonic() - started > TIMEOUT + 1.5:
                        break
            assert events >= 2
        finally:
            http.post(f"/v1/jobs/{job['id']}/cancel")


def test_the_cap_stays_under_the_open_file_limit():
    assert connection_cap(10_000, 1024) == 1024 - RESERVED_FDS
    assert connection_cap(100, 1024) == 100
