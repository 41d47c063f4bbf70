"""Optional API-key authentication (R19) for every route but /healthz.

With `FLOCKLAB_API_KEY` set, a request must carry it as `Authorization: Bearer <key>` or
`X-API-Key: <key>`; it is compared in constant time. Without it the service is open
(it listens on 127.0.0.1 by default).
"""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer

from .problems import ProblemError

_bearer = HTTPBearer(auto_error=False, description="The service's API key as a bearer token.")
_header = APIKeyHeader(name="X-API-Key", auto_error=False, description="The service's API key.")


def require_api_key(
    request: Request,
    bearer: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
    header: Annotated[str | None, Depends(_header)],
) -> None:
    expected = request.app.state.settings.api_key
    if expected is None:
        return
    given = header if header is not None else (bearer.credentials if bearer else None)
    if given is None or not secrets.compare_digest(
        given.encode(), expected.get_secret_value().encode()
    ):
        raise ProblemError(401, "unauthorized", "Unauthorized",
                           "a valid API key is required (Authorization: Bearer <key> or "
                           "X-API-Key)", headers={"WWW-Authenticate": "Bearer"})
