"""Request dependencies: the objects the lifespan put on `app.state`."""

from __future__ import annotations

import uuid
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


def get_job(runtime: JobRuntime, job_id: uuid.UUID, kind: str = "job") -> Job:
    """The job (or, with kind="sweep", the sweep) with this id; 404 when there is none of
    that kind (a sweep's id is not a job's and the other way round)."""
    job = runtime.store.get(str(job_id))
    if job is None or job.kind != kind:
        raise ProblemError(404, f"{kind}-not-found", f"{kind.capitalize()} not found",
                           f"no {kind} with id {job_id}")
    return job
