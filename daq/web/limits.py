"""Request-body limits enforced where the bytes arrive: an ASGI middleware in front of every route.

Why here and not in a handler: a token-less ``POST /api/command`` with a 300 MB body was read whole,
forwarded to the daemon and parsed there before its 1 MiB limit (8.8 s, 1.38 GB, motor samples gapped
0.46 s, the regulator's watchdog stopped the belt; issue 29). uvicorn has no body limit of its own, so
this middleware refuses a declared ``Content-Length`` above the limit before reading a byte, and counts
a chunked body as it streams in, answering 413 as soon as it passes the limit. Nothing above the limit
is ever buffered, parsed or forwarded.
"""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


class _TooLarge(Exception):
    """Raised from ``receive`` once a streaming body passes the limit."""


class BodyLimit:
    """Pure ASGI middleware: 413 for an HTTP request body larger than ``max_bytes`` (declared or streamed)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = _content_length(scope)
        if declared is not None and declared > self.max_bytes:
            await self._refuse(send, f"{declared} bytes declared")
            return
        seen = 0
        started = False

        async def counted() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:
                    raise _TooLarge
            return message

        async def watched(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted, watched)
        except _TooLarge:
            if not started:
                await self._refuse(send, f"more than {self.max_bytes} bytes sent")

    async def _refuse(self, send: Send, what: str) -> None:
        body = json.dumps({"id": "", "ok": False, "code": "malformed", "result": {},
                           "error": f"malformed request: body: {what}; the limit is {self.max_bytes} bytes"}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})


def _content_length(scope: Scope) -> int | None:
    """The declared body length; None if absent (chunked) or not a number (then counted as it streams)."""
    for name, value in scope.get("headers", []):
        if name == b"content-length":
            try:
                return int(value)
            except ValueError:
                return None
    return None
