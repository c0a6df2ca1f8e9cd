"""Limits enforced where the bytes arrive: ASGI middlewares in front of every route.

:class:`BodyLimit` caps every request body; :class:`ObserverRateLimit` caps how often a client without
the operator token may ask for more than a file (below).

Why here and not in a handler: a token-less ``POST /api/command`` with a 300 MB body was read whole,
forwarded to the daemon and parsed there before its 1 MiB limit (8.8 s, 1.38 GB, motor samples gapped
0.46 s, the regulator's watchdog stopped the belt; issue 29). uvicorn has no body limit of its own, so
this middleware refuses a declared ``Content-Length`` above the limit before reading a byte, and counts
a chunked body as it streams in, answering 413 as soon as it passes the limit. Nothing above the limit
is ever buffered, parsed or forwarded.

Why a rate limit for observers: every ``POST /api/command`` an observer sends reaches the daemon's
control handler (a ``status`` is answered, anything else refused there), so a flood of small,
well-formed requests would take the daemon's interpreter from its drivers as surely as one big
body did. Token-less requests to ``/api/`` and WebSocket handshakes on ``/ws`` take a token from a
bucket per client address (:class:`TokenBuckets`); an empty bucket is answered 429 with
``Retry-After``, never forwarded. The operator (the token, as a Bearer header or a ``daq.token.``
WebSocket subprotocol) is never limited, and neither are the page and its static files: a browser
cannot add the token to the page's own loads, and behind a proxy or an SSH tunnel every client has
the same address, so limiting those would let viewers keep the operator from loading the page.
"""

from __future__ import annotations

import json
import math
import threading
import time
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


class TokenBuckets:
    """One token bucket per key (a client address): ``burst`` tokens, refilled at ``rate_hz``.

    Memory is bounded: past ``max_keys`` addresses, those whose bucket has refilled are forgotten (a
    full bucket is the same as none), and if all are still in use, new addresses share one bucket.
    """

    SHARED = "(other addresses)"

    def __init__(self, rate_hz: float, burst: int, max_keys: int = 4096,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.rate_hz = rate_hz
        self.burst = burst
        self.max_keys = max_keys
        self.clock = clock
        self.refused = 0  # requests answered 429 since start (for /api/stats)
        self._buckets: dict[str, tuple[float, float]] = {}  # key -> (tokens, when counted)
        self._lock = threading.Lock()

    def take(self, key: str) -> float:
        """0.0 if ``key`` may go on (a token taken); else the seconds until its next token."""
        now = self.clock()
        with self._lock:
            if key not in self._buckets and len(self._buckets) >= self.max_keys:
                self._forget_full(now)
                if len(self._buckets) >= self.max_keys:
                    key = self.SHARED
            tokens, then = self._buckets.get(key, (float(self.burst), now))
            tokens = min(float(self.burst), tokens + (now - then) * self.rate_hz)
            if tokens >= 1.0:
                self._buckets[key] = (tokens - 1.0, now)
                return 0.0
            self._buckets[key] = (tokens, now)
            self.refused += 1
            return (1.0 - tokens) / self.rate_hz

    def _forget_full(self, now: float) -> None:
        full = [k for k, (tokens, then) in self._buckets.items()
                if tokens + (now - then) * self.rate_hz >= self.burst]
        for k in full:
            del self._buckets[k]


class ObserverRateLimit:
    """Pure ASGI middleware: 429 for a request ``limited(scope)`` says counts, once its address's bucket is empty.

    HTTP gets a JSON reply (the control reply's shape, code ``forbidden``) with ``Retry-After``. A
    WebSocket handshake is closed before it is accepted (uvicorn answers 403), not given a 429 as an
    HTTP denial: uvicorn 0.38's default WebSocket implementation logs "ASGI callable returned without
    completing handshake." for every denial response, so a flood of refused handshakes would flood
    the operator's log, which is what this is for.
    """

    def __init__(self, app: ASGIApp, buckets: TokenBuckets, limited: Callable[[Scope], bool]) -> None:
        self.app = app
        self.buckets = buckets
        self.limited = limited

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket") or not self.limited(scope):
            await self.app(scope, receive, send)
            return
        client = scope.get("client")
        wait = self.buckets.take(client[0] if client else "?")
        if wait <= 0.0:
            await self.app(scope, receive, send)
            return
        retry = str(max(1, math.ceil(wait)))
        body = json.dumps({"id": "", "ok": False, "code": "forbidden", "result": {},
                           "error": f"too many requests without the operator token from this address (at most "
                                    f"{self.buckets.burst} at once, then {self.buckets.rate_hz:g} per s); "
                                    f"retry in {retry} s"}).encode()
        headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                   (b"retry-after", retry.encode())]
        if scope["type"] == "http":
            await send({"type": "http.response.start", "status": 429, "headers": [*headers, (b"connection", b"close")]})
            await send({"type": "http.response.body", "body": body})
            return
        await receive()  # websocket.connect
        await send({"type": "websocket.close", "code": 1013})
