"""/v1/jobs: submit, get (with long-poll), list, cancel, and follow progress as SSE.

The routes are those of every kind of job (`resource`); this module gives a run's names
and words.
"""

from __future__ import annotations

import inspect
from typing import Annotated

from fastapi import APIRouter, Query

from flocklab.schemas.status import JobList, JobState, JobView

from ..bodies import EXAMPLE_SCENARIO
from ..deps import JobId
from .resource import Resource, add_routes

router = APIRouter(prefix="/jobs", tags=["jobs"])

JOBS = Resource(
    kind="job", id_name="job_id", id_type=JobId, state_type=JobState, view=JobView,
    page=JobList, get_name="get_job_route",
    submit_summary="Submit a scenario or a preset",
    submit_description="Stores the job durably, then answers 202 with a `Location` header. "
    "The body is a `JobRequest` or a bare `Scenario`. With an `Idempotency-Key`, repeating "
    "the same request returns the same job; another body with the same key is a 409.",
    body_schemas=("JobRequest", "Scenario"),
    body_examples={
        "scenario": {"summary": "A full scenario", "value": {"scenario": EXAMPLE_SCENARIO}},
        "preset": {"summary": "A preset with overrides", "value": {
            "preset": "vicsek-1995", "overrides": {"initial": {"N": 1000}}}},
        "bare": {"summary": "A bare scenario", "value": EXAMPLE_SCENARIO},
    },
    get_description="With `wait`, a long-poll: the answer comes when the job has finished, "
    "or after `wait` seconds with the job as it is then. With `until=change` it comes at "
    "the job's first change (status or progress) instead: what a progress display polls "
    "with.",
    cancel_description="A queued job is cancelled at once; a running one is asked to stop "
    "and is killed if it has not stopped after the grace period (cancelling it again while "
    "it stops is a no-op). A finished job (succeeded, failed, cancelled or timed out) gives "
    "409 `job-finished` with `status_now`.",
    events_description="`event: job` with the job as JSON on every change; `event: end` "
    "after the job finished.",
    list_filters=[inspect.Parameter(
        "model", inspect.Parameter.KEYWORD_ONLY, default=None,
        annotation=Annotated[str | None, Query(max_length=100,
                                               description="Only this model kind.")])],
)
add_routes(router, JOBS)
