"""The synchronous client: `Client` and the handles it returns (`Job`, `SweepJob`: both a
`Handle`, which refreshes, waits for and cancels a job of either kind)."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import httpx
import numpy as np

from flocklab.schemas import Scenario
from flocklab.schemas.status import SweepStatus
from flocklab.schemas.sweep import Sweep

from . import _core, _tables
from .errors import SweepFailed, raise_for_status

if TYPE_CHECKING:
    import pandas

H = TypeVar("H", bound="Handle")


class Client(_core.ClientBase):
    """A flocklab service client.

    >>> with Client("http://127.0.0.1:8000") as c:
    ...     job = c.submit(preset="vicsek-1995").wait()
    ...     traj = job.trajectory(stride=10)

    `transport` is passed to httpx (tests use `httpx.MockTransport` or a WSGI/ASGI
    transport); the underlying httpx client is created on first use.
    """

    httpx_class = httpx.Client
    http: httpx.Client

    def close(self) -> None:
        if self._http is not None:
            self._http.close()
            self._http = None

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        """Send a request; raise the status's APIError subclass on 4xx/5xx."""
        response = self.http.request(method, path, **kwargs)
        raise_for_status(response)
        return response

    # -- jobs and sweeps -------------------------------------------------------------------

    def submit(self, scenario: Scenario | dict[str, Any] | None = None, *,
               preset: str | None = None, overrides: dict[str, Any] | None = None,
               timeout_seconds: float | None = None, idempotency_key: str | None = None
               ) -> Job:
        """Submit a scenario (a `Scenario` or a dict) or a preset; returns the queued job."""
        body = _core.job_body(scenario, preset, overrides, timeout_seconds)
        return self._submit(Job, body, idempotency_key)

    def job(self, job_id: str) -> Job:
        return Job(self, self.request("GET", f"{Job.route}/{job_id}").json())

    def jobs(self, status: str | Sequence[str] | None = None, model: str | None = None,
             page_size: int = 100, limit: int | None = None) -> Iterator[Job]:
        """Jobs newest first, fetched a page at a time: every one, or the first `limit`."""
        return self._list(Job, status, page_size, limit, model=model)

    def sweep(self, spec: Sweep | dict[str, Any] | None = None, *,
              sweep_preset: str | None = None, timeout_seconds: float | None = None,
              idempotency_key: str | None = None) -> SweepJob:
        """Submit a sweep (a `schemas.sweep.Sweep` or a dict) or a named sweep
        (`sweep_preset="vicsek-1995-fig2a"`); returns its handle.

        >>> table = c.sweep(spec).wait()      # numpy structured array, a row per grid point
        """
        body = _core.sweep_body(spec, sweep_preset, timeout_seconds)
        return self._submit(SweepJob, body, idempotency_key)

    def get_sweep(self, sweep_id: str) -> SweepJob:
        return SweepJob(self, self.request("GET", f"{SweepJob.route}/{sweep_id}").json())

    def sweeps(self, status: str | Sequence[str] | None = None, page_size: int = 100
               ) -> Iterator[SweepJob]:
        """Every sweep, newest first, fetched a page at a time."""
        return self._list(SweepJob, status, page_size, None)

    def _submit(self, cls: type[H], body: dict[str, Any], idempotency_key: str | None) -> H:
        hdrs = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
        return cls(self, self.request("POST", cls.route, json=body, headers=hdrs).json())

    def _list(self, cls: type[H], status: str | Sequence[str] | None, page_size: int,
              limit: int | None, **params: Any) -> Iterator[H]:
        pager = _core.Pager(_core.list_params(status, page_size, limit, **params), limit)
        while pager.query is not None:
            for item in pager.take(self.request("GET", cls.route, params=pager.query).json()):
                yield cls(self, item)

    # -- catalog --------------------------------------------------------------------------

    def models(self) -> list[dict[str, Any]]:
        return self.request("GET", "/v1/models").json()

    def model_schema(self, kind: str) -> dict[str, Any]:
        return self.request("GET", f"/v1/models/{kind}").json()

    def presets(self) -> list[dict[str, Any]]:
        return self.request("GET", "/v1/presets").json()

    def health(self) -> dict[str, Any]:
        return self.request("GET", "/healthz").json()


class Handle(_core.HandleFields):
    """A handle on a job of either kind; its fields are those of the last response."""

    def __init__(self, client: Client, data: dict[str, Any]):
        self.client = client
        self.data = data

    def _get(self, wait: float = 0.0, until: str = "finished") -> None:
        """Re-read; with `wait`, long-poll until it has finished (`until="change"`: until
        it changes) or `wait` s pass."""
        self.data = self.client.request("GET", self.path(),
                                        params=_core.wait_params(wait, until),
                                        timeout=self.client.timeout + wait).json()

    def _wait(self, timeout: float | None, progress: bool | None) -> None:
        with _core.Waiter(self, timeout, progress) as waiter:
            for seconds in waiter:
                self._get(seconds, waiter.until)

    def _cancel(self) -> None:
        self.data = self.client.request("POST", self.path("/cancel")).json()


