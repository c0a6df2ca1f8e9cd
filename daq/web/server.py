"""The live web page's server: ``python -m daq.web.server``, a child process of ``daq daemon --web``.

Why its own process: like the estimator and the recorder (decision record 5), decimating
and serialising for browsers must not share an interpreter lock with the drivers and the
100 Hz ramp runner. It is a bus subscriber like any other (daq/web/feed.py), serves a
page whose scripts ship in daq/web/static/ (uPlot, no CDN: the page works offline), and
pushes frames over a WebSocket with per-page flow control (the page acknowledges each
frame once painted; at most ``max_unacked`` frames, by default one, are in flight to it).

Commands never bypass the daemon: ``POST /api/command`` becomes a control request that
the daemon's own ``ControlServer.handle`` answers (over this process's stdin/stdout, a
channel only the daemon holds), with the role decided here: without CURVE keys the
server binds to loopback only and every page operates (as every local ``daq ctl`` does);
with CURVE a page is an observer unless it presents the operator token the daemon
printed at start (``Authorization: Bearer TOKEN``; the page takes it from the URL's
``#token=`` fragment, which browsers never send to a server).

Hostile viewers (issue 29, decision record 34): bodies over ``max_body_bytes`` are refused (413) as
they arrive, token-less API requests and WebSocket handshakes are rate-limited per address (429;
daq/web/limits.py), commands need the page's header and its Origin, and operators' pages have
places of their own that viewers cannot fill.

Protocol: stdin line 1 is the :class:`~daq.web.messages.WebCfg`; stdout (a duplicate of
the original fd; anything printed goes to stderr) carries ``{"ready": ..., "url": ...}``
once serving, then :class:`~daq.web.messages.PipeCommand` lines; stdin carries the
daemon's :class:`~daq.web.messages.PipeReply` lines. EOF on stdin (the daemon is gone),
SIGTERM or a change of parent ends it.

Decision record: docs/decisions/0020-live-web-page.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import logging
import os
import secrets
import socket
import sys
import threading
import uuid
from pathlib import Path
from typing import IO, Any
from urllib.parse import urlsplit

import uvicorn
from pydantic import ValidationError
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from daq.background import BackgroundLoop
from daq.daemon.control import DuplicateKey, Reply, is_local_endpoint, loads_strict
from daq.streaming import heap

from .feed import BusFeed, ClientSession
from .limits import BodyLimit, ObserverRateLimit, TokenBuckets
from .messages import Ack, ClientMessage, CommandBody, PipeCommand, PipeReply, Role, View, WebCfg

STATIC = Path(__file__).resolve().parent / "static"
PAGE_HEADER = "x-daq-page"  # a cross-site form cannot set it: commands need it (CSRF)
HTTP_STATUS = {"malformed": 400, "input": 400, "forbidden": 403, "failed": 409, "internal": 500}
COMMAND_TIMEOUT_S = 120.0  # record_start waits for the recorder to see data
WS_PROTOCOL = "daq.v1"  # the page's WebSocket subprotocol; it offers "daq.token.TOKEN" beside it as the operator
WS_TOKEN_PREFIX = "daq.token."  # a browser cannot set Authorization on a WebSocket: the token rides as a subprotocol


def is_loopback_host(host: str) -> bool:
    """True for a host only this machine reaches (127.0.0.0/8, ::1, localhost)."""
    return is_local_endpoint(f"tcp://{host}:0")


def role_for(cfg: WebCfg, authorization: str | None) -> Role:
    """Operator without CURVE (loopback only, like the control socket); with CURVE only with the token."""
    if not cfg.curve:
        return "operator"
    given = (authorization or "").removeprefix("Bearer ").strip()
    return "operator" if cfg.token and given and secrets.compare_digest(given, cfg.token) else "observer"


def _same_origin(origin: str | None, host: str | None) -> bool:
    """A browser's WebSocket from another site's page may not read the rig (no Origin: not a browser)."""
    if origin is None:
        return True
    return bool(host) and urlsplit(origin).netloc.lower() == host.lower()


def _subprotocol_token(offered: str) -> str | None:
    """The operator token among offered subprotocols (``daq.token.TOKEN``), as a Bearer value for role_for."""
    names = [p.strip() for p in offered.split(",")]
    token = next((p.removeprefix(WS_TOKEN_PREFIX) for p in names if p.startswith(WS_TOKEN_PREFIX)), None)
    return f"Bearer {token}" if token else None


def _ws_token(ws: WebSocket) -> str | None:
    """The operator token a page offered as a subprotocol, as a Bearer value for role_for."""
    return _subprotocol_token(ws.headers.get("sec-websocket-protocol", ""))


def _refusal(error: str, code: str, status: int) -> JSONResponse:
    return JSONResponse(Reply(id="", ok=False, error=error, code=code).model_dump(), status_code=status)


def _page_request_refused(request: Request) -> JSONResponse | None:
    """Why a state-changing request is not the page's own (None: it is): the CSRF header, and a browser's
    Origin naming this server. Why both: a token-carrying POST from ``Origin: http://evil.example`` was
    obeyed (issue 29); only a browser sends Origin, and a browser always does on a POST."""
    if request.headers.get(PAGE_HEADER) != "1":
        return _refusal(f"forbidden: missing {PAGE_HEADER} header", "forbidden", 403)
    if not _same_origin(request.headers.get("origin"), request.headers.get("host")):
        return _refusal(f"forbidden: origin {request.headers.get('origin')!r} is not this page's", "forbidden", 403)
    return None


class DaemonLink:
    """Control requests to the daemon over our stdout, replies from our stdin (one JSON line each)."""

    def __init__(self, out: IO[str], inp: IO[str]) -> None:
        self._out = out
        self._in = inp
        self._lock = threading.Lock()
        self._waiting: dict[int, tuple[threading.Event, list[Reply]]] = {}
        self._next = 0
        self.closed = threading.Event()
        threading.Thread(target=self._read, name="daemon-link", daemon=True).start()

    def _read(self) -> None:
        for line in self._in:
            try:
                r = PipeReply.model_validate_json(line)
            except ValidationError:
                continue
            with self._lock:
                slot = self._waiting.pop(r.id, None)
            if slot is not None:
                slot[1].append(r.reply)
                slot[0].set()
        self.closed.set()  # EOF: the daemon is gone

    def send_line(self, line: str) -> None:
        with self._lock:
            self._out.write(line + "\n")
            self._out.flush()

    def call(self, role: Role, op: str, args: dict[str, Any] | None = None,
             timeout: float = COMMAND_TIMEOUT_S) -> Reply:
        """One control request, answered by the daemon's control server; TimeoutError without an answer."""
        request = json.dumps({"op": op, "args": args or {}, "id": uuid.uuid4().hex})
        done, box = threading.Event(), []
        with self._lock:
            self._next += 1
            cid = self._next
            self._waiting[cid] = (done, box)
        self.send_line(PipeCommand(id=cid, role=role, request=request).model_dump_json())
        if not done.wait(timeout) or not box:
            with self._lock:
                self._waiting.pop(cid, None)
            raise TimeoutError(f"the daemon did not answer {op!r} within {timeout:g} s")
        return box[0]


