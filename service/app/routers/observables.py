"""A job's observables as they arrive: the rows so far while it runs, all once it ended.

`GET /v1/jobs/{id}/observables?start=K` answers for a queued or running job too (unlike
`/metrics`, which waits for the results): the rows the run has published so far (see
service/live_observables.py), from row K on, with `partial: true` and the header
`Observables-Partial: true`. Once the job has ended it answers from the committed
`observables.csv` with `partial: false`, so a reader that pages with `start` = the rows
it holds ends with exactly the final series. A job that ended without results, or whose
results expired, answers as the other result routes do (404, 410).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse

from flocklab.service.jobs import Job, JobRuntime

from ..deps import JobId, RuntimeDep, get_job
from ..observables import CorruptObservables, live_sources, read_rows
from .results import _results_dir, corrupted

router = APIRouter(prefix="/jobs", tags=["results"])
MAX_ROWS = 100_000  # rows per answer: page with `start` beyond it
_ERRORS: dict[int | str, dict[str, Any]] = {401: {}, 404: {}, 410: {}, 422: {}, 500: {}}
_EXAMPLE = {"job_id": "3f2b8e1c-8f3a-4c55-9d2e-0c6b1f8e9a41", "status": "running",
            "partial": True, "start": 0, "rows": 2, "more": False,
            "observables": {"step": [0, 10], "time": [0.0, 10.0],
                            "polarization": [0.04, 0.31]}}


@router.get("/{job_id}/observables", summary="The observables so far, while the job runs",
            description="Rows `start` .. `start + limit` of the observables series as "
            "columns. For a queued or running job, the rows computed so far (`partial`: "
            "true; none before the run has published any); once the job has ended, the "
            "final series (`partial`: false). `more` says rows beyond `limit` are there: "
            "ask again with `start` + `rows`.",
            responses={200: {"content": {"application/json": {"example": _EXAMPLE}}},
                       **_ERRORS})
def observables(
    job_id: JobId, runtime: RuntimeDep,
    start: Annotated[int, Query(ge=0, le=2**62, description="First row to send.")] = 0,
    limit: Annotated[int, Query(ge=1, le=MAX_ROWS, description="Rows to send, at most."
                                )] = MAX_ROWS,
) -> JSONResponse:
    job = get_job(runtime, job_id)
    # The run's files move (live file → attempt folder → results) while we look: a file
    # gone under us means the job has moved on; look again, from the job's row.
    for _ in range(3):
        path = _source(runtime, job)
        if path is None:
            now = get_job(runtime, job_id)
            if now.terminal == job.terminal and now.has_results == job.has_results:
                break  # no rows published yet
            job = now
            continue
        try:
            columns, more = read_rows(path, start, limit)
        except FileNotFoundError:
            if job.terminal:  # the committed results lack it
                raise corrupted("observables.csv") from None
            job = get_job(runtime, job_id)
            continue
        except (OSError, CorruptObservables):
            raise corrupted("observables.csv") from None
        return _answer(job, start, columns, more)
    return _answer(job, start, {}, False)


def _source(runtime: JobRuntime, job: Job) -> Path | None:
    """The file holding the job's rows now (None: no rows yet)."""
    if job.terminal or job.has_results:
        _, folder = _results_dir(runtime, job.id)  # 404 / 410 as the result routes
        return folder / "observables.csv"
    for path in live_sources(runtime.results, job):
        if path.is_file():
            return path
    return None


def _answer(job: Job, start: int, columns: dict[str, list[float | None]], more: bool
            ) -> JSONResponse:
    partial = not job.terminal
    rows = len(next(iter(columns.values()), []))
    return JSONResponse(
        {"job_id": job.id, "status": job.status, "partial": partial, "start": start,
         "rows": rows, "more": more, "observables": columns},
        headers={"Observables-Partial": "true" if partial else "false",
                 "Cache-Control": "no-store"})
