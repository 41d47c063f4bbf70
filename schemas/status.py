"""What the service answers about a job or a sweep, shared with the client (which parses
its responses into these models).

One vocabulary of states, `JobState`, read by the job store (its CHECK constraint), the
client (`done`) and the browser viewer (from the OpenAPI document's enum of
`JobView.status`). Its order is the lifecycle: the live states, then the final ones.
A sweep is a job of another kind: both views extend `LifecycleView`, the fields every
stored job shows, and add their own progress (a job's steps, a sweep's runs).
"""

from __future__ import annotations

import datetime as dt
from typing import Any, ClassVar, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field

from .problems import Problem

JobState = Literal["queued", "running", "succeeded", "failed", "cancelled", "timed_out"]
SweepState = JobState
STATES: tuple[str, ...] = get_args(JobState)
LIVE_STATES: tuple[str, ...] = STATES[:2]  # queued, running: what a long-poll waits out
TERMINAL_STATES: tuple[str, ...] = STATES[2:]  # a job in one of these never changes again
ResultsState = Literal["pending", "available", "none", "expired"]


class LifecycleView(BaseModel):
    """The fields of any stored job, a run's or a sweep's: its state, times, attempts,
    error, results and links. The kinds override a field's description where it reads
    differently for them."""

    id: str = Field(description="The job's id (a UUID).")
    status: JobState
    progress: float = Field(ge=0, le=1, description="Fraction of steps done.")
    model: str = Field(description="The scenario's model kind.")
    created_at: dt.datetime
    started_at: dt.datetime | None = Field(description="Start of the latest attempt.")
    finished_at: dt.datetime | None
    attempts: int = Field(description="Attempts started (a lost worker is retried once).")
    cancel_requested: bool
    timeout_seconds: float
    error: Problem | None = Field(
        description="Why the job failed or timed out; for a queued job, why its previous "
        "attempt was interrupted.")
    results: ResultsState = Field(
        description="pending: not finished; available: metrics and trajectory can be "
        "fetched; none: the job ended without results; expired: deleted after the TTL.")
    results_expire_at: dt.datetime | None
    checksums: dict[str, str] | None = Field(description="sha256 (hex) of each result file.")
    links: dict[str, str]

    # The order a kind's fields are sent and listed in its schema, the base's and its own
    # interleaved: the API's order from before the kinds shared this base, kept so that
    # the OpenAPI document and the answers did not change (pydantic puts a base's fields
    # first). It names every field once (checked as the class is made).
    wire_order: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        fields = cls.__pydantic_fields__
        if sorted(cls.wire_order) != sorted(fields):
            raise TypeError(f"{cls.__name__}.wire_order must name each of its fields once")
        cls.__pydantic_fields__ = {name: fields[name] for name in cls.wire_order}
        cls.model_rebuild(force=True)

    @property
    def done(self) -> bool:
        """Finished: the state is final."""
        return self.status in TERMINAL_STATES


class JobView(LifecycleView):
    """A job as the API shows it."""

    model_config = ConfigDict(json_schema_extra={"examples": [{
        "id": "3f2b8e1c-8f3a-4c55-9d2e-0c6b1f8e9a41", "status": "running", "progress": 0.42,
        "steps_done": 210, "steps_total": 500, "model": "vicsek", "n_agents": 300,
        "created_at": "2024-05-01T12:00:00Z", "started_at": "2024-05-01T12:00:00.1Z",
        "finished_at": None, "attempts": 1, "cancel_requested": False, "backend": None,
        "timeout_seconds": 3600.0, "error": None, "results": "pending",
        "results_expire_at": None, "checksums": None,
        "links": {"self": "/v1/jobs/3f2b8e1c-8f3a-4c55-9d2e-0c6b1f8e9a41"},
    }]})

    wire_order = ("id", "status", "progress", "steps_done", "steps_total", "model", "n_agents",
                  "created_at", "started_at", "finished_at", "attempts", "cancel_requested",
                  "backend", "timeout_seconds", "error", "results", "results_expire_at",
                  "checksums", "links", "resumed_from_step")

    steps_done: int
    steps_total: int
    n_agents: int
    backend: str | None = Field(description="The Taichi backend that ran the job.")
    resumed_from_step: int | None = Field(
        default=None, description="The step of the checkpoint the latest attempt went on "
        "from, when a lost attempt of a job with checkpoints (`recording.checkpoint_every`) "
        "left one; null when it ran from step 0.")


class JobList(BaseModel):
    items: list[JobView]
    next_cursor: str | None = Field(description="Pass as `cursor` for the next page.")


class SweepStatus(LifecycleView):
    """A sweep as the API shows it: its runs done, failed and in all, and its results."""

    model_config = ConfigDict(extra="allow", json_schema_extra={"examples": [{
        "id": "5d0c4a7e-2b1f-4f0e-9c1a-7e3d2b6a8f10", "name": "eta-scan",
        "status": "running", "progress": 0.25, "runs_done": 6, "runs_failed": 0,
        "runs_total": 24, "model": "vicsek", "created_at": "2024-05-01T12:00:00Z",
        "started_at": "2024-05-01T12:00:00.1Z", "finished_at": None, "attempts": 1,
        "cancel_requested": False, "timeout_seconds": 3600.0, "error": None,
        "results": "pending", "results_expire_at": None, "checksums": None,
        "links": {"self": "/v1/sweeps/5d0c4a7e-2b1f-4f0e-9c1a-7e3d2b6a8f10"},
    }]})

    wire_order = ("id", "name", "status", "progress", "runs_done", "runs_failed", "runs_total",
                  "model", "created_at", "started_at", "finished_at", "attempts",
                  "cancel_requested", "timeout_seconds", "error", "results",
                  "results_expire_at", "checksums", "resumed_runs", "links")

    id: str = Field(description="The sweep's id (a UUID).")
    name: str | None = Field(default=None, description="The sweep's `name`.")
    status: SweepState = Field(description="`succeeded` once every run ended, even when "
                               "some runs failed (see `runs_failed` and runs.csv).")
    progress: float = Field(ge=0, le=1, description="Fraction of runs ended (completed or "
                            "failed).")
    runs_done: int = Field(description="Runs completed, those of an interrupted attempt "
                           "included (a retry does not redo them).")
    runs_failed: int = Field(description="Runs that diverged (ended without measures); "
                             "their rows in runs.csv say so.")
    runs_total: int = Field(description="Grid points x replicas.")
    model: str = Field(description="The base scenario's model kind.")
    attempts: int = Field(description="Attempts started; a lost worker's sweep is retried "
                          "once, continuing from its finished runs.")
    timeout_seconds: float = Field(description="Wall-clock limit of the whole sweep.")
    error: Problem | None = Field(
        description="Why the sweep failed or timed out; for a queued one, why its previous "
        "attempt was interrupted.")
    results: ResultsState = Field(
        description="available: table, runs and series can be fetched (also after a "
        "cancel: the runs finished before it); none: ended without results; expired: "
        "deleted after the TTL.")
    resumed_runs: dict[str, int] | None = Field(
        default=None, description="The runs the latest attempt continued from their "
        "checkpoints (runs with `recording.checkpoint_every`, partially run by a lost "
        "attempt): run index -> the checkpoint's step; null when none (docs/CHECKPOINTS.md).")


class SweepList(BaseModel):
    items: list[SweepStatus]
    next_cursor: str | None = Field(description="Pass as `cursor` for the next page.")
