"""What the sync and async clients share: request building and response decoding.

The two clients differ only in whether they await httpx; everything else lives here.
"""

from __future__ import annotations

import base64
import io
import json
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from flocklab.schemas import Problem, Scenario
from flocklab.schemas.status import JobView
from flocklab.schemas.version import version

DEFAULT_URL = "http://127.0.0.1:8000"
TERMINAL = frozenset({"succeeded", "failed", "cancelled", "timed_out"})
LONG_POLL_SECONDS = 10.0  # one GET ?wait= waits at most this long


def headers(api_key: str | None) -> dict[str, str]:
    h = {"Accept": "application/json, application/problem+json",
         "User-Agent": f"flocklab-client/{version()}"}
    if api_key:
        h["Authorization"] = f"Bearer {api_key}"
    return h


def submission(scenario: Scenario | dict[str, Any] | None, preset: str | None,
               overrides: dict[str, Any] | None, timeout_seconds: float | None
               ) -> dict[str, Any]:
    """The POST /v1/jobs body."""
    if (scenario is None) == (preset is None):
        raise ValueError("give exactly one of a scenario and preset=")
    body: dict[str, Any]
    if preset is not None:
        body = {"preset": preset}
        if overrides:
            body["overrides"] = overrides
    else:
        if overrides:
            raise ValueError("overrides= applies to a preset only")
        data = scenario.model_dump(mode="json") if isinstance(scenario, Scenario) else scenario
        body = {"scenario": data}
    if timeout_seconds is not None:
        body["timeout_seconds"] = timeout_seconds
    return body


def trajectory_params(start: int | None, stop: int | None, stride: int,
                      agents: slice | Sequence[int] | str | None,
                      arrays: Sequence[str] | str | None, fmt: str) -> dict[str, Any]:
    params: dict[str, Any] = {"format": fmt, "stride": stride}
    if start is not None:
        params["start"] = start
    if stop is not None:
        params["stop"] = stop
    if agents is not None:
        params["agents"] = _agents(agents)
    if arrays is not None:
        params["arrays"] = arrays if isinstance(arrays, str) else ",".join(arrays)
    return params


def snapshot_params(frame: int | None, time: float | None, width: int, height: int,
                    field: str, edges: bool | None, trails: int | None, overlays: bool
                    ) -> dict[str, Any]:
    """Query of `GET /v1/jobs/{id}/render/snapshot.png` (None: the server's default)."""
    given = {"frame": frame, "time": time, "width": width, "height": height, "field": field,
             "edges": edges, "trails": trails, "overlays": overlays}
    return {k: (str(v).lower() if isinstance(v, bool) else v) for k, v in given.items()
            if v is not None}


def save_or_return(content: bytes, path: str | Path | None) -> bytes | Path:
    if path is None:
        return content
    path = Path(path)
    path.write_bytes(content)
    return path


def _agents(agents: slice | Sequence[int] | str) -> str:
    if isinstance(agents, str):
        return agents
    if isinstance(agents, slice):
        parts = ["" if v is None else str(int(v)) for v in (agents.start, agents.stop)]
        if agents.step is not None:
            parts.append(str(int(agents.step)))
        return ":".join(parts)
    return ",".join(str(int(i)) for i in agents)


def wait_params(wait: float, until: str) -> dict[str, Any] | None:
    """Query of a long-poll GET: `until` is "finished" (the server's default) or "change"."""
    if until not in ("finished", "change"):
        raise ValueError(f"until must be 'finished' or 'change', not {until!r}")
    if wait <= 0:
        return None
    return {"wait": wait} if until == "finished" else {"wait": wait, "until": until}


def page_size_for(limit: int | None, page_size: int) -> int:
    if limit is not None and limit < 1:
        raise ValueError("limit must be at least 1 (None: every job)")
    return page_size if limit is None else min(page_size, limit)


