"""The service in the test process: the real app from `create_app`, its lifespan running
(a real `JobRuntime`: the SQLite store, the supervisor and its spawned Taichi workers),
reached over `httpx.ASGITransport` instead of a socket.

The app lives on an event loop in a thread of its own, as under uvicorn: the lifespan's
`ChangeHub` belongs to that loop, so every request, from a sync client or from an async
one on another loop, is handed to it. What needs a real socket (connection limits, slow
clients, an event stream read while it is open, killing the API process) keeps the real
server of tests/service/conftest.py.
"""

from __future__ import annotations

import asyncio
import os
import threading
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

import httpx

from flocklab.service.app.factory import create_app
from flocklab.service.app.settings import load_settings


def settings_from_env(env: dict[str, str], data_dir: Path) -> Any:
    """The settings a `flocklab serve` child with these FLOCKLAB_* variables added to the
    test process's environment would load (read the same way: JSON lists and all)."""
    saved = _set_environ(env)
    try:
        return load_settings(None, data_dir=data_dir)
    finally:
        _set_environ(saved)


def _set_environ(env: dict[str, str | None]) -> dict[str, str | None]:
    """Set (None: remove) these variables; return what they were."""
    saved = {k: os.environ.get(k) for k in env}
    for k, v in env.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    return saved


class InProcessServer:
    """Stands where a `ServerProcess` does in the route tests: `url`, `data_dir`,
    `children()` (the worker pids), plus `transport` / `async_transport` for clients."""

    url = "http://flocklab.test"

    def __init__(self, data_dir: Path, env: dict[str, str] | None = None):
        self.data_dir = Path(data_dir)
        env = env or {}
        self.settings = settings_from_env(env, self.data_dir)
        # Variables that are no setting (FLOCKLAB_SWEEP_BATCH_RUNS) are read by the workers
        # from their environment: they stay set while this service runs (a spawned worker
        # inherits the test process's), as they would be for a `flocklab serve` child.
        fields = type(self.settings).model_fields
        self._worker_env = {k: v for k, v in env.items()
                            if k.removeprefix("FLOCKLAB_").lower() not in fields}
        self._saved_env: dict[str, str | None] = {}
        self.app = create_app(self.settings)
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True,
                                        name="inproc-app")
        self._asgi = httpx.ASGITransport(app=self.app)
        self.transport = _SyncBridge(self)
        self.async_transport = _AsyncBridge(self)
        self._lifespan: asyncio.Future[None] | None = None
        self._to_app: asyncio.Queue[dict[str, Any]] | None = None

    # -- lifespan (the ASGI protocol, as uvicorn drives it) ------------------------------

    def start(self) -> InProcessServer:
        self._saved_env = _set_environ(self._worker_env)
        self._thread.start()
        self.call(self._startup())
        return self

    def stop(self) -> None:
        """The lifespan's shutdown (what SIGTERM runs under uvicorn); a second stop is a
        no-op."""
        if self._loop.is_closed():
            return
        if self._lifespan is not None:
            self.call(self._shutdown())
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(30)
        self._loop.close()
        _set_environ(self._saved_env)

    async def _startup(self) -> None:
        self._to_app = asyncio.Queue()
        from_app: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        scope = {"type": "lifespan", "asgi": {"version": "3.0"}, "state": {}}
        self._lifespan = asyncio.ensure_future(
            self.app(scope, self._to_app.get, from_app.put))  # type: ignore[arg-type]
        self._from_app = from_app
        await self._to_app.put({"type": "lifespan.startup"})
        msg = await from_app.get()
        if msg["type"] != "lifespan.startup.complete":
            raise RuntimeError(f"app did not start: {msg}")

    async def _shutdown(self) -> None:
        assert self._to_app is not None and self._lifespan is not None
        await self._to_app.put({"type": "lifespan.shutdown"})
        msg = await self._from_app.get()
        await self._lifespan
        if msg["type"] != "lifespan.shutdown.complete":
            raise RuntimeError(f"app did not stop cleanly: {msg}")

    # -- what the tests use --------------------------------------------------------------

    def call(self, coro: Coroutine[Any, Any, Any], timeout: float | None = None) -> Any:
        """Run `coro` on the app's loop and wait for its result."""
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout)

    def client(self, **kw: Any) -> httpx.Client:
        return httpx.Client(base_url=self.url, transport=self.transport, **kw)

    def children(self) -> list[int]:
        return self.app.state.runtime.supervisor.worker_pids()

    async def _handle(self, request: httpx.Request) -> httpx.Response:
        # The whole response is read on the app's loop (ASGITransport gathers the body
        # anyway); the response handed back owns plain bytes.
        response = await self._asgi.handle_async_request(request)
        body = await response.aread()
        return httpx.Response(response.status_code, headers=response.headers, content=body,
                              extensions=response.extensions)


def _buffered(request: httpx.Request, body: bytes) -> httpx.Request:
    """The request with its body read (on the caller's side: it may be a sync generator),
    headers as sent: a chunked body stays chunked for the app."""
    return httpx.Request(request.method, request.url, headers=request.headers,
                         stream=httpx.ByteStream(body), extensions=request.extensions)


class _SyncBridge(httpx.BaseTransport):
    def __init__(self, server: InProcessServer):
        self._server = server

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        return self._server.call(self._server._handle(_buffered(request, request.read())))


class _AsyncBridge(httpx.AsyncBaseTransport):
    def __init__(self, server: InProcessServer):
        self._server = server

    async def handle_async_request(self, request: httpx.Request) -> httpx.Response:
        body = await request.aread()
        fut = asyncio.run_coroutine_threadsafe(
            self._server._handle(_buffered(request, body)), self._server._loop)
        return await asyncio.wrap_future(fut)