def _poll_status(link: DaemonLink, feed: BusFeed) -> None:
    """The daemon's status for every page (an observer's request: read-only); main() polls it every status_s."""
    try:
        r = link.call("observer", "status", timeout=5.0)
    except (TimeoutError, OSError, ValueError):
        return
    if r.ok:
        st = dict(r.result)
        rec = st.get("recording")
        if rec:
            try:
                st["recording"] = {**rec, "size_bytes": os.stat(rec["path"]).st_size}
            except OSError:
                pass
        feed.set_status(st)


class WebApp:
    """The Starlette application and the state its handlers share."""

    def __init__(self, cfg: WebCfg, feed: BusFeed, link: DaemonLink) -> None:
        self.cfg = cfg
        self.feed = feed
        self.link = link
        self.sessions: set[ClientSession] = set()
        self.operator_sessions: set[ClientSession] = set()
        self.observer_buckets = TokenBuckets(cfg.observer_rate_hz, cfg.observer_burst)
        hosts = ["127.0.0.1", "localhost", "::1", "[::1]", cfg.host] if is_loopback_host(cfg.host) else ["*"]
        self.app = Starlette(
            routes=[Route("/", self.index), Route("/api/whoami", self.whoami), Route("/api/stats", self.stats),
                    Route("/api/latency/reset", self.reset_latency, methods=["POST"]),
                    Route("/api/command", self.command, methods=["POST"]), WebSocketRoute("/ws", self.ws),
                    Mount("/static", StaticFiles(directory=STATIC))],
            middleware=[Middleware(ObserverRateLimit, buckets=self.observer_buckets, limited=self.rate_limited),
                        Middleware(BodyLimit, max_bytes=cfg.max_body_bytes),
                        Middleware(TrustedHostMiddleware, allowed_hosts=hosts)])

    def rate_limited(self, scope: Any) -> bool:
        """Whether a request counts against its address's bucket: an API request or a WebSocket handshake
        without the operator token (the page and its files never count; daq/web/limits.py says why)."""
        path = scope.get("path", "")
        if not (path.startswith("/api/") or path == "/ws"):
            return False
        headers = {k.lower(): v for k, v in scope.get("headers", [])}
        if scope["type"] == "websocket":
            given = _subprotocol_token(headers.get(b"sec-websocket-protocol", b"").decode("latin-1"))
        else:
            given = headers.get(b"authorization", b"").decode("latin-1") or None
        return role_for(self.cfg, given) != "operator"

    async def index(self, request: Request) -> Response:
        return FileResponse(STATIC / "index.html", headers={"cache-control": "no-store"})

    async def whoami(self, request: Request) -> Response:
        return JSONResponse({"role": role_for(self.cfg, request.headers.get("authorization")),
                             "curve": self.cfg.curve, "rig": self.cfg.rig})

    async def stats(self, request: Request) -> Response:
        """Display latency per stream and the feed's own counters (read-only; for `daq bench web`)."""
        with self.feed.lock:  # the bus thread adds streams
            samples = {k: h.samples for k, h in self.feed.streams.items()}
        pages = self.sessions | self.operator_sessions
        return JSONResponse({"latency": self.feed.latency.summary(), "pages": len(pages),
                             "page_list": [{"frames_sent": s.frames_sent, "unacked": len(s.unacked)}
                                           for s in pages],
                             "bus_lost_blocks": self.feed.sub.stats.lost_blocks,
                             "rate_limited": self.observer_buckets.refused,
                             "streams": samples})

    async def reset_latency(self, request: Request) -> Response:
        """Operators only: an observer could reset the display-latency figures (issue 29)."""
        refused = _page_request_refused(request)
        if refused is not None:
            return refused
        if role_for(self.cfg, request.headers.get("authorization")) != "operator":
            return _refusal("forbidden: observers may not reset the latency figures", "forbidden", 403)
        self.feed.latency.clear()
        return JSONResponse({"reset": True})

    async def command(self, request: Request) -> Response:
        """One control request from a page, answered by the daemon's control server with the page's role."""
        refused = _page_request_refused(request)
        if refused is not None:
            return refused
        try:  # the body is at most max_body_bytes here (BodyLimit); a key twice is refused, not "last wins"
            body = CommandBody.model_validate(loads_strict(await request.body()))
        except DuplicateKey as exc:
            return _refusal(f"malformed request: {exc}", "malformed", 400)
        except ValidationError as exc:
            err = exc.errors(include_url=False)[0]
            return _refusal(f"malformed request: {'.'.join(map(str, err['loc']))}: {err['msg']}", "malformed", 400)
        except (ValueError, RecursionError) as exc:  # not JSON, not UTF-8, nested too deep
            return _refusal(f"malformed request: not JSON ({type(exc).__name__})", "malformed", 400)
        role = role_for(self.cfg, request.headers.get("authorization"))
        try:
            reply = await asyncio.to_thread(self.link.call, role, body.op, body.args)
        except TimeoutError as exc:
            return JSONResponse(Reply(id="", ok=False, error=str(exc), code="failed").model_dump(), status_code=504)
        return JSONResponse(reply.model_dump(), status_code=200 if reply.ok else HTTP_STATUS.get(reply.code, 500))

    async def ws(self, ws: WebSocket) -> None:
        """Frames to one page, as fast as it draws them (its acks), never more than max_unacked in flight."""
        if not _same_origin(ws.headers.get("origin"), ws.headers.get("host")):
            await ws.close(code=1008)
            return
        operator = role_for(self.cfg, _ws_token(ws)) == "operator" and self.cfg.curve
        pool = self.operator_sessions if operator else self.sessions
        if len(pool) >= (self.cfg.max_operator_pages if operator else self.cfg.max_clients):
            await ws.close(code=1013)
            return
        await ws.accept(subprotocol=WS_PROTOCOL if WS_PROTOCOL in ws.scope.get("subprotocols", []) else None)
        session = ClientSession(self.feed, self.cfg.max_unacked)
        pool.add(session)
        wake = asyncio.Event()
        receiver = asyncio.create_task(self._receive(ws, session, wake))
        loop = asyncio.get_running_loop()
        last = 0.0
        try:
            while not receiver.done():
                wake.clear()
                if not session.can_send:
                    with contextlib.suppress(asyncio.TimeoutError):
                        await asyncio.wait_for(wake.wait(), 0.5)
                    continue
                wait = self.cfg.frame_s - (loop.time() - last)
                if wait > 0:
                    await asyncio.sleep(wait)
                frame = session.frame()
                if frame is None:
                    continue
                last = loop.time()
                await ws.send_text(frame.model_dump_json())
        except (WebSocketDisconnect, RuntimeError, OSError):
            pass
        finally:
            receiver.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await receiver  # its end (a disconnect, a bad frame) is retrieved here, never logged as a traceback
            pool.discard(session)

    async def _receive(self, ws: WebSocket, session: ClientSession, wake: asyncio.Event) -> None:
        """The page's views and acks; ends (and with it the page's socket) on a disconnect or a frame that is not
        UTF-8 text (uvicorn hands that on as a KeyError: its traceback reached the operator's log, issue 29)."""
        while True:
            try:
                text = await ws.receive_text()
            except (WebSocketDisconnect, KeyError, RuntimeError, UnicodeDecodeError):
                with contextlib.suppress(RuntimeError, OSError):
                    await ws.close(code=1007)
                return
            try:
                msg = ClientMessage.model_validate({"msg": json.loads(text)}).msg
            except (ValueError, ValidationError):
                continue  # a page bug must not end the others' frames; ignore it
            if isinstance(msg, View):
                session.set_view(msg)
            elif isinstance(msg, Ack):
                session.ack(msg.seq)
            wake.set()


