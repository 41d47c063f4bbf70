"""Connection limits uvicorn lacks: request timeouts, a connection cap, quiet logs.

Uvicorn's h11 protocol bounds only the idle gap after a response (`timeout_keep_alive`):
a connection that never finishes its request line, headers or body stays open forever,
and enough of them exhaust the file descriptors (then every route, /healthz included,
times out and asyncio logs each failed accept). `GuardedH11Protocol` adds:

- a deadline for the request line and headers (`header_timeout_seconds`, counted from
  the connection's start or from the moment the next request's first bytes arrive) and
  one for the body (`body_timeout_seconds`, counted from the end of the headers); when one
  passes, the client gets `408` problem+json (if no response has started) and the
  connection is closed;
- a cap on open connections (`max_connections`, kept below the open-file limit): one
  over it is answered `503` problem+json at once and closed, before it holds anything;
- a cap per client (`max_connections_per_client`, by peer IP address, below the global
  cap): one client holding many event streams, or reconnecting with headers it never
  finishes, is refused on its own connections long before it fills the server, so other
  clients still get in;
- headroom for `/healthz` (`healthz_headroom` connections past the global cap): such a
  connection is served only if its request line is `GET` or `HEAD /healthz`, and closed
  after that one response, so a liveness probe answers even when clients fill the cap;
- one log line per kind of event and interval with a count, instead of a line per
  connection (`QuietLog`), and the same for uvicorn's and asyncio's per-connection lines.

It subclasses uvicorn's `H11Protocol` (uvicorn 0.29-0.54: `connection_made`,
`data_received`, `on_response_complete`, `connection_lost`, `self.conn`, `self.cycle`),
selected with `uvicorn.Config(http=...)`.
"""

from __future__ import annotations

import asyncio
import json
import logging
import resource
import threading
import time
from dataclasses import dataclass
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from flocklab.service.jobs.problems import problem

log = logging.getLogger("flocklab.connections")

# Descriptors kept free for everything but client sockets: the SQLite store, result files
# being served, worker pipes, the log.
RESERVED_FDS = 128
LOG_INTERVAL_SECONDS = 10.0
# A refused connection is kept this long, discarding what the client sends, so that it
# reads the 503 rather than a reset (closing on unread input sends an RST); beyond
# MAX_LINGERING such connections at once, they are closed at once.
LINGER_SECONDS = 0.5
MAX_LINGERING = 64


@dataclass(frozen=True)
class ConnectionLimits:
    header_timeout: float
    body_timeout: float
    max_connections: int
    max_per_client: int
    healthz_headroom: int


def raise_fd_limit() -> int:
    """Raise the soft open-file limit to the hard one (capped at 65536); return it."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = min(hard, 65536) if hard != resource.RLIM_INFINITY else 65536
    if target > soft:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            soft = target
        except (ValueError, OSError):
            pass
    return soft


def connection_cap(wanted: int, fd_limit: int, headroom: int = 0) -> int:
    """`wanted`, lowered so that the cap (and the /healthz headroom above it) can always be
    answered before descriptors run out."""
    return max(1, min(wanted, fd_limit - RESERVED_FDS - headroom))


# The longest request line a /healthz headroom connection may take to show its target.
MAX_PROBE_LINE = 8192


def is_healthz_line(head: bytes) -> bool:
    """Whether a request line (up to its CRLF) asks for GET or HEAD /healthz."""
    parts = head.split(b" ")
    return (len(parts) == 3 and parts[0] in (b"GET", b"HEAD")
            and parts[1].split(b"?", 1)[0] == b"/healthz")


def peer_host(transport: Any) -> str:
    """The client's address without its port (connections from one host share a quota)."""
    peer = transport.get_extra_info("peername")
    if isinstance(peer, tuple) and peer:
        return str(peer[0])
    return "local"  # a Unix socket: every client is this host