class SSEParser:
    """Server-Sent Events from lines of text: `feed(line)` yields (event, data) at each
    blank line that ends an event; comments (keep-alives) are skipped."""

    def __init__(self) -> None:
        self.event: str = "message"
        self.data: list[str] = []

    def feed(self, line: str) -> Iterator[tuple[str, Any]]:
        if line == "":
            if self.data:
                yield self.event, json.loads("\n".join(self.data))
            self.event, self.data = "message", []
        elif line.startswith(":"):
            return
        else:
            field, _, value = line.partition(":")
            value = value.removeprefix(" ")
            if field == "event":
                self.event = value
            elif field == "data":
                self.data.append(value)


def load_npz(content: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(content), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def metrics(body: dict[str, Any]) -> dict[str, Any]:
    """Observables as float arrays (missing values as NaN), the summary as sent."""
    obs = {k: np.array([np.nan if v is None else v for v in vals], dtype=float)
           for k, vals in body["observables"].items()}
    return {"summary": body["summary"], "observables": obs}


def observable_pages(pages: list[dict[str, Any]]) -> dict[str, Any]:
    """`GET …/observables` answers, paged with `start`, as one: each column a float array
    (missing values NaN); `partial` and `status` as the last page says."""
    names: list[str] = []
    for page in pages:
        names += [n for n in page["observables"] if n not in names]
    obs = {n: np.array([np.nan if v is None else v for page in pages
                        for v in page["observables"].get(n, [])], dtype=float) for n in names}
    return {"partial": pages[-1]["partial"], "status": pages[-1]["status"],
            "observables": obs}


class JobFields:
    """The fields of a job, shared by `Job` and `AsyncJob`: `state` is the `JobView` of the
    last response (typed: datetimes, the error as a `Problem`), `data` the same as JSON."""

    state: JobView
    _data: dict[str, Any]

    @property
    def data(self) -> dict[str, Any]:
        return self._data

    @data.setter
    def data(self, value: dict[str, Any]) -> None:
        self.state = JobView.model_validate(value)
        self._data = value

    @property
    def id(self) -> str:
        return self.state.id

    @property
    def status(self) -> str:
        return self.state.status

    @property
    def progress(self) -> float:
        return self.state.progress

    @property
    def done(self) -> bool:
        return self.status in TERMINAL

    @property
    def error(self) -> Problem | None:
        """The problem that ended the job (failed, timed out), else None."""
        return self.state.error if self.status in ("failed", "timed_out") else None

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.id} {self.status} {self.progress:.0%}>"


class ProgressBar:
    """A one-line progress bar on a terminal (stderr); silent when disabled."""

    WIDTH = 30

    def __init__(self, enabled: bool | None, stream: TextIO | None = None):
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self._last = ""

    def update(self, job: JobFields) -> None:
        if not self.enabled:
            return
        filled = int(job.progress * self.WIDTH)
        line = (f"\r{job.id[:8]} [{'#' * filled}{'.' * (self.WIDTH - filled)}] "
                f"{job.progress:4.0%} {job.status:<10}")
        if line != self._last:
            self._last = line
            self.stream.write(line)
            self.stream.flush()

    def close(self) -> None:
        if self.enabled and self._last:
            self.stream.write("\n")
            self.stream.flush()


# The whole trajectory files a job may have, by `recording.format` name.
TRAJECTORY_FILES = {"h5md": "trajectory.h5", "gsd": "trajectory.gsd"}


def trajectory_file(format: str) -> str:
    """The file name of a trajectory format ("h5md" or "gsd")."""
    if format not in TRAJECTORY_FILES:
        raise ValueError(f"format must be one of {', '.join(TRAJECTORY_FILES)}, not {format!r}")
    return TRAJECTORY_FILES[format]


def check_digest(header: str | None, actual: bytes, path: Path) -> None:
    """Compare a Repr-Digest header with the sha-256 of what was saved; delete on mismatch."""
    if header and header.startswith("sha-256=:"):
        expected = base64.b64decode(header[len("sha-256=:"):].rstrip(":"))
        if expected != actual:
            path.unlink(missing_ok=True)
            raise OSError(f"download of {path.name} is corrupt (sha-256 mismatch)")
