"""Every error response as RFC 9457 problem details (`application/problem+json`).

Handlers cover our own `ProblemError`, FastAPI's request validation (query and path
parameters; bodies are parsed by hand) and Starlette's HTTP errors (404 for unknown routes,
405, ...). Anything unexpected is caught by `UnexpectedErrorMiddleware` rather than a
handler for `Exception`: Starlette re-raises after such a handler answered, and uvicorn
then closes the keep-alive connection, so a pooled client's next request on it failed.
A full disk (ENOSPC, SQLite's "database or disk is full") is a 503, not a 500.
"""

from __future__ import annotations

import json
import logging
from http import HTTPStatus
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from flocklab.schemas import FieldError
from flocklab.schemas.problems import json_safe
from flocklab.service.jobs.disk import is_disk_full
from flocklab.service.jobs.problems import bounded, problem

PROBLEM_MEDIA_TYPE = "application/problem+json"
log = logging.getLogger("flocklab.api")


class ProblemError(Exception):
    """Raise anywhere in a request to answer with a problem body."""

    def __init__(self, status: int, slug: str, title: str, detail: str | None = None, *,
                 errors: list[FieldError] | None = None, headers: dict[str, str] | None = None,
                 **extra: Any):
        super().__init__(detail or title)
        self.body = problem(slug, title, status, detail, **extra)
        if errors is not None:
            self.body["errors"] = [e.model_dump() for e in errors]
        self.status = status
        self.headers = headers


def invalid(errors: list[FieldError], detail: str | None = None) -> ProblemError:
    """422 naming every invalid field."""
    first = errors[0] if errors else None
    return ProblemError(422, "validation-error", "Invalid request",
                        detail or (f"{first.loc}: {first.msg}" if first else None), errors=errors)


def problem_response(body: dict[str, Any], request: Request | None = None,
                     headers: dict[str, str] | None = None) -> JSONResponse:
    body = bounded(body)
    if request is not None:
        body.setdefault("instance", request.url.path)
        body = _without_data_dir(body, request)
    return JSONResponse(json_safe(body), status_code=body["status"], headers=headers,
                        media_type=PROBLEM_MEDIA_TYPE)


def _without_data_dir(body: dict[str, Any], request: Request) -> dict[str, Any]:
    """`body` with the server's data directory replaced by `<data>` wherever a message
    carries it: the last guard of the rule that no body shows a server path (the error
    paths scrub their own messages; a new one that forgets is caught here)."""
    settings = getattr(request.app.state, "settings", None)
    if settings is None:
        return body
    text = json.dumps(json_safe(body))
    roots = {str(settings.data_dir), str(Path(settings.data_dir).resolve())}
    hits = sorted((r for r in roots if len(r) > 1 and json.dumps(r)[1:-1] in text),
                  key=len, reverse=True)  # the longer first: one may contain the other
    for root in hits:
        text = text.replace(json.dumps(root)[1:-1], "<data>")
    return json.loads(text) if hits else body


async def _on_problem(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ProblemError)
    return problem_response(exc.body, request, exc.headers)


async def _on_validation(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors = [
        FieldError(loc=".".join(str(p) for p in e.get("loc", ())) or "(root)",
                   msg=str(e.get("msg", "")), type=str(e.get("type", "value_error")))
        for e in exc.errors()
    ]
    return problem_response(invalid(errors).body, request)


async def _on_http(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    title = HTTPStatus(exc.status_code).phrase
    detail = exc.detail if isinstance(exc.detail, str) and exc.detail != title else None
    body = problem(title.lower().replace(" ", "-"), title, exc.status_code, detail)
    return problem_response(body, request, dict(exc.headers) if exc.headers else None)


DISK_FULL_RETRY_AFTER = 60


class UnexpectedErrorMiddleware:
    """Any exception a route did not turn into a problem: logged, answered as a problem
    (503 for a full disk, else 500) and not re-raised, so the connection stays usable.
    An exception after the response started is re-raised: the connection must close so
    the client sees a truncated body rather than a complete-looking one."""

    def __init__(self, app: ASGIApp):
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracking_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, tracking_send)
        except ClientDisconnect:
            return  # the client left (or was cut off by a timeout): nobody to answer
        except Exception as exc:
            if started:
                raise
            headers: list[tuple[bytes, bytes]] = []
            if is_disk_full(exc):
                log.error("disk full on %s %s: %s", scope["method"], scope["path"], exc)
                body = problem("insufficient-storage", "Out of disk space", 503,
                               "the server's data disk is full; retry later")
                headers.append((b"retry-after", str(DISK_FULL_RETRY_AFTER).encode()))
            else:
                log.exception("unhandled error on %s %s", scope["method"], scope["path"])
                body = problem("internal-error", "Internal Server Error", 500,
                               "an unexpected error occurred; it has been logged")
            body["instance"] = scope["path"]
            payload = json.dumps(body).encode()
            await send({"type": "http.response.start", "status": body["status"], "headers": [
                (b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                (b"content-length", str(len(payload)).encode()), *headers]})
            await send({"type": "http.response.body", "body": payload})


def install_problem_handlers(app: FastAPI) -> None:
    app.add_exception_handler(ProblemError, _on_problem)
    app.add_exception_handler(RequestValidationError, _on_validation)
    app.add_exception_handler(StarletteHTTPException, _on_http)
