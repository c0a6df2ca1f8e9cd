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

from daq.daemon.control import Reply, is_local_endpoint

from .feed import BusFeed, ClientSession
from .messages import Ack, ClientMessage, CommandBody, PipeCommand, PipeReply, Role, View, WebCfg

STATIC = Path(__file__).resolve().parent / "static"
PAGE_HEADER = "x-daq-page"  # a cross-site form cannot set it: commands need it (CSRF)
HTTP_STATUS = {"malformed": 400, "input": 400, "forbidden": 403, "failed": 409, "internal": 500}
COMMAND_TIMEOUT_S = 120.0  # record_start waits for the recorder to see data


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


def _status_loop(link: DaemonLink, feed: BusFeed, period: float, stop: threading.Event) -> None:
    """The daemon's status for every page, every ``period`` s (an observer's request: read-only)."""
    while not stop.wait(period):
        try:
            r = link.call("observer", "status", timeout=5.0)
        except (TimeoutError, OSError, ValueError):
            continue
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
        hosts = ["127.0.0.1", "localhost", "::1", "[::1]", cfg.host] if is_loopback_host(cfg.host) else ["*"]
        self.app = Starlette(
            routes=[Route("/", self.index), Route("/api/whoami", self.whoami), Route("/api/stats", self.stats),
                    Route("/api/latency/reset", self.reset_latency, methods=["POST"]),
                    Route("/api/command", self.command, methods=["POST"]), WebSocketRoute("/ws", self.ws),
                    Mount("/static", StaticFiles(directory=STATIC))],
            middleware=[Middleware(TrustedHostMiddleware, allowed_hosts=hosts)])

    async def index(self, request: Request) -> Response:
        return FileResponse(STATIC / "index.html", headers={"cache-control": "no-store"})

    async def whoami(self, request: Request) -> Response:
        return JSONResponse({"role": role_for(self.cfg, request.headers.get("authorization")),
                             "curve": self.cfg.curve, "rig": self.cfg.rig})

    async def stats(self, request: Request) -> Response:
        """Display latency per stream and the feed's own counters (read-only; for `daq bench web`)."""
        with self.feed.lock:  # the bus thread adds streams
            samples = {k: h.samples for k, h in self.feed.streams.items()}
        return JSONResponse({"latency": self.feed.latency.summary(), "pages": len(self.sessions),
                             "page_list": [{"frames_sent": s.frames_sent, "unacked": len(s.unacked)}
                                           for s in self.sessions],
                             "bus_lost_blocks": self.feed.sub.stats.lost_blocks,
                             "streams": samples})

    async def reset_latency(self, request: Request) -> Response:
        if request.headers.get(PAGE_HEADER) != "1":
            return JSONResponse({"error": f"missing {PAGE_HEADER} header"}, status_code=403)
        self.feed.latency.clear()
        return JSONResponse({"reset": True})

    async def command(self, request: Request) -> Response:
        """One control request from a page, answered by the daemon's control server with the page's role."""
        if request.headers.get(PAGE_HEADER) != "1":
            return JSONResponse(Reply(id="", ok=False, error=f"forbidden: missing {PAGE_HEADER} header",
                                      code="forbidden").model_dump(), status_code=403)
        try:
            body = CommandBody.model_validate_json(await request.body())
        except ValidationError as exc:
            err = exc.errors(include_url=False)[0]
            msg = f"malformed request: {'.'.join(map(str, err['loc']))}: {err['msg']}"
            return JSONResponse(Reply(id="", ok=False, error=msg, code="malformed").model_dump(), status_code=400)
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
        if len(self.sessions) >= self.cfg.max_clients:
            await ws.close(code=1013)
            return
        await ws.accept()
        session = ClientSession(self.feed, self.cfg.max_unacked)
        self.sessions.add(session)
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
            self.sessions.discard(session)

    async def _receive(self, ws: WebSocket, session: ClientSession, wake: asyncio.Event) -> None:
        while True:
            text = await ws.receive_text()
            try:
                msg = ClientMessage.model_validate({"msg": json.loads(text)}).msg
            except (ValueError, ValidationError):
                continue  # a page bug must not end the others' frames; ignore it
            if isinstance(msg, View):
                session.set_view(msg)
            elif isinstance(msg, Ack):
                session.ack(msg.seq)
            wake.set()


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
    stop = threading.Event()
    threading.Thread(target=_status_loop, args=(link, feed, cfg.status_s, stop), name="status", daemon=True).start()

    def watch() -> None:
        while not stop.wait(0.25):
            if link.closed.is_set() or (cfg.parent_pid and os.getppid() != cfg.parent_pid):
                server.should_exit = True
                return
    threading.Thread(target=watch, name="parent-watch", daemon=True).start()
    link.send_line(json.dumps({"ready": True, "pid": os.getpid(), "url": url_of(cfg.host, port)}))
    try:
        server.run(sockets=[sock])
    finally:
        stop.set()
        feed.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
