"""Every error response as RFC 9457 problem details (`application/problem+json`).

Handlers cover our own `ProblemError`, FastAPI's request validation (query and path
parameters; bodies are parsed by hand), Starlette's HTTP errors (404 for unknown routes,
405, ...) and anything unexpected (500, without internals in the body).
"""

from __future__ import annotations

import logging
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from schemas import FieldError
from schemas.problems import json_safe
from service.jobs.problems import problem

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
    body = dict(body)
    if request is not None:
        body.setdefault("instance", request.url.path)
    return JSONResponse(json_safe(body), status_code=body["status"], headers=headers,
                        media_type=PROBLEM_MEDIA_TYPE)


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


async def _on_unexpected(request: Request, exc: Exception) -> JSONResponse:
    log.exception("unhandled error on %s %s", request.method, request.url.path)
    return problem_response(problem("internal-error", "Internal Server Error", 500,
                                    "an unexpected error occurred; it has been logged"), request)


def install_problem_handlers(app: FastAPI) -> None:
    app.add_exception_handler(ProblemError, _on_problem)
    app.add_exception_handler(RequestValidationError, _on_validation)
    app.add_exception_handler(StarletteHTTPException, _on_http)
    app.add_exception_handler(Exception, _on_unexpected)
