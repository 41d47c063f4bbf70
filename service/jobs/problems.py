"""Problem-details bodies (RFC 9457) built without FastAPI, so workers can make them too.

A job's `error` is the problem that ended it; its `status` is the HTTP status the same
problem would carry in a response (advisory, as RFC 9457 allows).
"""

from __future__ import annotations

from typing import Any

TYPE_PREFIX = "urn:flocklab:problem:"
# What one problem body may carry: enough errors to see the pattern, strings long enough
# for any message the service writes. A hostile body (thousands of bad axes, a 200 KB
# preset name echoed back) made 571 KB answers; the rest is counted, not listed.
MAX_ERRORS = 20
MAX_DETAIL_CHARS = 2000
MAX_FIELD_CHARS = 500


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


def bounded(body: dict[str, Any]) -> dict[str, Any]:
    """`body` within the size limits: the first MAX_ERRORS `errors` (`errors_total`
    counts them all), `detail` and each error's fields cut to MAX_DETAIL_CHARS and
    MAX_FIELD_CHARS characters (the cut is said in the text)."""
    out = dict(body)
    if isinstance(out.get("detail"), str):
        out["detail"] = _cut(out["detail"], MAX_DETAIL_CHARS)
    errors = out.get("errors")
    if isinstance(errors, list):
        if len(errors) > MAX_ERRORS:
            out["errors_total"] = len(errors)
        out["errors"] = [{k: _cut(v, MAX_FIELD_CHARS) if isinstance(v, str) else v
                          for k, v in e.items()} if isinstance(e, dict) else e
                         for e in errors[:MAX_ERRORS]]
    return out


def _cut(text: str, limit: int) -> str:
    return text if len(text) <= limit else (
        f"{text[:limit]}... ({len(text) - limit} more characters)")
