"""Issue 28, finding 4: one client holding connections (event streams, or reconnecting
with headers it never finishes) must not get every other client a 503, and `/healthz`
answers even when the global cap is full. On Linux all of 127.0.0.0/8 is loopback, so
sockets bound to 127.0.0.2, .3, ... are different clients of the real server."""

from __future__ import annotations

import json
import socket
import time

import httpx
import pytest

from tests.service.svc_helpers import long_scenario, submit

CAP = 24
PER_CLIENT = 6
HEADROOM = 2


@pytest.fixture
def fair(make_server):
    return make_server({"FLOCKLAB_HEADER_TIMEOUT_SECONDS": "30",
                        "FLOCKLAB_MAX_CONNECTIONS": str(CAP),
                        "FLOCKLAB_MAX_CONNECTIONS_PER_CLIENT": str(PER_CLIENT),
                        "FLOCKLAB_HEALTHZ_HEADROOM": str(HEADROOM)})


def _connect(port: int, source: str) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.settimeout(10)
    s.bind((source, 0))
    s.connect(("127.0.0.1", port))
    return s


def _read_all(s: socket.socket) -> bytes:
    out = b""
    while chunk := s.recv(65536):
        out += chunk
    return out


def _get(port: int, source: str, path: str) -> tuple[bytes, float]:
    """One request with Connection: close from `source`; the raw response and its time."""
    started = time.monotonic()
    with _connect(port, source) as s:
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".encode())
        raw = _read_all(s)
    return raw, time.monotonic() - started


def _status(raw: bytes) -> int:
    return int(raw.split(b" ", 2)[1])


def _hold(port: int, source: str, n: int) -> list[socket.socket]:
    """`n` connections from `source` that send half a header and stall."""
    socks = []
    for _ in range(n):
        s = _connect(port, source)
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: ")
        socks.append(s)
    time.sleep(0.3)
    return socks


@pytest.mark.slow
def test_one_client_at_its_cap_leaves_others_served(fair):
    # The hostile client tries for the whole global cap; it gets its own share only.
    held = _hold(fair.port, "127.0.0.2", CAP)
    try:
        refused = 0
        for s in held[PER_CLIENT:]:
            raw = _read_all(s)
            assert _status(raw) == 503, raw[:200]
            body = json.loads(raw.partition(b"\r\n\r\n")[2])
            assert body["type"].endswith("too-many-connections")
            assert f"this client holds its maximum of {PER_CLIENT}" in body["detail"]
            assert b"retry-after: 1" in raw.lower()
            refused += 1
        assert refused == CAP - PER_CLIENT
        # Another client's /healthz (and API) answer at once.
        raw, took = _get(fair.port, "127.0.0.3", "/healthz")
        assert _status(raw) == 200 and took < 1.0, (raw[:200], took)
        raw, took = _get(fair.port, "127.0.0.3", "/v1/jobs")
        assert _status(raw) == 200 and took < 1.0, (raw[:200], took)
        # The hostile client's held connections are still open (counted, not dropped).
        raw, _ = _get(fair.port, "127.0.0.2", "/healthz")
        assert _status(raw) == 503
    finally:
        for s in held:
            s.close()
    time.sleep(0.3)  # its connections closed: it is served again
    raw, _ = _get(fair.port, "127.0.0.2", "/healthz")
    assert _status(raw) == 200


@pytest.mark.slow
def test_event_streams_of_one_client_leave_others_served(fair):
    """Event streams are responses: the deadlines never cut them, the per-client cap
    bounds how many one client holds."""
    with httpx.Client(base_url=fair.url, timeout=30) as http:
        job = submit(http, {"scenario": long_scenario()})
    streams = []
    try:
        for _ in range(CAP):
            s = _connect(fair.port, "127.0.0.4")
            s.sendall(f"GET /v1/jobs/{job['id']}/events HTTP/1.1\r\nHost: x\r\n"
                      f"Accept: text/event-stream\r\n\r\n".encode())
            streams.append(s)
        time.sleep(0.5)
        first = [s.recv(64) for s in streams]
        assert all(f.startswith(b"HTTP/1.1 200 ") for f in first[:PER_CLIENT]), first
        assert all(f.startswith(b"HTTP/1.1 503 ") for f in first[PER_CLIENT:]), first
        raw, took = _get(fair.port, "127.0.0.5", "/healthz")
        assert _status(raw) == 200 and took < 1.0, (raw[:200], took)
    finally:
        for s in streams:
            s.close()
        with httpx.Client(base_url=fair.url, timeout=30) as http:
            http.post(f"/v1/jobs/{job['id']}/cancel")


@pytest.mark.slow
def test_healthz_answers_when_many_clients_fill_the_cap(fair):
    """Past the global cap only /healthz gets in (the headroom), one request each."""
    clients = [f"127.0.1.{i}" for i in range(1, CAP // PER_CLIENT + 1)]
    held = [s for c in clients for s in _hold(fair.port, c, PER_CLIENT)]
    try:
        raw, took = _get(fair.port, "127.0.0.9", "/healthz")
        assert _status(raw) == 200 and took < 1.0, (raw[:200], took)
        raw, _ = _get(fair.port, "127.0.0.9", "/v1/jobs")
        assert _status(raw) == 503, raw[:200]
        assert b"the server holds its maximum" in raw
        # A keep-alive /healthz in the headroom is closed after its one response.
        with _connect(fair.port, "127.0.0.9") as s:
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
            raw = _read_all(s)
        assert _status(raw) == 200 and raw.count(b"HTTP/1.1") == 1
        # The headroom is not a second cap to fill: its connections are freed.
        for _ in range(3 * HEADROOM):
            raw, _ = _get(fair.port, "127.0.0.9", "/healthz")
            assert _status(raw) == 200
    finally:
        for s in held:
            s.close()
    time.sleep(0.3)
    raw, _ = _get(fair.port, "127.0.0.9", "/v1/jobs")
    assert _status(raw) == 200
