"""The sweep routes' request body and the view of a stored sweep (`schemas.status`)."""

from __future__ import annotations

import json
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from flocklab.schemas import Problem
from flocklab.schemas.status import SweepStatus
from flocklab.schemas.sweep import Sweep
from flocklab.service.jobs import Job

from .wire import _checksums, _ts

EXAMPLE_SWEEP: dict[str, Any] = {
    "name": "eta-scan",
    "base": {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03},
        "space": {"kind": "periodic", "L": 5.0},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 100},
        "time": {"steps": 500},
        "recording": {"every": 0, "observables_every": 10},
        "seed": 1,
    },
    "axes": [{"path": "model.eta", "values": [0.5, 2.0, 4.0]}],
    "replicas": 2,
    "measure": {"va": {"observable": "polarization", "reduce": "mean", "from_step": 200}},
}


class SweepRequest(BaseModel):
    """A sweep submission with options: a sweep, or a named one (`flocklab sweep
    preset:NAME`). A bare sweep object is accepted as the body too."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, json_schema_extra={
        "examples": [{"sweep": EXAMPLE_SWEEP, "timeout_seconds": 7200},
                     {"sweep_preset": "vicsek-1995-fig2a"}]})

    sweep: Sweep | None = Field(default=None, description="The sweep to run.")
    sweep_preset: Annotated[str, Field(min_length=1, max_length=100)] | None = Field(
        default=None, description="Name of a named sweep, e.g. 'vicsek-1995-fig2a'.")
    timeout_seconds: Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)] | None = Field(
        default=None, description="Wall-clock limit for the whole sweep; default: the "
        "service's job timeout.")

    @model_validator(mode="after")
    def _one_source(self) -> SweepRequest:
        if (self.sweep is None) == (self.sweep_preset is None):
            raise ValueError("give exactly one of 'sweep' and 'sweep_preset'")
        return self


def sweep_view(job: Job, ttl_seconds: float) -> SweepStatus:
    base = f"/v1/sweeps/{job.id}"
    links = {"self": base, "spec": f"{base}/spec", "events": f"{base}/events",
             "cancel": f"{base}/cancel"}
    if job.has_results and not job.results_expired:
        results = "available"
        links |= {"table": f"{base}/table", "runs": f"{base}/runs", "series": f"{base}/series"}
    elif job.results_expired:
        results = "expired"
    else:
        results = "none" if job.terminal else "pending"
    ended, total = job.steps_done, job.steps_total
    return SweepStatus(
        id=job.id, name=_name(job), status=job.status,  # type: ignore[arg-type]
        progress=min(1.0, ended / total) if total else 0.0,
        runs_done=max(0, ended - job.runs_failed), runs_failed=job.runs_failed,
        runs_total=total, model=job.model_kind,
        created_at=_ts(job.created_at), started_at=_ts(job.started_at),  # type: ignore[arg-type]
        finished_at=_ts(job.finished_at), attempts=job.attempts,
        cancel_requested=bool(job.cancel_requested), timeout_seconds=job.timeout_seconds,
        error=Problem.model_validate(job.problem) if job.problem else None,
        results=results,  # type: ignore[arg-type]
        results_expire_at=_ts(job.finished_at + ttl_seconds)
        if results == "available" and job.finished_at else None,
        checksums=_checksums(job) if results == "available" else None,
        resumed_runs=json.loads(job.resumed_runs) if job.resumed_runs else None,
        links=links,
    )


def _name(job: Job) -> str | None:
    name = json.loads(job.scenario).get("name")
    return name if isinstance(name, str) else None
