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


def connection_cap(wanted: int, fd_limit: int) -> int:
    """`wanted`, lowered so that the cap can always be answered before descriptors run out."""
    return max(1, min(wanted, fd_limit - RESERVED_FDS))


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


def _raw_problem(status: int, slug: str, title: str, detail: str) -> bytes:
    """A complete HTTP/1.1 response with a problem body that closes the connection."""
    body = json.dumps(problem(slug, title, status, detail)).encode()
    head = (f"HTTP/1.1 {status} {title}\r\ncontent-type: application/problem+json\r\n"
            f"content-length: {len(body)}\r\nconnection: close\r\n")
    if status == 503:
        head += "retry-after: 1\r\n"
    return head.encode() + b"\r\n" + body


def guarded_protocol(limits: ConnectionLimits) -> type[H11Protocol]:
    """uvicorn's h11 protocol with the limits above (a class per server's limits)."""
    quiet = QuietLog(log)
    refused = _raw_problem(503, "too-many-connections", "Service Unavailable",
                           f"the server holds its maximum of {limits.max_connections} "
                           f"connections; retry shortly")
    header_late = _raw_problem(408, "request-timeout", "Request Timeout",
                               f"the request line and headers did not arrive within "
                               f"{limits.header_timeout:g} s")
    body_late = _raw_problem(408, "request-timeout", "Request Timeout",
                             f"the request body did not arrive within "
                             f"{limits.body_timeout:g} s of its headers")

    lingering = 0

    class GuardedH11Protocol(H11Protocol):
        _deadline: asyncio.TimerHandle | None = None
        _phase: str | None = None  # "headers" | "body" while a deadline runs
        _refused = False

        def connection_made(self, transport: Any) -> None:
            super().connection_made(transport)
            if len(self.connections) > limits.max_connections:
                self._refuse(transport)
                return
            self._arm("headers")

        def _refuse(self, transport: Any) -> None:
            nonlocal lingering
            quiet.note("cap", f"refused connections over the cap of {limits.max_connections}")
            self._refused = True
            transport.write(refused)
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
            super().data_received(data)
            self._follow()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            # Pipelined bytes may already hold (part of) the next request.
            self._follow()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            super().connection_lost(exc)

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
