"""Pictures of a job's results: a snapshot (PNG), its observables (PNG), a movie (MP4).

Each picture is drawn once per distinct set of options by `service.render.worker` in a
child process (matplotlib never loads in the API process, and a slow large-N draw never
holds the API's GIL), then kept in the job's results folder under `render/`, so it is
served from disk afterwards and deleted with the results. The job routes' rules apply:
the same auth, 404/409/410 for a missing, unfinished or expired job, problem+json errors.
The cache is bounded in size and by the disk reserve (render_cache.py), and the draws at
once are shared fairly between clients (render_slots.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import os
import sys
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, FastAPI, Query, Request
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from flocklab.schemas import FieldError
from flocklab.service.jobs import Job
from flocklab.service.jobs.disk import scrub_paths
from flocklab.service.render.limits import MAX_FPS, MIN_FPS

from ..deps import JobId, RuntimeDep
from ..problems import ProblemError, invalid
from ..render_cache import RENDER_DIR, RenderCache
from ..render_slots import RenderSlots
from .results import _results_dir

router = APIRouter(prefix="/jobs", tags=["results"])
sweep_router = APIRouter(prefix="/sweeps", tags=["sweeps"])

RENDER_TIMEOUT_SECONDS = 300.0
_locks: dict[str, asyncio.Lock] = {}  # one draw per cache file at a time
_ERRORS: dict[int | str, dict[str, Any]] = {401: {}, 404: {}, 409: {}, 410: {}, 422: {},
                                            503: {}}
_PNG = {200: {"content": {"image/png": {"schema": {"type": "string", "format": "binary"}}}}}
_MP4 = {200: {"content": {"video/mp4": {"schema": {"type": "string", "format": "binary"}}}}}

Width = Annotated[int, Query(ge=64, le=4096, description="Picture width in pixels.")]
Height = Annotated[int, Query(ge=64, le=4096, description="Picture height in pixels.")]
FieldMode = Annotated[Literal["auto", "arrows", "density", "polarization"], Query(
    description="Arrows per agent, or a density / local-polarization field (auto: a "
    "density field above 5000 agents).")]
Edges = Annotated[bool | None, Query(
    description="Draw the interaction edges (default: at N <= 200).")]
Overlays = Annotated[bool, Query(
    description="Obstacles and destination (M3); virtual leaders, path, offsets (M4).")]


@router.get("/{job_id}/render/snapshot.png", summary="A frame drawn as the papers do",
            description="Agents as heading/velocity arrows coloured by heading, the "
            "interaction edges at small N, obstacles and destination (M3), virtual "
            "leaders, path and offsets (M4), the periodic box; a density or polarization "
            "field at large N. Drawn once per option set, then served from the cache.",
            response_class=FileResponse, responses={**_PNG, **_ERRORS})
async def snapshot(
    request: Request, job_id: JobId, runtime: RuntimeDep,
    frame: Annotated[int | None, Query(ge=-2**31, le=2**31,
                                       description="Frame index (negative: from the end; "
                                       "default the last).")] = None,
    time: Annotated[float | None, Query(allow_inf_nan=False,
                                        description="The last frame at or before this "
                                        "time.")] = None,
    width: Width = 800, height: Height = 800, field: FieldMode = "auto", edges: Edges = None,
    trails: Annotated[int | None, Query(ge=0, le=100_000, description=(
        "Draw each agent's path over this many frames back (0: from the first)."))] = None,
    overlays: Overlays = True,
) -> FileResponse:
    if frame is not None and time is not None:
        raise invalid([FieldError(loc="query.time", msg="give a frame or a time, not both",
                                  type="value_error")])
    options = {"frame": frame, "time": time, "width": width, "height": height,
               "field": field, "edges": edges, "trails": trails, "overlays": overlays}
    return await _render(request, lambda: _results_dir(runtime, job_id), "snapshot", "png",
                         options)


@router.get("/{job_id}/render/observables.png", summary="Observables against time",
            description="One panel per observable, the convergence time marked.",
            response_class=FileResponse, responses={**_PNG, **_ERRORS})
async def observables(
    request: Request, job_id: JobId, runtime: RuntimeDep,
    names: Annotated[str | None, Query(max_length=2000, pattern=r"^[A-Za-z0-9_,]*$",
                                       description="Comma-separated observables (default: "
                                       "the model's usual ones).")] = None,
    width: Width = 900, height: Height = 700,
) -> FileResponse:
    chosen = [n for n in (names or "").split(",") if n] or None
    if chosen is not None and len(chosen) > 12:
        raise invalid([FieldError(loc="query.names", msg="at most 12 observables",
                                  type="value_error")])
    options = {"names": chosen, "width": width, "height": height}
    return await _render(request, lambda: _results_dir(runtime, job_id), "observables", "png",
                         options)


@router.get("/{job_id}/render/movie.mp4", summary="The recorded frames as an MP4 movie",
            description="H.264, made once and cached with the results.",
            response_class=FileResponse, responses={**_MP4, **_ERRORS})
async def movie(
    request: Request, job_id: JobId, runtime: RuntimeDep,
    width: Annotated[int, Query(ge=64, le=1920, description="Width in pixels.")] = 640,
    height: Annotated[int, Query(ge=64, le=1920, description="Height in pixels.")] = 640,
    fps: Annotated[float, Query(ge=MIN_FPS, le=MAX_FPS, allow_inf_nan=False,
                                description="Frames per second.")] = 20.0,
    stride: Annotated[int, Query(ge=1, le=2**31, description="Every k-th frame.")] = 1,
    field: FieldMode = "auto", edges: Edges = None, overlays: Overlays = True,
) -> FileResponse:
    options = {"width": width, "height": height, "fps": fps, "stride": stride,
               "field": field, "edges": edges, "overlays": overlays}
    return await _render(request, lambda: _results_dir(runtime, job_id), "movie", "mp4",
                         options)


@sweep_router.get("/{sweep_id}/render/plot.png", summary="Each measure against the axes",
                  description="One panel per measure: the measure's mean against the first "
                  "axis, one curve per value of the second, error bars from the replicas "
                  "(sem, else sd): Vicsek 1995 Fig. 2a from `vicsek-1995-fig2a`.",
                  response_class=FileResponse, responses={**_PNG, **_ERRORS})
async def sweep_plot(
    request: Request, sweep_id: uuid.UUID, runtime: RuntimeDep,
    names: Annotated[str | None, Query(max_length=2000, pattern=r"^[A-Za-z0-9_,]*$",
                                       description="Comma-separated measures (default: "
                                       "all).")] = None,
    width: Width = 900, height: Height = 600,
) -> FileResponse:
    from .sweeps import _results_dir as sweep_results_dir

    chosen = [n for n in (names or "").split(",") if n] or None
    options = {"names": chosen, "width": width, "height": height}
    return await _render(request, lambda: sweep_results_dir(runtime, sweep_id), "sweep",
                         "png", options)


async def _render(request: Request, locate: Callable[[], tuple[Job, Path]], what: str,
                  ext: str, options: dict[str, Any]) -> FileResponse:
    """Serve the cached picture of `what` for these options, drawing it first if need be.
    `locate` finds the results folder or raises the result routes' problems (a sweep's
    route passes its own, with what="sweep": the worker draws sweep folders too)."""
    app = request.app
    job, folder = await run_in_threadpool(locate)
    key = hashlib.sha256(json.dumps([what, options], sort_keys=True).encode()).hexdigest()
    target = folder / RENDER_DIR / f"{what}-{key[:24]}.{ext}"
    media = "image/png" if ext == "png" else "video/mp4"
    filename = f"{job.id}-{what}.{ext}"
    cache = _cache(app)
    if not await run_in_threadpool(cache.hit, target):
        lock = _locks.setdefault(str(target), asyncio.Lock())
        async with lock:
            if not target.is_file():  # another request may have drawn it meanwhile
                client = request.client.host if request.client else "local"
                try:
                    await run_in_threadpool(cache.reserve)
                    await _draw(_slots(app), client, what, folder, target, options)
                except Exception:
                    # the results may have expired (their folder deleted) while drawing:
                    # then that is the answer (410), not the worker's failure to read or
                    # write them (a 422 "not a run folder", or a server error)
                    await run_in_threadpool(locate)
                    raise
                await run_in_threadpool(cache.add, target)
        _locks.pop(str(target), None)
    return FileResponse(target, media_type=media, filename=filename,
                        content_disposition_type="inline")


def _cache(app: FastAPI) -> RenderCache:
    if not hasattr(app.state, "render_cache"):
        s = app.state.settings
        app.state.render_cache = RenderCache(app.state.runtime.results.root,
                                             s.render_cache_bytes, s.min_free_disk_bytes)
    return app.state.render_cache


def _slots(app: FastAPI) -> RenderSlots:
    """The app's render slots (created on its own event loop, on first use)."""
    if not hasattr(app.state, "render_slots"):
        s = app.state.settings
        app.state.render_slots = RenderSlots(s.render_slots, s.render_slots_per_client)
    return app.state.render_slots


