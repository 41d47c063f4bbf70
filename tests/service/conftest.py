"""Fixtures for the service tests: the real app with real SQLite stores and real spawned
Taichi workers (no mocks), in this process over `httpx.ASGITransport` (`server`, `http`,
`make_app`: tests/service/inproc.py) or as real `flocklab serve` processes on 127.0.0.1
(`real_server`, `make_server`) for what needs a socket or a process to kill. The shared
in-process `server` is in tests/conftest.py: the client tests use the same one."""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from flocklab.service.serve import ServerProcess
from tests.service.inproc import InProcessServer

MiB = 2**20

# Limits small enough to test against without allocating anything large.
TEST_ENV = {
    "FLOCKLAB_WARMUP_PRESET": "",
    "FLOCKLAB_MAX_AGENTS": "5000",
    "FLOCKLAB_MAX_STEPS": "200000",
    "FLOCKLAB_MAX_TRAJECTORY_BYTES": str(8 * MiB),
    "FLOCKLAB_MAX_BODY_BYTES": str(256 * 1024),
    "FLOCKLAB_MAX_JSON_BYTES": str(256 * 1024),
    "FLOCKLAB_THREADS_PER_WORKER": "1",
}


@pytest.fixture(scope="session")
def real_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """One shared `flocklab serve` on a socket (uvicorn's connection handling, its log)."""
    yield from _serve(tmp_path_factory.mktemp("real") / "data", TEST_ENV)


@pytest.fixture
def make_app(tmp_path: Path) -> Iterator:
    """Start in-process services with extra settings; all are stopped after."""
    started: list[InProcessServer] = []

    def make(env: dict[str, str] | None = None,
             data_dir: Path | None = None) -> InProcessServer:
        s = InProcessServer(data_dir or tmp_path / f"app{len(started)}",
                            {**TEST_ENV, **(env or {})})
        started.append(s)
        return s.start()

    yield make
    for s in started:
        s.stop()


@pytest.fixture
def make_server(tmp_path: Path) -> Iterator:
    """Start servers with extra settings; all are stopped (and orphans reaped) after."""
    started: list[ServerProcess] = []

    def make(env: dict[str, str] | None = None, data_dir: Path | None = None) -> ServerProcess:
        s = ServerProcess(data_dir or tmp_path / f"data{len(started)}",
                          env={**TEST_ENV, **(env or {})})
        started.append(s)
        return s.start()

    yield make
    for s in started:
        _cleanup(s)


def _serve(data_dir: Path, env: dict[str, str]) -> Iterator[ServerProcess]:
    s = ServerProcess(data_dir, env=env).start()
    try:
        yield s
    finally:
        _cleanup(s)


def _cleanup(s: ServerProcess) -> None:
    workers = s.children()
    s.stop()
    for pid in workers:  # only our own server's workers, by pid
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


@pytest.fixture
def http(server: InProcessServer) -> Iterator[httpx.Client]:
    with server.client(timeout=30) as c:
        yield c


@pytest.fixture
def real_http(real_server: ServerProcess) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=real_server.url, timeout=30) as c:
        yield c
