"""Fixtures for the client tests: a real `flocklab serve` on 127.0.0.1."""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator
from typing import Any

import pytest

from flocklab.service.serve import ServerProcess

ENV = {
    "FLOCKLAB_WARMUP_PRESET": "",
    "FLOCKLAB_MAX_AGENTS": "5000",
    "FLOCKLAB_MAX_STEPS": "200000",
    "FLOCKLAB_THREADS_PER_WORKER": "1",
}


def start(data_dir, env: dict[str, str]) -> Iterator[ServerProcess]:
    s = ServerProcess(data_dir, env={**ENV, **env}).start()
    try:
        yield s
    finally:
        workers = s.children()
        s.stop()
        for pid in workers:  # only this server's own workers, by pid
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    yield from start(tmp_path_factory.mktemp("client") / "data", {})


@pytest.fixture(scope="session")
def strict_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """An API key, one queued job at most, results kept for 1 s."""
    yield from start(tmp_path_factory.mktemp("strict") / "data", {
        "FLOCKLAB_API_KEY": "k3y", "FLOCKLAB_MAX_QUEUED": "1",
        "FLOCKLAB_RESULT_TTL_SECONDS": "1"})


def scenario(n: int = 80, steps: int = 20, every: int = 5) -> dict[str, Any]:
    return {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.3},
        "space": {"kind": "periodic", "L": 4.0},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": n},
        "time": {"steps": steps},
        "recording": {"every": every, "arrays": ["position", "heading"]},
        "seed": 7,
    }


LONG = scenario(n=1000, steps=100_000, every=0)
