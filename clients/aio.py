"""The asynchronous twin of `clients.sync`: `AsyncClient` and `AsyncJob`."""

from __future__ import annotations

import hashlib
import time
from collections.abc import AsyncIterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import httpx
import numpy as np

from flocklab.schemas import Scenario
from flocklab.schemas.status import SweepStatus
from flocklab.schemas.sweep import Sweep

from . import _core, _sweeps
from .errors import JobTimeout, raise_for_status

if TYPE_CHECKING:
    import pandas


class AsyncClient:
    """Like `Client`, with every network call awaited.

    >>> async with AsyncClient() as c:
    ...     job = await (await c.submit(preset="vicsek-1995")).wait()
    """

    def __init__(self, base_url: str = _core.DEFAULT_URL, api_key: str | None = None, *,
                 transport: httpx.AsyncBaseTransport | None = None, timeout: float = 30.0):
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self._api_key = api_key
        self._transport = transport
        self._http: httpx.AsyncClient | None = None

    @property
    def http(self) -> httpx.AsyncClient:
        if self._http is None:
            self._http = httpx.AsyncClient(base_url=self.base_url,
                                           headers=_core.headers(self._api_key),
                                           transport=self._transport, timeout=self.timeout)
        return self._http

    async def aclose(self) -> None:
        if self._http is not None:
            await self._http.aclose()
            self._http = None

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        response = await self.http.request(method, path, **kwargs)
        raise_for_status(response)
        return response

    async def submit(self, scenario: Scenario | dict[str, Any] | None = None, *,
                     preset: str | None = None, overrides: dict[str, Any] | None = None,
                     timeout_seconds: float | None = None, idempotency_key: str | None = None
                     ) -> AsyncJob:
        body = _core.submission(scenario, preset, overrides, timeout_seconds)
        hdrs = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
        r = await self.request("POST", "/v1/jobs", json=body, headers=hdrs)
        return AsyncJob(self, r.json())

    async def job(self, job_id: str) -> AsyncJob:
        return AsyncJob(self, (await self.request("GET", f"/v1/jobs/{job_id}")).json())

    async def jobs(self, status: str | Sequence[str] | None = None, model: str | None = None,
                   page_size: int = 100, limit: int | None = None
                   ) -> AsyncIterator[AsyncJob]:
        params: dict[str, Any] = {"limit": _core.page_size_for(limit, page_size)}
        if status is not None:
            params["status"] = [status] if isinstance(status, str) else list(status)
        if model is not None:
            params["model"] = model
        count = 0
        while True:
            page = (await self.request("GET", "/v1/jobs", params=params)).json()
            for item in page["items"]:
                yield AsyncJob(self, item)
                count += 1
                if limit is not None and count >= limit:
                    return
            if not page["next_cursor"]:
                return
            params["cursor"] = page["next_cursor"]

    async def sweep(self, spec: Sweep | dict[str, Any] | None = None, *,
                    sweep_preset: str | None = None, timeout_seconds: float | None = None,
                    idempotency_key: str | None = None) -> AsyncSweepJob:
        body = _sweeps.submission(spec, sweep_preset, timeout_seconds)
        hdrs = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
        r = await self.request("POST", "/v1/sweeps", json=body, headers=hdrs)
        return AsyncSweepJob(self, SweepStatus.model_validate(r.json()))

    async def get_sweep(self, sweep_id: str) -> AsyncSweepJob:
        r = await self.request("GET", f"/v1/sweeps/{sweep_id}")
        return AsyncSweepJob(self, SweepStatus.model_validate(r.json()))

    async def sweeps(self, status: str | Sequence[str] | None = None, page_size: int = 100
                     ) -> AsyncIterator[AsyncSweepJob]:
        params: dict[str, Any] = {"limit": page_size}
        if status is not None:
            params["status"] = [status] if isinstance(status, str) else list(status)
        while True:
            page = (await self.request("GET", "/v1/sweeps", params=params)).json()
            for item in page["items"]:
                yield AsyncSweepJob(self, SweepStatus.model_validate(item))
            if not page["next_cursor"]:
                return
            params["cursor"] = page["next_cursor"]

    async def models(self) -> list[dict[str, Any]]:
        return (await self.request("GET", "/v1/models")).json()

    async def model_schema(self, kind: str) -> dict[str, Any]:
        return (await self.request("GET", f"/v1/models/{kind}")).json()

    async def presets(self) -> list[dict[str, Any]]:
        return (await self.request("GET", "/v1/presets")).json()

    async def health(self) -> dict[str, Any]:
        return (await self.request("GET", "/healthz")).json()


