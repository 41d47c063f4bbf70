"""What the sync and async clients share: request building, response decoding and the
handle base of a job of either kind (`HandleFields`: a run's `JobFields`, a sweep's
`SweepFields`).

The two clients differ only in whether they await httpx; everything else lives here (a
sweep's tables are decoded in `_tables`).
"""

from __future__ import annotations

import base64
import io
import json
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, ClassVar, TextIO

import httpx
import numpy as np

from flocklab.schemas import Problem, Scenario
from flocklab.schemas.status import JobView, LifecycleView, SweepStatus
from flocklab.schemas.sweep import Sweep
from flocklab.schemas.version import version

from .errors import JobTimeout

DEFAULT_URL = "http://127.0.0.1:8000"
LONG_POLL_SECONDS = 10.0  # one GET ?wait= waits at most this long


class ClientBase:
    """What `Client` and `AsyncClient` hold: where the service is, how long a request may
    take, the key, and the httpx client (of `httpx_class`), made on first use."""

    httpx_class: ClassVar[type[httpx.Client] | type[httpx.AsyncClient]]

    def __init__(self, base_url: str = DEFAULT_URL, api_key: str | None = None, *,
                 transport: httpx.BaseTransport | httpx.AsyncBaseTransport | None = None,
                 timeout: float = 30.0):
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self._api_key = api_key
        self._transport = transport
        self._http: Any = None

    @property
    def http(self) -> Any:
        if self._http is None:
            self._http = self.httpx_class(base_url=self.base_url, headers=headers(self._api_key),
                                          transport=self._transport,  # type: ignore[arg-type]
                                          timeout=self.timeout)
        return self._http


def headers(api_key: str | None) -> dict[str, str]:
    h = {"Accept": "application/json, application/problem+json",
         "User-Agent": f"flocklab-client/{version()}"}
    if api_key:
        h["Authorization"] = f"Bearer {api_key}"
    return h


def job_body(scenario: Scenario | dict[str, Any] | None, preset: str | None,
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


def sweep_body(spec: Sweep | dict[str, Any] | None, sweep_preset: str | None,
               timeout_seconds: float | None) -> dict[str, Any]:
    """The POST /v1/sweeps body: the bare sweep, or wrapped (a named sweep, a timeout)."""
    if (spec is None) == (sweep_preset is None):
        raise ValueError("give exactly one of a sweep and sweep_preset=")
    if sweep_preset is not None:
        body: dict[str, Any] = {"sweep_preset": sweep_preset}
    else:
        sweep = spec.model_dump(mode="json") if isinstance(spec, Sweep) else spec
        if not isinstance(sweep, dict):
            raise TypeError("a sweep is a schemas.sweep.Sweep or a dict")
        if timeout_seconds is None:
            return sweep
        body = {"sweep": sweep}
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


def list_params(status: str | Sequence[str] | None, page_size: int, limit: int | None,
                **filters: Any) -> dict[str, Any]:
    """Query of a list GET: a page of `page_size` rows (fewer when `limit` wants fewer),
    only these statuses, and the `filters` given (None: none)."""
    if limit is not None and limit < 1:
        raise ValueError("limit must be at least 1 (None: every job)")
    params: dict[str, Any] = {"limit": page_size if limit is None else min(page_size, limit)}
    if status is not None:
        params["status"] = [status] if isinstance(status, str) else list(status)
    return params | {k: v for k, v in filters.items() if v is not None}


class Pager:
    """A list's loop, less its request: `take(page)` gives the page's rows (no more than
    `limit` in all), then `query` asks for the next page, or is None: no more to fetch."""

    def __init__(self, query: dict[str, Any], limit: int | None):
        self.query: dict[str, Any] | None = query
        self.limit, self.count = limit, 0

    def take(self, page: dict[str, Any]) -> list[dict[str, Any]]:
        items = page["items"]
        if self.limit is not None:
            items = items[:self.limit - self.count]
        self.count += len(items)
        if not page["next_cursor"] or (self.limit is not None and self.count >= self.limit):
            self.query = None
        elif self.query is not None:
            self.query["cursor"] = page["next_cursor"]
        return items


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


class Follower:
    """A handle's event stream (`…/events`), less its transport: `feed(line)` gives the
    views that line completes (each also becomes the handle's `data`); `ended` turns true
    once the stream says the job finished, or that the server is shutting down."""

    def __init__(self, handle: HandleFields):
        self.handle, self.parser, self.ended = handle, SSEParser(), False

    def feed(self, line: str) -> list[dict[str, Any]]:
        views = []
        for event, data in self.parser.feed(line):
            if event == self.handle.noun:
                self.handle.data = data
                views.append(data)
            elif event in ("end", "shutdown"):
                self.ended = True
                break
        return views


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


class HandleFields:
    """What every handle shares, a run's or a sweep's, sync or async: `state` is the view
    of the last response (typed: datetimes, the error as a `Problem`), `data` the same as
    JSON. The kinds set where they live (`route`) and what their view is (`view`)."""

    view: ClassVar[type[LifecycleView]]
    route: ClassVar[str]  # "/v1/jobs" or "/v1/sweeps"
    noun: ClassVar[str]  # in messages: "job" or "sweep"
    state: Any
    _data: dict[str, Any]

    @property
    def data(self) -> dict[str, Any]:
        return self._data

    @data.setter
    def data(self, value: dict[str, Any]) -> None:
        self.state = self.view.model_validate(value)
        self._data = value

    @property
    def id(self) -> str:
        return self.state.id

    @property
    def progress(self) -> float:
        return self.state.progress

    @property
    def done(self) -> bool:
        return self.state.done

    def path(self, tail: str = "") -> str:
        return f"{self.route}/{self.id}{tail}"


class JobFields(HandleFields):
    """The fields of a run's handle (`Job`, `AsyncJob`)."""

    view = JobView
    route = "/v1/jobs"
    noun = "job"
    state: JobView

    @property
    def status(self) -> str:
        return self.state.status

    @property
    def error(self) -> Problem | None:
        """The problem that ended the job (failed, timed out), else None."""
        return self.state.error if self.status in ("failed", "timed_out") else None

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.id} {self.status} {self.progress:.0%}>"


