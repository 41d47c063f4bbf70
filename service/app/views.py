"""How a stored job shows on the wire: `JobView` for a run, `SweepStatus` for a sweep,
both `schemas.status.LifecycleView` with their kind's progress and links.

`VIEWS` maps the store's `kind` to its view, so a route, a list or an event stream of
either kind draws its rows through one `view(job, ttl)`.
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Callable
from typing import Any

from flocklab.schemas import Problem
from flocklab.schemas.status import JobView, LifecycleView, SweepStatus
from flocklab.service.jobs import Job

# Where each kind lives, the links it always has, and those its results add.
ROUTES = {"job": "/v1/jobs", "sweep": "/v1/sweeps"}
_LINKS = {"job": ("events", "cancel"), "sweep": ("spec", "events", "cancel")}
_RESULT_LINKS = {"job": {"metrics": "metrics", "trajectory": "trajectory",
                         "trajectory_h5": "trajectory.h5"},
                 "sweep": {"table": "table", "runs": "runs", "series": "series"}}


def _lifecycle(job: Job, ttl_seconds: float) -> dict[str, Any]:
    """The `LifecycleView` fields of a stored job of either kind."""
    base = f"{ROUTES[job.kind]}/{job.id}"
    links = {"self": base} | {name: f"{base}/{name}" for name in _LINKS[job.kind]}
    if job.has_results and not job.results_expired:
        results = "available"
        links |= {name: f"{base}/{tail}" for name, tail in _RESULT_LINKS[job.kind].items()}
    elif job.results_expired:
        results = "expired"
    else:
        results = "none" if job.terminal else "pending"
    return {
        "id": job.id, "status": job.status, "model": job.model_kind,
        "created_at": _ts(job.created_at), "started_at": _ts(job.started_at),
        "finished_at": _ts(job.finished_at), "attempts": job.attempts,
        "cancel_requested": bool(job.cancel_requested),
        "timeout_seconds": job.timeout_seconds,
        "error": Problem.model_validate(job.problem) if job.problem else None,
        "results": results,
        "results_expire_at": _ts(job.finished_at + ttl_seconds)
        if results == "available" and job.finished_at else None,
        "checksums": json.loads(job.checksums)
        if results == "available" and job.checksums else None,
        "links": links,
    }


def job_view(job: Job, ttl_seconds: float) -> JobView:
    """A run: progress is the fraction of steps done (1 once it succeeded)."""
    progress = 1.0 if job.status == "succeeded" else (
        min(1.0, job.steps_done / job.steps_total) if job.steps_total else 0.0)
    return JobView(**_lifecycle(job, ttl_seconds), progress=progress,
                   steps_done=job.steps_done, steps_total=job.steps_total,
                   n_agents=job.n_agents, backend=job.backend,
                   resumed_from_step=job.resumed_from_step)


def sweep_view(job: Job, ttl_seconds: float) -> SweepStatus:
    """A sweep: its store row's steps count the runs that ended, failed ones included."""
    ended, total = job.steps_done, job.steps_total
    name = json.loads(job.scenario).get("name")
    return SweepStatus(**_lifecycle(job, ttl_seconds),
                       progress=min(1.0, ended / total) if total else 0.0,
                       name=name if isinstance(name, str) else None,
                       runs_done=max(0, ended - job.runs_failed), runs_failed=job.runs_failed,
                       runs_total=total,
                       resumed_runs=json.loads(job.resumed_runs) if job.resumed_runs else None)


VIEWS: dict[str, Callable[[Job, float], LifecycleView]] = {"job": job_view,
                                                          "sweep": sweep_view}


def _ts(t: float | None) -> dt.datetime | None:
    return None if t is None else dt.datetime.fromtimestamp(t, dt.timezone.utc)