async def _draw(slots: RenderSlots, client: str, what: str, folder: Path, target: Path,
                options: dict[str, Any]) -> None:
    target.parent.mkdir(exist_ok=True)
    tmp = target.with_name(f".{target.stem}.{uuid.uuid4().hex[:8]}{target.suffix}")
    request = json.dumps({"what": what, "folder": str(folder), "out": str(tmp),
                          "options": options}).encode()
    async with slots.slot(client):
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "flocklab.service.render.worker", stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
            env={**os.environ, "MPLBACKEND": "Agg"})
        try:
            out, err = await asyncio.wait_for(proc.communicate(request),
                                              RENDER_TIMEOUT_SECONDS)
        except (asyncio.TimeoutError, asyncio.CancelledError):
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            await proc.wait()
            tmp.unlink(missing_ok=True)
            raise ProblemError(503, "render-timeout", "Rendering took too long",
                               f"the picture was not drawn within {RENDER_TIMEOUT_SECONDS:g} "
                               "s; ask for a smaller size, a stride, or a field",
                               headers={"Retry-After": str(slots.retry_after())}) from None
    if proc.returncode != 0:
        tmp.unlink(missing_ok=True)
        raise _failure(proc.returncode, out, err)
    os.replace(tmp, target)


def _failure(code: int | None, out: bytes, err: bytes) -> ProblemError:
    """The problem for a failed draw. The worker's messages name the folder (they are the
    CLI's too, where a path helps): clients never see server paths, so they are scrubbed."""
    try:
        body = json.loads(out.decode().strip().splitlines()[-1])
    except (ValueError, IndexError):
        body = None
    if code in (2, 3) and isinstance(body, dict):
        detail = scrub_paths(str(body.get("detail")))
    if code == 2 and isinstance(body, dict):
        status = int(body.get("status", 422))
        if status == 404:
            return ProblemError(404, "nothing-to-draw", "Nothing to draw", detail)
        loc = f"query.{body['loc']}" if body.get("loc") else "query"
        return invalid([FieldError(loc=loc, msg=detail, type="value_error")])
    if code == 3 and isinstance(body, dict):
        return ProblemError(503, "plotting-unavailable", "Plotting unavailable", detail)
    raise RuntimeError(f"render worker failed ({code}): {err.decode()[-2000:]}")
