"""/healthz: liveness and readiness without touching Taichi or waiting on a worker."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from ..deps import RuntimeDep

router = APIRouter(tags=["health"])


@router.get("/healthz", summary="Health check (no authentication)",
            responses={200: {"content": {"application/json": {"example": {
                "status": "ok", "supervisor": True, "workers": 1, "queued": 0,
                "running": 0}}}},
                       503: {"description": "The job supervisor is not running."}})
def healthz(runtime: RuntimeDep) -> JSONResponse:
    ok = runtime.supervisor.alive
    body: dict[str, Any] = {
        "status": "ok" if ok else "degraded",
        "supervisor": ok,
        "workers": len(runtime.supervisor.worker_pids()),
        "queued": runtime.store.count("queued"),
        "running": runtime.store.count("running"),
    }
    return JSONResponse(body, status_code=200 if ok else 503)