class OneLineErrors(logging.Filter):
    """uvicorn's log records as one line each: the exception's type and message instead of its traceback.

    Why: the web process's stderr is the daemon's, which is the operator's log; invalid UTF-8 in a
    WebSocket text frame printed uvicorn's 8-line traceback there (issue 29), although uvicorn itself
    answers it correctly (it closes that socket with 1007). A traceback is for a developer: the type and
    message still name the fault.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info and record.exc_info[1] is not None:
            exc = record.exc_info[1]
            record.msg = f"{record.getMessage()} ({type(exc).__name__}: {' '.join(str(exc).split())})"
            record.args = None
            record.exc_info = record.exc_text = None
        return True


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    sock.listen(64)
    sock.set_inheritable(True)
    return sock


def url_of(host: str, port: int) -> str:
    try:
        bracket = isinstance(ipaddress.ip_address(host), ipaddress.IPv6Address)
    except ValueError:
        bracket = False
    return f"http://{'[' + host + ']' if bracket else host}:{port}/"


def main() -> int:
    """Read the configuration from stdin, subscribe, serve until SIGTERM, stdin EOF or the parent's death."""
    channel = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # whatever prints (uvicorn, a library) goes to stderr, never into the command channel
    cfg = WebCfg.model_validate_json(sys.stdin.readline())
    if not is_loopback_host(cfg.host) and not (cfg.curve and cfg.token):
        print("web: refusing a non-loopback address without CURVE keys and an operator token", file=sys.stderr)
        return 2
    feed = BusFeed([cfg.bus, *cfg.also], cfg.rcvhwm).start()
    link = DaemonLink(channel, sys.stdin)
    web = WebApp(cfg, feed, link)
    sock = _bind(cfg.host, cfg.port)
    port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(web.app, log_level="warning", access_log=False, lifespan="off",
                                           ws_max_size=1 << 16, timeout_graceful_shutdown=2))
    for name in ("uvicorn.error", "uvicorn.asgi", "uvicorn"):  # configured by uvicorn.Config just above
        logging.getLogger(name).addFilter(OneLineErrors())
    stop = threading.Event()
    BackgroundLoop(lambda: _poll_status(link, feed), "status", interval=cfg.status_s, stop=stop).start()
    heap.start(stop)  # resident memory: what the process holds, not the high-water mark of its heap

    def watch() -> None:  # until the finally below: asking uvicorn to exit again is a no-op
        if link.closed.is_set() or (cfg.parent_pid and os.getppid() != cfg.parent_pid):
            server.should_exit = True
    BackgroundLoop(watch, "parent-watch", interval=0.25, stop=stop).start()
    link.send_line(json.dumps({"ready": True, "pid": os.getpid(), "url": url_of(cfg.host, port)}))
    try:
        server.run(sockets=[sock])
    finally:
        stop.set()
        feed.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
