"""The app factory: settings in, a FastAPI app out, whose lifespan owns the job runtime."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from http import HTTPStatus
from typing import Any

from fastapi import Depends, FastAPI
from fastapi.middleware.cors import CORSMiddleware
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse
from pydantic.json_schema import models_json_schema
from starlette.concurrency import run_in_threadpool

from flocklab.schemas import Problem, Scenario
from flocklab.schemas.sweep import Sweep
from flocklab.schemas.version import version
from flocklab.service.jobs import JobRuntime

from .admission import AdmissionMiddleware
from .auth import require_api_key
from .bodies import JobRequest, SweepRequest
from .body_limit import BodyLimitMiddleware
from .events import ChangeHub
from .problems import PROBLEM_MEDIA_TYPE, UnexpectedErrorMiddleware, install_problem_handlers
from .routers import catalog, health, jobs, observables, render, results, sweeps
from .settings import Settings, load_settings
from .viewer import install as install_viewer

DESCRIPTION = """\
Run published multi-agent flocking models as jobs.

Submit a scenario (or a preset) to `POST /v1/jobs`, follow it with
`GET /v1/jobs/{id}?wait=10` or the SSE stream `/v1/jobs/{id}/events`, then fetch
`/metrics`, `/trajectory` slices or the whole `/trajectory.h5`. Every error is
`application/problem+json` (RFC 9457). With an API key configured, send it as
`Authorization: Bearer <key>` or `X-API-Key` on every route but `/healthz`.
"""


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or load_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        hub = ChangeHub(asyncio.get_running_loop())
        runtime = JobRuntime(settings.data_dir, settings.supervisor_config(),
                             on_change=hub.publish_threadsafe)
        app.state.runtime, app.state.hub = runtime, hub
        runtime.start()
        try:
            yield
        finally:
            await run_in_threadpool(runtime.close)

    # With an API key, the API description needs it too and the browser UIs (which
    # cannot send it) are off.
    public_docs = settings.api_key is None
    app = FastAPI(title="flocklab", version=version(), description=DESCRIPTION,
                  lifespan=lifespan, openapi_url="/openapi.json" if public_docs else None,
                  docs_url="/docs" if public_docs else None,
                  redoc_url="/redoc" if public_docs else None, openapi_tags=[
                      {"name": "jobs", "description": "Submit, follow and cancel jobs."},
                      {"name": "results", "description": "Metrics and trajectories."},
                      {"name": "sweeps", "description": "Parameter sweeps: many runs, "
                       "one table."},
                      {"name": "catalog", "description": "Models and presets."},
                      {"name": "health", "description": "Probes."}])
    app.state.settings = settings
    install_problem_handlers(app)
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_body_bytes)
    # Outside the body limit: refusals by content type, disk or queue read no body.
    app.add_middleware(AdmissionMiddleware, settings=settings)
    if settings.cors_origins:  # off unless origins are listed (R20)
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins,
                           allow_methods=["GET", "POST"],
                           allow_headers=["Authorization", "X-API-Key", "Idempotency-Key",
                                          "Content-Type"],
                           expose_headers=["Location", "Retry-After", "Idempotent-Replayed"])
    app.add_middleware(UnexpectedErrorMiddleware)  # outermost: catches every layer's error
    app.include_router(health.router)
    auth = [Depends(require_api_key)]
    for module in (jobs, results, observables, render, sweeps, catalog):
        app.include_router(module.router, prefix="/v1", dependencies=auth)
    app.include_router(render.sweep_router, prefix="/v1", dependencies=auth)
    install_viewer(app)  # the browser viewer at / and offline Swagger UI assets
    app.openapi = lambda: _openapi(app)  # type: ignore[method-assign]
    if not public_docs:
        @app.get("/openapi.json", include_in_schema=False, dependencies=auth)
        def openapi_json() -> JSONResponse:
            return JSONResponse(app.openapi())
    return app


def _openapi(app: FastAPI) -> dict[str, Any]:
    """FastAPI's schema, plus the hand-parsed request body's models and problem+json
    bodies on every error response."""
    if app.openapi_schema:
        return app.openapi_schema
    schema = get_openapi(title=app.title, version=app.version, description=app.description,
                         routes=app.routes, tags=app.openapi_tags)
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    _, defs = models_json_schema(
        [(JobRequest, "validation"), (Scenario, "validation"), (Problem, "validation"),
         (SweepRequest, "validation"), (Sweep, "validation")],
        ref_template="#/components/schemas/{model}")
    components.update(defs["$defs"])
    problem_ref = {"$ref": "#/components/schemas/Problem"}
    for path in schema["paths"].values():
        for op in path.values():
            for code, response in op.get("responses", {}).items():
                if code.isdigit() and int(code) >= 400:
                    response["description"] = HTTPStatus(int(code)).phrase
                    response["content"] = {PROBLEM_MEDIA_TYPE: {"schema": problem_ref}}
    app.openapi_schema = schema
    return schema
