"""Fixtures for the client tests: the real service in this process (the real app, store
and workers: tests/service/inproc.py), reached through the client's `transport=` seam.
`server` is the session's shared one (tests/conftest.py, the service tests' too);
`strict_server` has settings of its own."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from tests.service.inproc import InProcessServer

ENV = {
    "FLOCKLAB_WARMUP_PRESET": "",
    "FLOCKLAB_MAX_AGENTS": "5000",
    "FLOCKLAB_MAX_STEPS": "200000",
    "FLOCKLAB_THREADS_PER_WORKER": "1",
}


def start(data_dir, env: dict[str, str]) -> Iterator[InProcessServer]:
    s = InProcessServer(data_dir, {**ENV, **env}).start()
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture(scope="session")
def strict_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[InProcessServer]:
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
