"""Problem-details bodies (RFC 9457) built without FastAPI, so workers can make them too.

A job's `error` is the problem that ended it; its `status` is the HTTP status the same
problem would carry in a response (advisory, as RFC 9457 allows).
"""

from __future__ import annotations

from typing import Any

TYPE_PREFIX = "urn:flocklab:problem:"


def problem(slug: str, title: str, status: int, detail: str | None = None, **extra: Any
            ) -> dict[str, Any]:
    """A problem body; `slug` names the problem type (documented in docs/SERVICE.md)."""
    body: dict[str, Any] = {"type": TYPE_PREFIX + slug, "title": title, "status": status}
    if detail is not None:
        body["detail"] = detail
    body.update(extra)
    return body


def cluster_problem(exc: Any) -> dict[str, Any]:
    """The problem body of a ClusterError (cluster unreachable, or lost mid-job)."""
    from flocklab.service.sweeps.ray_executor import ClusterUnavailable

    slug, title = (("cluster-unavailable", "Ray cluster unavailable")
                   if isinstance(exc, ClusterUnavailable) else
                   ("cluster-task-lost", "Ray task lost"))
    return problem(slug, title, 503, str(exc), ray_address=exc.address)
