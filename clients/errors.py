"""Exceptions raised by the client: one class per HTTP status, each carrying the
RFC 9457 problem body the service sent."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import httpx

if TYPE_CHECKING:
    from flocklab.schemas.status import SweepStatus


class FlocklabError(Exception):
    """Base of every error this package raises."""


class APIError(FlocklabError):
    """The service answered with an error status. `problem` is its problem-details body."""

    status: int = 0

    def __init__(self, status: int, problem: dict[str, Any], headers: httpx.Headers):
        self.status = status
        self.problem = problem
        self.headers = headers
        self.title: str = problem.get("title", "")
        self.detail: str | None = problem.get("detail")
        self.errors: list[dict[str, Any]] = problem.get("errors") or []
        super().__init__(f"{status} {self.title}: {self.detail}" if self.detail
                         else f"{status} {self.title}")


class ClientError(APIError):
    """4xx: the request was wrong; repeating it will not help."""


class BadRequest(ClientError):
    """400 (malformed request); also the base of 422."""


class Unauthorized(ClientError):
    """401: missing or wrong API key."""


class NotFound(ClientError):
    """404: no such job, model, route or result."""


class Conflict(ClientError):
    """409: e.g. cancelling a finished job, results not ready, an Idempotency-Key reused."""


class Gone(ClientError):
    """410: the job's results were deleted after the retention period."""


class PayloadTooLarge(ClientError):
    """413: the request body, or a JSON trajectory slice, is over the service's cap."""


class UnprocessableEntity(BadRequest):
    """422: invalid scenario or parameters; `errors` lists each field and why."""


class TooManyRequests(ClientError):
    """429: the queue is full; retry after `retry_after` seconds."""

    @property
    def retry_after(self) -> float | None:
        value = self.headers.get("Retry-After")
        try:
            return float(value) if value is not None else None
        except ValueError:
            return None


class ServerError(APIError):
    """5xx: the service failed; the request may succeed later."""


class ServiceUnavailable(ServerError):
    """503: the service cannot take jobs right now."""


class JobTimeout(FlocklabError, TimeoutError):
    """`Job.wait` ran out of time; the job goes on running."""


class SweepFailed(FlocklabError):
    """`wait()` found the sweep ended without succeeding (failed, timed out, cancelled).
    `status` is its final `SweepStatus`; the runs finished before the end may still be
    fetched with `table()`."""

    def __init__(self, status: SweepStatus):
        self.status = status
        why = f": {status.error.detail}" if status.error and status.error.detail else ""
        super().__init__(f"sweep {status.id} {status.status} after {status.runs_done} of "
                         f"{status.runs_total} runs{why}")


_BY_STATUS: dict[int, type[APIError]] = {
    400: BadRequest, 401: Unauthorized, 404: NotFound, 409: Conflict, 410: Gone,
    413: PayloadTooLarge, 422: UnprocessableEntity, 429: TooManyRequests,
    503: ServiceUnavailable,
}


def raise_for_status(response: httpx.Response) -> None:
    """Raise the matching APIError for an error response (the body is already read)."""
    if response.status_code < 400:
        return
    try:
        body = response.json()
    except ValueError:
        body = None
    if not isinstance(body, dict):
        body = {"title": response.reason_phrase, "status": response.status_code,
                "detail": response.text[:500] or None}
    status = response.status_code
    cls = _BY_STATUS.get(status) or (ServerError if status >= 500 else ClientError)
    raise cls(status, body, response.headers)
