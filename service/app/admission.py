"""Checks every request with a body passes before a route reads it, cheapest first.

1. Content type (415): a body must be `application/json` (or `+json`). A browser page can
   send a cross-site form or `text/plain` POST without asking (no CORS preflight), but
   not `application/json`; refusing the others keeps pages the user visits from queueing
   jobs on a local service that has no API key (the CSRF stance, docs/SERVICE_HARDENING.md).
2. Disk reserve (503 + Retry-After): below `min_free_disk_bytes` free on the data disk,
   nothing new is accepted.
3. Queue full (429 + Retry-After): refused from a cached count before the body is read or
   parsed, so refusals under a burst are immediate. A request with an `Idempotency-Key`
   goes on to the store, which answers a replay with its job even when the queue is full.

A pure ASGI middleware keyed on "an unsafe method with a body", so routes added later get
the same checks; body-less POSTs (cancel) pass.
"""

from __future__ import annotations

import json
import logging
import time
from typing import Any

from starlette.types import ASGIApp, Receive, Scope, Send

from flocklab.service.jobs.disk import free_bytes
from flocklab.service.jobs.problems import problem

from .problems import PROBLEM_MEDIA_TYPE
from .queue_gauge import QueueGauge
from .settings import Settings

log = logging.getLogger("flocklab.api")

UNSAFE = frozenset({"POST", "PUT", "PATCH", "DELETE"})
DISK_RETRY_AFTER = 60
DISK_LOG_INTERVAL = 60.0


def is_json_media_type(value: str) -> bool:
    """`application/json` or `application/<x>+json`, with any parameters."""
    media = value.split(";", 1)[0].strip().lower()
    return media == "application/json" or (media.startswith("application/")
                                           and media.endswith("+json"))


def has_body(headers: dict[bytes, bytes]) -> bool:
    if b"transfer-encoding" in headers:
        return True
    try:
        return int(headers.get(b"content-length", b"0")) > 0
    except ValueError:
        return True  # the body limit answers a malformed length


class AdmissionMiddleware:
    def __init__(self, app: ASGIApp, settings: Settings):
        self.app = app
        self.settings = settings
        self._disk_logged = -1e9

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] not in UNSAFE:
            await self.app(scope, receive, send)
            return
        headers = dict(scope["headers"])
        content_type = headers.get(b"content-type", b"").decode("latin-1")
        body = has_body(headers)
        if (content_type or body) and not is_json_media_type(content_type):
            await _refuse(scope, send, problem(
                "unsupported-media-type", "Unsupported Media Type", 415,
                f"request bodies must be application/json, not "
                f"{content_type or 'a body without a Content-Type'}"),
                {"Accept-Post": "application/json"})
            return
        if body:
            refusal = self._admission_refusal(scope, headers)
            if refusal is not None:
                await _refuse(scope, send, *refusal)
                return
        await self.app(scope, receive, send)

    def _admission_refusal(self, scope: Scope, headers: dict[bytes, bytes]
                           ) -> tuple[dict[str, Any], dict[str, str]] | None:
        settings = self.settings
        if settings.min_free_disk_bytes > 0:
            free = free_bytes(settings.data_dir)
            if free < settings.min_free_disk_bytes:
                now = time.monotonic()
                if now - self._disk_logged >= DISK_LOG_INTERVAL:
                    self._disk_logged = now
                    log.warning("refusing submissions: %d bytes free on the data disk, under "
                                "the reserve of %d", free, settings.min_free_disk_bytes)
                return problem(
                    "insufficient-storage", "Out of disk space", 503,
                    "the server's data disk is below its free-space reserve; retry later"
                ), {"Retry-After": str(DISK_RETRY_AFTER)}
        if b"idempotency-key" in headers:
            return None
        gauge = queue_gauge(scope["app"])
        if gauge is None:
            return None
        queued = gauge.queued()
        if queued >= settings.max_queued:
            return queue_full(queued, settings.max_queued, gauge)
        return None


def queue_gauge(app: Any) -> QueueGauge | None:
    """The app's gauge, made on first use (None before the lifespan opened the store)."""
    gauge = getattr(app.state, "queue_gauge", None)
    runtime = getattr(app.state, "runtime", None)
    if gauge is None and runtime is not None:
        settings = getattr(app.state, "settings", None)
        gauge = app.state.queue_gauge = QueueGauge(
            runtime.store.path, workers=settings.workers if settings is not None else 1)
    return gauge


def queue_full(queued: int, max_queued: int, gauge: QueueGauge
               ) -> tuple[dict[str, Any], dict[str, str]]:
    """The 429 body and headers, Retry-After from the measured drain rate."""
    retry = gauge.retry_after(queued)
    return problem("queue-full", "Too many queued jobs",
                   429, f"{queued} jobs are waiting (limit {max_queued}); retry in about "
                   f"{retry} s", retry_after_seconds=retry), {"Retry-After": str(retry)}


async def _refuse(scope: Scope, send: Send, body: dict[str, Any], headers: dict[str, str]
                  ) -> None:
    body = {**body, "instance": scope.get("path")}
    payload = json.dumps(body).encode()
    raw = [(b"content-type", PROBLEM_MEDIA_TYPE.encode()),
           (b"content-length", str(len(payload)).encode())]
    raw += [(k.lower().encode(), v.encode()) for k, v in headers.items()]
    await send({"type": "http.response.start", "status": body["status"], "headers": raw})
    await send({"type": "http.response.body", "body": payload})
