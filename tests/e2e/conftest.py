"""The end-to-end tests' fixtures: the real server of the service tests (a session one,
and one per test with its own settings)."""

from tests.service.conftest import http, make_server, server

__all__ = ["http", "make_server", "server"]
