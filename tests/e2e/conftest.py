"""The end-to-end tests' fixtures: real `flocklab serve` processes on a socket (a session
one, and one per test with its own settings), which a browser or a fuzzer can reach."""

from collections.abc import Iterator

import httpx
import pytest

from flocklab.service.serve import ServerProcess
from tests.service.conftest import make_server, real_server

__all__ = ["http", "make_server", "real_server", "server"]


@pytest.fixture(scope="session")
def server(real_server: ServerProcess) -> ServerProcess:
    return real_server


@pytest.fixture
def http(real_server: ServerProcess) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=real_server.url, timeout=30) as c:
        yield c
