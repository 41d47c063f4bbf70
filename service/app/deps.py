"""Request dependencies: the objects the lifespan put on `app.state`."""

from __future__ import annotations

import uuid
from pathlib import Path as FilePath
from typing import Annotated

from fastapi import Depends, Path, Request

from flocklab.service.jobs import Job, JobRuntime

from .events import ChangeHub
from .problems import ProblemError
from .settings import Settings


def _runtime(request: Request) -> JobRuntime:
    return request.app.state.runtime


def _settings(request: Request) -> Settings:
    return request.app.state.settings


def _hub(request: Request) -> ChangeHub:
    return request.app.state.hub


RuntimeDep = Annotated[JobRuntime, Depends(_runtime)]
SettingsDep = Annotated[Settings, Depends(_settings)]
HubDep = Annotated[ChangeHub, Depends(_hub)]
# Job ids are parsed as UUIDs before anything else sees them (R22).
JobId = Annotated[uuid.UUID, Path(description="The job's id (a UUID).",
                                  examples=["3f2b8e1c-8f3a-4c55-9d2e-0c6b1f8e9a41"])]


def get_job(runtime: JobRuntime, job_id: uuid.UUID | str, kind: str = "job") -> Job:
    """The job (or, with kind="sweep", the sweep) with this id; 404 when there is none of
    that kind (a sweep's id is not a job's and the other way round)."""
    job = runtime.store.get(str(job_id))
    if job is None or job.kind != kind:
        raise ProblemError(404, f"{kind}-not-found", f"{kind.capitalize()} not found",
                           f"no {kind} with id {job_id}")
    return job


def results_dir(runtime: JobRuntime, row_id: uuid.UUID | str, kind: str = "job"
                ) -> tuple[Job, FilePath]:
    """The row of `kind` and its results folder, once it has results: else 409 while it
    runs, 404 when it ended without, 410 once they expired (or their folder is gone)."""
    job = get_job(runtime, row_id, kind)
    if job.results_expired:
        raise _expired(kind)
    if not job.has_results:
        if not job.terminal:
            raise ProblemError(409, "results-pending", "Results not ready",
                               f"the {kind} is {job.status}", status_now=job.status)
        raise ProblemError(404, "no-results", "No results",
                           f"the {kind} ended ({job.status}) without results")
    folder = runtime.results.job_dir(job.id)
    if not folder.is_dir():
        if get_job(runtime, row_id, kind).results_expired:
            raise _expired(kind)  # the expiry sweep won the race
        raise ProblemError(410, "results-missing", "Results missing",
                           f"this {kind}'s results folder is gone from the server's disk "
                           "although the results had not expired (deleted outside the "
                           "service)")
    return job, folder


def _expired(kind: str) -> ProblemError:
    return ProblemError(410, "results-expired", "Results expired",
                        f"this {kind}'s results were deleted after the retention period")