class AsyncJob(_core.JobFields):
    def __init__(self, client: AsyncClient, data: dict[str, Any]):
        self.client = client
        self.data = data

    async def refresh(self, wait: float = 0.0, until: str = "finished") -> AsyncJob:
        r = await self.client.request("GET", f"/v1/jobs/{self.id}",
                                      params=_core.wait_params(wait, until),
                                      timeout=self.client.timeout + wait)
        self.data = r.json()
        return self

    async def wait(self, timeout: float | None = None, progress: bool | None = None
                   ) -> AsyncJob:
        deadline = None if timeout is None else time.monotonic() + timeout
        bar = _core.ProgressBar(progress)
        until = "change" if bar.enabled else "finished"
        try:
            bar.update(self)
            while not self.done:
                remaining = _core.LONG_POLL_SECONDS if deadline is None else (
                    deadline - time.monotonic())
                if remaining <= 0:
                    raise JobTimeout(f"job {self.id} still {self.status} after {timeout} s")
                await self.refresh(wait=min(_core.LONG_POLL_SECONDS, remaining), until=until)
                bar.update(self)
        finally:
            bar.close()
        return self

    async def events(self) -> AsyncIterator[dict[str, Any]]:
        """The asynchronous twin of `Job.events()`."""
        parser = _core.SSEParser()
        async with self.client.http.stream("GET", f"/v1/jobs/{self.id}/events",
                                           headers={"Accept": "text/event-stream"}) as r:
            if r.status_code >= 400:
                await r.aread()
                raise_for_status(r)
            async for line in r.aiter_lines():
                for event, data in parser.feed(line):
                    if event == "job":
                        self.data = data
                        yield data
                    elif event in ("end", "shutdown"):
                        return

    async def cancel(self) -> AsyncJob:
        self.data = (await self.client.request("POST", f"/v1/jobs/{self.id}/cancel")).json()
        return self

    async def metrics(self) -> dict[str, Any]:
        r = await self.client.request("GET", f"/v1/jobs/{self.id}/metrics")
        return _core.metrics(r.json())

    async def observables(self, start: int = 0) -> dict[str, Any]:
        """As `Job.observables`: the rows so far while the job runs, all once it ended."""
        pages: list[dict[str, Any]] = []
        while not pages or pages[-1]["more"]:
            r = await self.client.request("GET", f"/v1/jobs/{self.id}/observables",
                                          params={"start": start})
            pages.append(r.json())
            start += pages[-1]["rows"]
        return _core.observable_pages(pages)

    async def trajectory(self, start: int | None = None, stop: int | None = None,
                         stride: int = 1, agents: slice | Sequence[int] | str | None = None,
                         arrays: Sequence[str] | str | None = None) -> dict[str, np.ndarray]:
        params = _core.trajectory_params(start, stop, stride, agents, arrays, "npz")
        r = await self.client.request("GET", f"/v1/jobs/{self.id}/trajectory", params=params)
        return _core.load_npz(r.content)

    async def snapshot(self, path: str | Path | None = None, *, frame: int | None = None,
                       time: float | None = None, width: int = 800, height: int = 800,
                       field: str = "auto", edges: bool | None = None,
                       trails: int | None = None, overlays: bool = True) -> bytes | Path:
        params = _core.snapshot_params(frame, time, width, height, field, edges, trails,
                                       overlays)
        r = await self.client.request("GET", f"/v1/jobs/{self.id}/render/snapshot.png",
                                      params=params, timeout=max(self.client.timeout, 330.0))
        return _core.save_or_return(r.content, path)

    async def download(self, path: str | Path, format: str = "h5md") -> Path:
        path = Path(path)
        digest = hashlib.sha256()
        name = _core.trajectory_file(format)
        async with self.client.http.stream("GET", f"/v1/jobs/{self.id}/{name}") as r:
            if r.status_code >= 400:
                await r.aread()
                raise_for_status(r)
            expected = r.headers.get("Repr-Digest")
            with path.open("wb") as f:
                async for chunk in r.aiter_bytes():
                    digest.update(chunk)
                    f.write(chunk)
        _core.check_digest(expected, digest.digest(), path)
        return path


class AsyncSweepJob:
    """The asynchronous twin of `clients.sync.SweepJob`."""

    def __init__(self, client: AsyncClient, state: SweepStatus):
        self.client = client
        self.state = state

    @property
    def id(self) -> str:
        return self.state.id

    @property
    def done(self) -> bool:
        return self.state.status in _core.TERMINAL

    def __repr__(self) -> str:
        s = self.state
        return f"<AsyncSweepJob {s.id} {s.status} {s.runs_done}/{s.runs_total} runs>"

    async def status(self, wait: float = 0.0, until: str = "finished") -> SweepStatus:
        r = await self.client.request("GET", f"/v1/sweeps/{self.id}",
                                      params=_core.wait_params(wait, until),
                                      timeout=self.client.timeout + wait)
        self.state = SweepStatus.model_validate(r.json())
        return self.state

    async def wait(self, timeout: float | None = None, progress: bool | None = None
                   ) -> np.ndarray:
        deadline = None if timeout is None else time.monotonic() + timeout
        bar = _core.ProgressBar(progress)
        until = "change" if bar.enabled else "finished"  # a bar shows every run's end
        try:
            bar.update(self.state)  # type: ignore[arg-type]
            while not self.done:
                remaining = _core.LONG_POLL_SECONDS if deadline is None else (
                    deadline - time.monotonic())
                if remaining <= 0:
                    raise JobTimeout(f"sweep {self.id} still {self.state.status} after "
                                     f"{timeout} s")
                await self.status(wait=min(_core.LONG_POLL_SECONDS, remaining),
                                  until=until)
                bar.update(self.state)  # type: ignore[arg-type]
        finally:
            bar.close()
        if self.state.status != "succeeded":
            raise _sweeps.SweepFailed(self.state)
        return await self.table()

    async def spec(self) -> Sweep:
        r = await self.client.request("GET", f"/v1/sweeps/{self.id}/spec")
        return Sweep.model_validate_json(r.content)

    async def cancel(self) -> SweepStatus:
        r = await self.client.request("POST", f"/v1/sweeps/{self.id}/cancel")
        self.state = SweepStatus.model_validate(r.json())
        return self.state

    async def table(self, name: str = "table") -> np.ndarray:
        r = await self.client.request("GET", _sweeps.table_path(self.id, name),
                                      params={"format": "json"})
        return _sweeps.structured(r.json())

    async def runs(self) -> np.ndarray:
        return await self.table("runs")

    async def series(self) -> np.ndarray:
        return await self.table("series")

    async def table_frame(self, name: str = "table") -> pandas.DataFrame:
        return _sweeps.frame(await self.table(name))

    async def csv(self, name: str = "table") -> str:
        r = await self.client.request("GET", _sweeps.table_path(self.id, name),
                                      params={"format": "csv"})
        return r.text
