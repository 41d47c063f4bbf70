"""flocklab's Python client: submit scenarios to a flocklab service and fetch results.

Needs only httpx, numpy and `schemas` (pydantic): importing it never imports Taichi or
FastAPI.

    from flocklab.clients import Client
    with Client("http://127.0.0.1:8000") as c:
        job = c.submit(preset="vicsek-1995").wait()
        metrics = job.metrics()
        frames = job.trajectory(stride=10, agents=slice(0, 100))
"""

from .aio import AsyncClient, AsyncJob, AsyncSweepJob
from .errors import (
    APIError,
    BadRequest,
    ClientError,
    Conflict,
    FlocklabError,
    Gone,
    JobTimeout,
    NotFound,
    PayloadTooLarge,
    ServerError,
    ServiceUnavailable,
    SweepFailed,
    TooManyRequests,
    Unauthorized,
    UnprocessableEntity,
)
from .sync import Client, Job, SweepJob

__all__ = [
    "APIError",
    "AsyncClient",
    "AsyncJob",
    "AsyncSweepJob",
    "BadRequest",
    "Client",
    "ClientError",
    "Conflict",
    "FlocklabError",
    "Gone",
    "Job",
    "JobTimeout",
    "NotFound",
    "PayloadTooLarge",
    "ServerError",
    "ServiceUnavailable",
    "SweepFailed",
    "SweepJob",
    "TooManyRequests",
    "Unauthorized",
    "UnprocessableEntity",
]
