"""The asynchronous twin of `clients.sync`: `AsyncClient` and its handles (`AsyncJob`,
`AsyncSweepJob`: both an `AsyncHandle`)."""

from __future__ import annotations

import hashlib
from collections.abc import AsyncIterator, Sequence
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

H = TypeVar("H", bound="AsyncHandle")


class AsyncClient(_core.ClientBase):
    """Like `Client`, with every network call awaited.

    >>> async with AsyncClient() as c:
    ...     job = await (await c.submit(preset="vicsek-1995")).wait()
    """

    httpx_class = httpx.AsyncClient
    http: httpx.AsyncClient

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
        body = _core.job_body(scenario, preset, overrides, timeout_seconds)
        return await self._submit(AsyncJob, body, idempotency_key)

    async def job(self, job_id: str) -> AsyncJob:
        return AsyncJob(self, (await self.request("GET", f"{AsyncJob.route}/{job_id}")).json())

    def jobs(self, status: str | Sequence[str] | None = None, model: str | None = None,
             page_size: int = 100, limit: int | None = None) -> AsyncIterator[AsyncJob]:
        return self._list(AsyncJob, status, page_size, limit, model=model)

    async def sweep(self, spec: Sweep | dict[str, Any] | None = None, *,
                    sweep_preset: str | None = None, timeout_seconds: float | None = None,
                    idempotency_key: str | None = None) -> AsyncSweepJob:
        body = _core.sweep_body(spec, sweep_preset, timeout_seconds)
        return await self._submit(AsyncSweepJob, body, idempotency_key)

    async def get_sweep(self, sweep_id: str) -> AsyncSweepJob:
        r = await self.request("GET", f"{AsyncSweepJob.route}/{sweep_id}")
        return AsyncSweepJob(self, r.json())

    def sweeps(self, status: str | Sequence[str] | None = None, page_size: int = 100
               ) -> AsyncIterator[AsyncSweepJob]:
        return self._list(AsyncSweepJob, status, page_size, None)

    async def _submit(self, cls: type[H], body: dict[str, Any], idempotency_key: str | None
                      ) -> H:
        hdrs = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
        return cls(self, (await self.request("POST", cls.route, json=body, headers=hdrs)).json())

    async def _list(self, cls: type[H], status: str | Sequence[str] | None, page_size: int,
                    limit: int | None, **params: Any) -> AsyncIterator[H]:
        pager = _core.Pager(_core.list_params(status, page_size, limit, **params), limit)
        while pager.query is not None:
            page = (await self.request("GET", cls.route, params=pager.query)).json()
            for item in pager.take(page):
                yield cls(self, item)

    async def models(self) -> list[dict[str, Any]]:
        return (await self.request("GET", "/v1/models")).json()

    async def model_schema(self, kind: str) -> dict[str, Any]:
        return (await self.request("GET", f"/v1/models/{kind}")).json()

    async def presets(self) -> list[dict[str, Any]]:
        return (await self.request("GET", "/v1/presets")).json()

    async def health(self) -> dict[str, Any]:
        return (await self.request("GET", "/healthz")).json()


class AsyncHandle(_core.HandleFields):
    """The asynchronous twin of `clients.sync.Handle`."""

    def __init__(self, client: AsyncClient, data: dict[str, Any]):
        self.client = client
        self.data = data

    async def _get(self, wait: float = 0.0, until: str = "finished") -> None:
        r = await self.client.request("GET", self.path(),
                                      params=_core.wait_params(wait, until),
                                      timeout=self.client.timeout + wait)
        self.data = r.json()

    async def _wait(self, timeout: float | None, progress: bool | None) -> None:
        with _core.Waiter(self, timeout, progress) as waiter:
            for seconds in waiter:
                await self._get(seconds, waiter.until)

    async def _cancel(self) -> None:
        self.data = (await self.client.request("POST", self.path("/cancel"))).json()


class AsyncJob(_core.JobFields, AsyncHandle):
    async def refresh(self, wait: float = 0.0, until: str = "finished") -> AsyncJob:
        await self._get(wait, until)
        return self

    async def wait(self, timeout: float | None = None, progress: bool | None = None
                   ) -> AsyncJob:
        await self._wait(timeout, progress)
        return self

    async def events(self) -> AsyncIterator[dict[str, Any]]:
        """The asynchronous twin of `Job.events()`."""
        follower = _core.Follower(self)
        async with self.client.http.stream("GET", self.path("/events"),
                                           headers={"Accept": "text/event-stream"}) as r:
            if r.status_code >= 400:
                await r.aread()
                raise_for_status(r)
            async for line in r.aiter_lines():
                for data in follower.feed(line):
                    yield data
                if follower.ended:
                    return

    async def cancel(self) -> AsyncJob:
        await self._cancel()
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


class AsyncSweepJob(_core.SweepFields, AsyncHandle):
    """The asynchronous twin of `clients.sync.SweepJob`."""

    async def status(self, wait: float = 0.0, until: str = "finished") -> SweepStatus:
        await self._get(wait, until)
        return self.state

    async def wait(self, timeout: float | None = None, progress: bool | None = None
                   ) -> np.ndarray:
        await self._wait(timeout, progress)
        if self.state.status != "succeeded":
            raise SweepFailed(self.state)
        return await self.table()

    async def spec(self) -> Sweep:
        r = await self.client.request("GET", f"/v1/sweeps/{self.id}/spec")
        return Sweep.model_validate_json(r.content)

    async def cancel(self) -> SweepStatus:
        await self._cancel()
        return self.state

    async def table(self, name: str = "table") -> np.ndarray:
        r = await self.client.request("GET", _tables.table_path(self.id, name),
                                      params={"format": "json"})
        return _tables.structured(r.json())

    async def runs(self) -> np.ndarray:
        return await self.table("runs")

    async def series(self) -> np.ndarray:
        return await self.table("series")

    async def table_frame(self, name: str = "table") -> pandas.DataFrame:
        return _tables.frame(await self.table(name))

    async def csv(self, name: str = "table") -> str:
        r = await self.client.request("GET", _tables.table_path(self.id, name),
                                      params={"format": "csv"})
        return r.text