class QuietLog:
    """Counts events by kind and logs each kind at most once per interval, with the count
    since its last line: a flood of bad connections costs a few lines a minute."""

    def __init__(self, logger: logging.Logger, interval: float = LOG_INTERVAL_SECONDS):
        self.logger = logger
        self.interval = interval
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}
        self._last: dict[str, float] = {}

    def note(self, kind: str, message: str) -> None:
        with self._lock:
            self._counts[kind] = self._counts.get(kind, 0) + 1
            now = time.monotonic()
            if now - self._last.get(kind, -1e18) < self.interval:
                return
            count, self._counts[kind], self._last[kind] = self._counts[kind], 0, now
        self.logger.warning("%s (%d in the last %.0f s)", message, count, self.interval)


class RateLimitFilter(logging.Filter):
    """Lets through at most one record per message template and interval, for the given
    templates (uvicorn's and asyncio's per-connection warnings); the next one that passes
    says how many were dropped."""

    def __init__(self, templates: tuple[str, ...], interval: float = LOG_INTERVAL_SECONDS):
        super().__init__()
        self.templates = templates
        self.interval = interval
        self._lock = threading.Lock()
        self._last: dict[str, float] = {}
        self._dropped: dict[str, int] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        template = str(record.msg)
        if not template.startswith(self.templates):
            return True
        with self._lock:
            now = time.monotonic()
            if now - self._last.get(template, -1e18) < self.interval:
                self._dropped[template] = self._dropped.get(template, 0) + 1
                return False
            self._last[template] = now
            dropped = self._dropped.pop(template, 0)
        if dropped:
            record.msg = f"{record.msg} ({dropped} similar lines dropped)"
        return True


NOISY_TEMPLATES = ("Invalid HTTP request received", "Exceeded concurrency limit",
                   "socket.accept() out of system resource", "Unsupported upgrade request",
                   "No supported WebSocket library detected")


def quiet_noisy_loggers() -> None:
    """Rate-limit the per-connection warnings of uvicorn and asyncio."""
    flt = RateLimitFilter(NOISY_TEMPLATES)
    for name in ("uvicorn.error", "asyncio"):
        logging.getLogger(name).addFilter(flt)


def _raw_problem(status: int, slug: str, title: str, detail: str,
                 headers: dict[str, str] | None = None) -> bytes:
    """A complete HTTP/1.1 response with a problem body that closes the connection."""
    body = json.dumps(problem(slug, title, status, detail)).encode()
    head = (f"HTTP/1.1 {status} {title}\r\ncontent-type: application/problem+json\r\n"
            f"content-length: {len(body)}\r\nconnection: close\r\n")
    for name, value in (headers or {}).items():
        head += f"{name.lower()}: {value}\r\n"
    return head.encode() + b"\r\n" + body