class Job(_core.JobFields, Handle):
    """A handle on one job; its fields are those of the last response (`refresh()`)."""

    def refresh(self, wait: float = 0.0, until: str = "finished") -> Job:
        """Re-read the job; with `wait`, long-poll until it has finished (`until=
        "change"`: until it changes) or `wait` s pass."""
        self._get(wait, until)
        return self

    def wait(self, timeout: float | None = None, progress: bool | None = None) -> Job:
        """Block until the job has finished; returns it (check `status`, `error`).

        Raises JobTimeout after `timeout` seconds. `progress` draws a bar on stderr
        (default: when stderr is a terminal), which long-polls for each change.
        """
        self._wait(timeout, progress)
        return self

    def events(self) -> Iterator[dict[str, Any]]:
        """Follow the job's Server-Sent Events: yields the job (as a dict, also kept in
        `data`) at each change, and ends once it has finished (or the server shuts down:
        then `done` is still false)."""
        follower = _core.Follower(self)
        with self.client.http.stream("GET", self.path("/events"),
                                     headers={"Accept": "text/event-stream"}) as r:
            if r.status_code >= 400:
                r.read()
                raise_for_status(r)
            for line in r.iter_lines():
                yield from follower.feed(line)
                if follower.ended:
                    return

    def cancel(self) -> Job:
        self._cancel()
        return self

    def metrics(self) -> dict[str, Any]:
        """{"summary": dict, "observables": {name: float array}}."""
        return _core.metrics(self.client.request("GET", f"/v1/jobs/{self.id}/metrics").json())

    def observables(self, start: int = 0) -> dict[str, Any]:
        """The observables from row `start` on, also while the job runs: {"partial":
        true until the job has ended (more rows may come), "status", "observables": {name:
        float array}}; once it has ended, the final series (what `metrics()` holds)."""
        pages: list[dict[str, Any]] = []
        while not pages or pages[-1]["more"]:
            pages.append(self.client.request("GET", f"/v1/jobs/{self.id}/observables",
                                             params={"start": start}).json())
            start += pages[-1]["rows"]
        return _core.observable_pages(pages)

    def trajectory(self, start: int | None = None, stop: int | None = None, stride: int = 1,
                   agents: slice | Sequence[int] | str | None = None,
                   arrays: Sequence[str] | str | None = None) -> dict[str, np.ndarray]:
        """Frames start:stop:stride for the chosen agents: {"step", "time", "agents",
        and each recorded array shaped (frames, agents[, components])}."""
        params = _core.trajectory_params(start, stop, stride, agents, arrays, "npz")
        r = self.client.request("GET", f"/v1/jobs/{self.id}/trajectory", params=params)
        return _core.load_npz(r.content)

    def snapshot(self, path: str | Path | None = None, *, frame: int | None = None,
                 time: float | None = None, width: int = 800, height: int = 800,
                 field: str = "auto", edges: bool | None = None, trails: int | None = None,
                 overlays: bool = True) -> bytes | Path:
        """A frame drawn as the papers do (PNG; default the last frame): its bytes, or
        saved to `path`. `field`: auto, arrows, density or polarization; `trails`: frames
        of path behind each agent (0: all); `edges`: default at N <= 200."""
        params = _core.snapshot_params(frame, time, width, height, field, edges, trails,
                                       overlays)
        r = self.client.request("GET", f"/v1/jobs/{self.id}/render/snapshot.png",
                                params=params, timeout=max(self.client.timeout, 330.0))
        return _core.save_or_return(r.content, path)

    def download(self, path: str | Path, format: str = "h5md") -> Path:
        """Save the whole H5MD file (format "gsd": the GSD file, which a job recorded with
        recording.format gsd has), streamed, and check its sha-256."""
        path = Path(path)
        digest = hashlib.sha256()
        name = _core.trajectory_file(format)
        with self.client.http.stream("GET", f"/v1/jobs/{self.id}/{name}") as r:
            if r.status_code >= 400:
                r.read()
                raise_for_status(r)
            expected = r.headers.get("Repr-Digest")
            with path.open("wb") as f:
                for chunk in r.iter_bytes():
                    digest.update(chunk)
                    f.write(chunk)
        _core.check_digest(expected, digest.digest(), path)
        return path



class SweepJob(_core.SweepFields, Handle):
    """A handle on one sweep. `state` is the `SweepStatus` of the last response."""

    def status(self, wait: float = 0.0, until: str = "finished") -> SweepStatus:
        """Re-read the sweep; with `wait`, long-poll until it has finished (`until=
        "change"`: until it changes) or `wait` s pass."""
        self._get(wait, until)
        return self.state

    def wait(self, timeout: float | None = None, progress: bool | None = None) -> np.ndarray:
        """Block until the sweep has finished and return its table (`table()`).

        Raises SweepFailed when it failed, timed out or was cancelled, and JobTimeout
        after `timeout` seconds (the sweep goes on). `progress` draws a bar over runs on
        stderr (default: when stderr is a terminal).
        """
        self._wait(timeout, progress)
        if self.state.status != "succeeded":
            raise SweepFailed(self.state)
        return self.table()

    def spec(self) -> Sweep:
        """The sweep as the service stores it (every default filled in)."""
        return Sweep.model_validate_json(self.client.request(
            "GET", f"/v1/sweeps/{self.id}/spec").content)

    def cancel(self) -> SweepStatus:
        """Stop the sweep; the runs it finished stay available (`table()`)."""
        self._cancel()
        return self.state

    def table(self, name: str = "table") -> np.ndarray:
        """A row per grid point: the axes, then each measure's mean, sd, sem and count.
        `name` "runs" gives a row per run, "series" the replica-averaged time series."""
        r = self.client.request("GET", _tables.table_path(self.id, name),
                                params={"format": "json"})
        return _tables.structured(r.json())

    def runs(self) -> np.ndarray:
        return self.table("runs")

    def series(self) -> np.ndarray:
        return self.table("series")

    def table_frame(self, name: str = "table") -> pandas.DataFrame:
        """`table(name)` as a pandas DataFrame (needs pandas, which flocklab does not)."""
        return _tables.frame(self.table(name))

    def csv(self, name: str = "table") -> str:
        """The table exactly as the service stores it (CSV text)."""
        return self.client.request("GET", _tables.table_path(self.id, name),
                                   params={"format": "csv"}).text
