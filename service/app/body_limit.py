"""Request body cap (R18): 413 before any parsing. Uvicorn has no limit of its own.

A declared Content-Length over the cap is refused before the body is read; a body sent
without one (chunked) is counted as it streams and refused the moment it passes the cap.
A pure ASGI middleware, so it also guards routes that read the body themselves.
"""

from __future__ import annotations

import json

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from flocklab.service.jobs.problems import problem

from .problems import PROBLEM_MEDIA_TYPE


class _TooLarge(Exception):
    pass


class BodyLimitMiddleware:
    def __init__(self, app: ASGIApp, max_bytes: int):
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None:
            try:
                too_large = int(declared) > self.max_bytes
            except ValueError:
                await self._refuse(scope, send, 400, "Bad Request", "invalid Content-Length")
                return
            if too_large:
                await self._refuse_size(scope, send)
                return
        seen = 0
        started = False

        async def counting_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:
                    raise _TooLarge
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except _TooLarge:
            if not started:
                await self._refuse_size(scope, send)

    async def _refuse_size(self, scope: Scope, send: Send) -> None:
        await self._refuse(scope, send, 413, "Content Too Large",
                           f"the request body exceeds the limit of {self.max_bytes} bytes")

    async def _refuse(self, scope: Scope, send: Send, status: int, title: str, detail: str
                      ) -> None:
        body = problem(title.lower().replace(" ", "-"), title, status, detail,
                       instance=scope.get("path"))
        if status == 413:
            body["max_bytes"] = self.max_bytes
        payload = json.dumps(body).encode()
        await send({"type": "http.response.start", "status": status, "headers": [
            (b"content-type", PROBLEM_MEDIA_TYPE.encode()),
            (b"content-length", str(len(payload)).encode()),
            (b"connection", b"close"),
        ]})
        await send({"type": "http.response.body", "body": payload})
