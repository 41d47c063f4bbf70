"""Scenarios and helpers shared by the service tests."""

from __future__ import annotations

import time
from typing import Any

import httpx

PROBLEM = "application/problem+json"
TERMINAL = {"succeeded", "failed", "cancelled", "timed_out"}


def scenario(n: int = 100, steps: int = 20, every: int = 5, **extra: Any) -> dict[str, Any]:
    """A small Vicsek run: N agents in a periodic box, frames every `every` steps."""
    return {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5},
        "space": {"kind": "periodic", "L": 5.0},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": n},
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"every": every, "arrays": ["position", "heading"]},
        "seed": 3,
        **extra,
    }


def long_scenario() -> dict[str, Any]:
    """Runs for minutes unless stopped (N = 1000, 10^5 steps, nothing recorded)."""
    return scenario(n=1000, steps=100_000, every=0)


def submit(http: httpx.Client, body: dict[str, Any], **kw: Any) -> dict[str, Any]:
    r = http.post("/v1/jobs", json=body, **kw)
    assert r.status_code == 202, r.text
    return r.json()


def wait_for(http: httpx.Client, job_id: str, statuses: set[str] = TERMINAL,
             timeout: float = 60.0) -> dict[str, Any]:
    """Long-poll until the job is in one of `statuses` (looking at every change: a
    non-final status may last less than one wait for the end)."""
    deadline = time.monotonic() + timeout
    while True:
        job = http.get(f"/v1/jobs/{job_id}", params={"wait": 2, "until": "change"}).json()
        if job["status"] in statuses:
            return job
        assert time.monotonic() < deadline, f"job still {job['status']} after {timeout} s"


def assert_problem(r: httpx.Response, status: int, loc: str | None = None) -> dict[str, Any]:
    """The response is a problem+json with this status (and names `loc` if given)."""
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers["content-type"]
    body = r.json()
    assert body["status"] == status and body["title"]
    if loc is not None:
        locs = [e["loc"] for e in body.get("errors") or []]
        assert loc in locs, f"{loc!r} not in {locs}"
    return body