class SweepFields(HandleFields):
    """The fields of a sweep's handle (`SweepJob`, `AsyncSweepJob`); its `status()` is a
    request (the sweep re-read), not a field."""

    view = SweepStatus
    route = "/v1/sweeps"
    noun = "sweep"
    state: SweepStatus

    def __repr__(self) -> str:
        s = self.state
        return f"<{type(self).__name__} {s.id} {s.status} {s.runs_done}/{s.runs_total} runs>"


class Waiter:
    """`wait()`'s loop, less its request: iterating gives the seconds of each next
    long-poll until the handle is done, drawing the bar before each, and raises
    JobTimeout at the deadline; leaving the `with` block ends the bar's line. A bar
    long-polls for each change (`until`), to show every step."""

    def __init__(self, handle: HandleFields, timeout: float | None, progress: bool | None):
        self.handle, self.timeout = handle, timeout
        self.deadline = None if timeout is None else time.monotonic() + timeout
        self.bar = ProgressBar(progress)
        self.until = "change" if self.bar.enabled else "finished"

    def __iter__(self) -> Iterator[float]:
        h = self.handle
        self.bar.update(h)
        while not h.done:
            remaining = LONG_POLL_SECONDS if self.deadline is None else (
                self.deadline - time.monotonic())
            if remaining <= 0:
                raise JobTimeout(f"{h.noun} {h.id} still {h.state.status} after "
                                 f"{self.timeout} s")
            yield min(LONG_POLL_SECONDS, remaining)
            self.bar.update(h)

    def __enter__(self) -> Waiter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.bar.close()


class ProgressBar:
    """A one-line progress bar on a terminal (stderr); silent when disabled."""

    WIDTH = 30

    def __init__(self, enabled: bool | None, stream: TextIO | None = None):
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self._last = ""

    def update(self, handle: HandleFields) -> None:
        if not self.enabled:
            return
        filled = int(handle.progress * self.WIDTH)
        line = (f"\r{handle.id[:8]} [{'#' * filled}{'.' * (self.WIDTH - filled)}] "
                f"{handle.progress:4.0%} {handle.state.status:<10}")
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