def guarded_protocol(limits: ConnectionLimits) -> type[H11Protocol]:
    """uvicorn's h11 protocol with the limits above (a class per server's limits)."""
    quiet = QuietLog(log)
    retry = {"Retry-After": "1"}
    refused = _raw_problem(503, "too-many-connections", "Service Unavailable",
                           f"the server holds its maximum of {limits.max_connections} "
                           f"connections; retry shortly", retry)
    client_refused = _raw_problem(
        503, "too-many-connections", "Service Unavailable",
        f"this client holds its maximum of {limits.max_per_client} connections; close "
        f"some (event streams, idle keep-alives) or retry shortly", retry)
    header_late = _raw_problem(408, "request-timeout", "Request Timeout",
                               f"the request line and headers did not arrive within "
                               f"{limits.header_timeout:g} s")
    body_late = _raw_problem(408, "request-timeout", "Request Timeout",
                             f"the request body did not arrive within "
                             f"{limits.body_timeout:g} s of its headers")

    lingering = 0
    # Connections served (not refused): within the cap, in the /healthz headroom, by host.
    admitted = 0
    probes = 0
    per_client: dict[str, int] = {}

    class GuardedH11Protocol(H11Protocol):
        _deadline: asyncio.TimerHandle | None = None
        _phase: str | None = None  # "headers" | "body" while a deadline runs
        _refused = False
        _host: str | None = None  # the client, while the connection is counted
        _slot: str | None = None  # what it is counted in: "cap" or "headroom"
        _probe: bytes | None = None  # headroom connection: its bytes until the request line
        _closes_after_response = False  # a headroom connection that asked for /healthz

        def connection_made(self, transport: Any) -> None:
            nonlocal admitted, probes
            super().connection_made(transport)
            host = peer_host(transport)
            # A client at its own cap gets neither a connection nor the headroom.
            over_client = per_client.get(host, 0) >= limits.max_per_client
            if admitted >= limits.max_connections:
                if over_client or probes >= limits.healthz_headroom:
                    quiet.note("cap", f"refused connections over the cap of "
                                      f"{limits.max_connections}")
                    self._refuse(transport, refused)
                    return
                probes += 1
                self._probe, self._slot = b"", "headroom"
            elif over_client:
                quiet.note("client-cap", f"refused connections over the per-client cap of "
                                         f"{limits.max_per_client}")
                self._refuse(transport, client_refused)
                return
            else:
                admitted += 1
                self._slot = "cap"
            self._host = host
            per_client[host] = per_client.get(host, 0) + 1
            self._arm("headers")

        def _refuse(self, transport: Any, answer: bytes) -> None:
            nonlocal lingering
            self._refused = True
            transport.write(answer)
            if lingering >= MAX_LINGERING:
                transport.close()
                return
            lingering += 1

            def close() -> None:
                nonlocal lingering
                lingering -= 1
                transport.close()

            self.loop.call_later(LINGER_SECONDS, close)

        def data_received(self, data: bytes) -> None:
            if self._refused:
                return  # answered already; this is the request we refused
            if self._probe is not None:
                data = self._screen_probe(data)
                if not data:
                    return
            super().data_received(data)
            self._follow()

        def _screen_probe(self, data: bytes) -> bytes:
            """A headroom connection's bytes, held back until its request line shows
            whether it is /healthz; then all of them, or b"" (and a 503) if it is not."""
            assert self._probe is not None
            self._probe += data
            line, crlf, _ = self._probe.partition(b"\r\n")
            if not crlf and len(self._probe) < MAX_PROBE_LINE:
                return b""
            if crlf and is_healthz_line(line):
                data, self._probe = self._probe, None
                self._closes_after_response = True
                return data
            quiet.note("cap", f"refused connections over the cap of {limits.max_connections}")
            self._disarm()
            self._probe = None
            self._release()
            self._refuse(self.transport, refused)
            return b""

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if self._closes_after_response:  # headroom serves one /healthz, then frees
                self.transport.close()
                return
            # Pipelined bytes may already hold (part of) the next request.
            self._follow()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            self._release()
            super().connection_lost(exc)

        def _release(self) -> None:
            """Uncount this connection (once)."""
            nonlocal admitted, probes
            if self._host is None:
                return
            if self._slot == "headroom":
                probes -= 1
            else:
                admitted -= 1
            left = per_client[self._host] - 1
            if left:
                per_client[self._host] = left
            else:
                del per_client[self._host]
            self._host = self._slot = None

        def _follow(self) -> None:
            """Keep the deadline that fits how far the current request has arrived."""
            if self.transport is None or self.transport.is_closing():
                self._disarm()
                return
            state = self.conn.their_state
            if state is h11.IDLE:
                # Nothing of the next request yet: the keep-alive timer bounds the gap.
                waiting = self.conn.trailing_data[0] or self.timeout_keep_alive_task is None
                if waiting and self._phase != "headers":
                    self._arm("headers")
                elif not waiting:
                    self._disarm()
            elif state is h11.SEND_BODY:
                if self._phase != "body":
                    self._arm("body")
            else:  # the request has fully arrived (or the connection is ending)
                self._disarm()

        def _arm(self, phase: str) -> None:
            self._disarm()
            delay = limits.header_timeout if phase == "headers" else limits.body_timeout
            self._phase = phase
            self._deadline = self.loop.call_later(delay, self._expired)

        def _disarm(self) -> None:
            if self._deadline is not None:
                self._deadline.cancel()
            self._deadline, self._phase = None, None

        def _expired(self) -> None:
            phase, self._deadline, self._phase = self._phase, None, None
            if self.transport.is_closing():
                return
            quiet.note(f"timeout-{phase}", f"closed connections whose request {phase} did "
                                           f"not arrive in time")
            if self.cycle is None or self.cycle.response_complete or (
                    not self.cycle.response_started):
                self.transport.write(header_late if phase == "headers" else body_late)
            self.transport.close()

    return GuardedH11Protocol
