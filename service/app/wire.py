"""The service's request and response bodies (the scenario itself is `schemas.Scenario`)."""

from __future__ import annotations

import datetime as dt
import json
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from flocklab.schemas import Problem, Scenario
from flocklab.schemas.status import JobView
from flocklab.service.jobs import Job

EXAMPLE_SCENARIO: dict[str, Any] = {
    "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 2.0},
    "space": {"kind": "periodic", "L": 7.0},
    "neighbours": {"radius": 1.0},
    "initial": {"kind": "random", "N": 300},
    "time": {"steps": 500, "dt": 1.0},
    "recording": {"every": 10, "arrays": ["position", "heading"]},
    "seed": 1,
}


class JobRequest(BaseModel):
    """A submission: a full scenario, or a named preset with optional overrides.

    A bare scenario object (one with a `model` key) is accepted as the body too.
    """

    model_config = ConfigDict(
        extra="forbid", strict=True, frozen=True,
        json_schema_extra={"examples": [
            {"scenario": EXAMPLE_SCENARIO},
            {"preset": "vicsek-1995", "overrides": {"initial": {"N": 1000}},
             "timeout_seconds": 600},
        ]},
    )

    scenario: Scenario | None = Field(default=None, description="The scenario to run.")
    preset: Annotated[str, Field(min_length=1, max_length=100)] | None = Field(
        default=None, description="Name of a preset (see GET /v1/presets).")
    overrides: dict[str, Any] | None = Field(
        default=None, description="Merged into the preset's scenario, object by object "
        "(e.g. {\"initial\": {\"N\": 1000}}); the result is validated as a scenario.")
    timeout_seconds: Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)] | None = Field(
        default=None, description="Wall-clock limit for the job; default: the service's.")

    @model_validator(mode="after")
    def _one_source(self) -> JobRequest:
        if (self.scenario is None) == (self.preset is None):
            raise ValueError("give exactly one of 'scenario' and 'preset'")
        if self.overrides is not None and self.preset is None:
            raise ValueError("'overrides' apply to a preset only")
        return self


def job_view(job: Job, ttl_seconds: float) -> JobView:
    base = f"/v1/jobs/{job.id}"
    links = {"self": base, "events": f"{base}/events", "cancel": f"{base}/cancel"}
    if job.has_results and not job.results_expired:
        results = "available"
        links |= {"metrics": f"{base}/metrics", "trajectory": f"{base}/trajectory",
                  "trajectory_h5": f"{base}/trajectory.h5"}
    elif job.results_expired:
        results = "expired"
    else:
        results = "none" if job.terminal else "pending"
    progress = 1.0 if job.status == "succeeded" else (
        min(1.0, job.steps_done / job.steps_total) if job.steps_total else 0.0)
    return JobView(
        id=job.id, status=job.status, progress=progress,  # type: ignore[arg-type]
        steps_done=job.steps_done, steps_total=job.steps_total, model=job.model_kind,
        n_agents=job.n_agents, created_at=_ts(job.created_at), started_at=_ts(job.started_at),
        finished_at=_ts(job.finished_at), attempts=job.attempts,
        cancel_requested=bool(job.cancel_requested), backend=job.backend,
        timeout_seconds=job.timeout_seconds,
        error=Problem.model_validate(job.problem) if job.problem else None,
        results=results,
        results_expire_at=_ts(job.finished_at + ttl_seconds)
        if results == "available" and job.finished_at else None,
        checksums=_checksums(job) if results == "available" else None,
        links=links,
        resumed_from_step=job.resumed_from_step,
    )


def _ts(t: float | None) -> dt.datetime | None:
    return None if t is None else dt.datetime.fromtimestamp(t, dt.timezone.utc)


def _checksums(job: Job) -> dict[str, str] | None:
    return json.loads(job.checksums) if job.checksums else None
