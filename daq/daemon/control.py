"""The daemon's control channel: JSON requests over ZeroMQ, loopback by default, CURVE for remote.

Why this shape: the operator daemon drives a motor, so whoever can reach the control
socket can move hardware. The socket therefore binds to loopback unless CURVE keys are
configured, and with CURVE every client is identified by its public key: keys in
``operators_dir`` may command, keys in ``observers_dir`` may only read status, any other
key fails the handshake and never reaches a handler. The role is taken from the
``User-Id`` property of each received frame, which libzmq fills in from the ZAP reply
(pyzmq's authenticator answers with the client's Z85 public key), so it cannot be forged
from the message body.

Messages are one JSON object per frame (``Request`` in, ``Reply`` out). A malformed
request gets an error reply naming the bad field; neither it nor a handler exception
stops the server.

Decision record: docs/decisions/0014-safety-in-the-regulator.md.
"""

from __future__ import annotations

import ipaddress
import json
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import zmq
import zmq.auth
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from zmq.auth.thread import ThreadAuthenticator

from daq.errors import InputError

Op = Literal["status", "ramp", "stop", "estop", "record_start", "record_stop", "note"]
READ_ONLY_OPS: frozenset[str] = frozenset({"status"})
FORBIDDEN = "forbidden: observers may only read status"
MAX_MSG_BYTES = 1 << 20  # a control request is small; refuse anything that could exhaust memory
POLL_MS = 100  # how often the server thread checks for stop()

Handler = Callable[[dict], dict]


class _Args(BaseModel):
    """Base for per-op arguments: strict types, no unknown keys (a typo must not be ignored)."""

    model_config = ConfigDict(extra="forbid", strict=True)


class NoArgs(_Args):
    """Ops that take no arguments."""


class RampArgs(_Args):
    file: str = Field(min_length=1, description="ramp definition file to run")
    time_scale: float = Field(1.0, gt=0, le=1, description="slow a ramp down, never speed it up")


class NoteArgs(_Args):
    text: str = Field(description="free text for the run log")

    @field_validator("text")
    @classmethod
    def _not_blank(cls, v: str) -> str:
        """A blank note is almost certainly a client bug."""
        if not v.strip():
            raise ValueError("must not be empty")
        return v


class RecordStartArgs(_Args):
    path: str | None = Field(None, min_length=1, description="output file; the recorder picks one if absent")


ARGS_MODELS: dict[str, type[_Args]] = {
    "status": NoArgs, "ramp": RampArgs, "stop": NoArgs, "estop": NoArgs,
    "record_start": RecordStartArgs, "record_stop": NoArgs, "note": NoteArgs,
}


class Request(BaseModel):
    """One control request; ``args`` is validated against the op's own model and normalised."""

    model_config = ConfigDict(extra="forbid")
    op: Op
    args: dict[str, Any] = Field(default_factory=dict)
    id: str

    @model_validator(mode="after")
    def _check_args(self) -> Request:
        """Validate args per op so handlers receive only well-typed, known keys."""
        try:
            parsed = ARGS_MODELS[self.op].model_validate(self.args)
        except ValidationError as exc:
            raise ValueError(_describe(exc, prefix="args")) from None
        self.args = parsed.model_dump(exclude_none=True)
        return self


class Reply(BaseModel):
    """One control reply; ``error`` is set exactly when ``ok`` is False."""

    model_config = ConfigDict(extra="forbid")
    id: str
    ok: bool
    result: dict[str, Any] = Field(default_factory=dict)
    error: str | None = None
    code: Literal["malformed", "forbidden", "input", "failed", "internal"] | None = Field(
        None, description="kind of error: 'malformed'/'input' are the client's to fix (bad request, bad file)")


class ControlCfg(BaseModel):
    """Where the control socket binds and, optionally, the CURVE keys that allow remote use."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    endpoint: str = Field("tcp://127.0.0.1:5570", description="where the server binds; loopback unless CURVE")
    server_secret_file: Path | None = Field(None, description="server key pair (*.key_secret); enables CURVE")
    operators_dir: Path | None = Field(None, description="public keys (*.key) of clients allowed to command")
    observers_dir: Path | None = Field(None, description="public keys (*.key) of clients allowed to read status")

    @model_validator(mode="after")
    def _curve_complete(self) -> ControlCfg:
        """Half a CURVE configuration is a mistake, not a request for an open socket."""
        dirs = self.operators_dir is not None or self.observers_dir is not None
        if dirs and self.server_secret_file is None:
            raise ValueError("operators_dir/observers_dir need server_secret_file (CURVE)")
        if self.server_secret_file is not None and not dirs:
            raise ValueError("server_secret_file needs operators_dir and/or observers_dir, else nobody may connect")
        return self

    @property
    def curve(self) -> bool:
        return self.server_secret_file is not None


def _describe(exc: ValidationError, prefix: str = "") -> str:
    """Turn a pydantic error into 'field: problem' lines a client can act on."""
    parts = []
    for err in exc.errors(include_url=False):
        loc = ".".join(str(p) for p in ((prefix,) if prefix else ()) + tuple(err["loc"]))
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{loc}: {msg}" if loc else msg)
    return "; ".join(parts)


def is_local_endpoint(endpoint: str) -> bool:
    """True if only this host can reach the endpoint (tcp loopback, ipc, inproc)."""
    transport, sep, rest = endpoint.partition("://")
    if not sep:
        return False
    if transport in ("ipc", "inproc"):
        return True
    if transport != "tcp":
        return False
    host = rest.rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # '*', an interface name or a host name: possibly reachable from outside
        return False


def check_endpoint_security(cfg: ControlCfg) -> None:
    """Refuse to expose motor control to the network without authentication."""
    if not cfg.curve and not is_local_endpoint(cfg.endpoint):
        raise ValueError(f"refusing to bind control socket to non-loopback {cfg.endpoint!r} without CURVE: "
                         "set server_secret_file and operators_dir/observers_dir, or bind to 127.0.0.1")


def generate_keys(directory: str | Path, name: str) -> tuple[Path, Path]:
    """Create a CURVE key pair; the public file goes to peers, the secret file stays here."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    public, secret = zmq.auth.create_certificates(str(directory), name)
    return Path(public), Path(secret)


def _load_keys(directory: Path | None) -> set[bytes]:
    """Z85 public keys of every *.key file in a directory (none if not configured)."""
    return set(zmq.auth.load_certificates(str(directory))) if directory is not None else set()


class ControlServer:
    """Serves control requests from a ROUTER socket on its own thread; handlers run on that thread."""

    def __init__(self, handlers: dict[str, Handler], cfg: ControlCfg = ControlCfg()) -> None:
        self.handlers = dict(handlers)
        self.cfg = cfg
        self.endpoint: str | None = None
        self.requests = 0
        self.errors = 0
        self._operators: set[bytes] = set()
        self._observers: set[bytes] = set()
        self._ctx: zmq.Context | None = None
        self._auth: ThreadAuthenticator | None = None
        self._sock: zmq.Socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> ControlServer:
        """Check the security policy, bind, and serve; errors surface here, not in the thread."""
        if self._thread is not None:
            raise RuntimeError("control server already started")
        check_endpoint_security(self.cfg)
        self._ctx = zmq.Context()  # own context: the ZAP handler must not affect other sockets
        try:
            sock = self._ctx.socket(zmq.ROUTER)
            sock.setsockopt(zmq.LINGER, 200)
            sock.setsockopt(zmq.MAXMSGSIZE, MAX_MSG_BYTES)
            if self.cfg.curve:
                self._operators = _load_keys(self.cfg.operators_dir)
                self._observers = _load_keys(self.cfg.observers_dir)
                public, secret = zmq.auth.load_certificate(str(self.cfg.server_secret_file))
                if not secret:
                    raise ValueError(f"{self.cfg.server_secret_file} holds no secret key")
                # the authenticator must run before bind: libzmq lets CURVE clients in if no ZAP handler answers
                self._auth = ThreadAuthenticator(self._ctx)
                self._auth.start()
                self._auth.configure_curve_callback("*", credentials_provider=self)
                sock.curve_secretkey = secret
                sock.curve_publickey = public
                sock.curve_server = True
            self._sock = sock
            sock.bind(self.cfg.endpoint)
            self.endpoint = sock.getsockopt_string(zmq.LAST_ENDPOINT)
        except Exception:
            self._teardown()
            raise
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name="control-server", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop serving and release the port."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
        self._teardown()

    def _teardown(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        if self._auth is not None:  # after the socket: no handshake may run without the handler
            self._auth.stop()
            self._auth = None
        if self._ctx is not None:
            self._ctx.term()
            self._ctx = None

    def __enter__(self) -> ControlServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- authentication ----------------------------------------------------------------------
    def callback(self, domain: str, key: bytes) -> bool:
        """ZAP credentials provider: let in the union of operator and observer keys."""
        return key in self._operators or key in self._observers

    def role_of(self, user_id: str | None) -> Literal["operator", "observer"] | None:
        """Role for a client; without CURVE only local clients can connect, and they all operate."""
        if not self.cfg.curve:
            return "operator"
        key = (user_id or "").encode()
        if key in self._operators:
            return "operator"
        if key in self._observers:
            return "observer"
        return None  # passed the handshake but no longer listed: treat as nobody

    # -- serving -------------------------------------------------------------------------------
    def _serve(self) -> None:
        sock = self._sock
        assert sock is not None
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        while not self._stop.is_set():
            try:
                if not poller.poll(POLL_MS):
                    continue
                frames = sock.recv_multipart(copy=False)
            except zmq.ZMQError:
                if self._stop.is_set():
                    break
                continue
            if len(frames) < 2:
                continue
            envelope, payload = [f.bytes for f in frames[:-1]], frames[-1]
            try:
                user_id = payload.get("User-Id") if self.cfg.curve else None
            except zmq.ZMQError:
                user_id = None
            reply = self.handle(payload.bytes, self.role_of(user_id))
            try:
                sock.send_multipart(envelope + [reply.model_dump_json().encode()])
            except zmq.ZMQError:
                pass  # the client went away; nothing to tell it

    def handle(self, raw: bytes, role: Literal["operator", "observer"] | None) -> Reply:
        """Turn one raw request into a reply; never raises."""
        self.requests += 1
        rid = ""
        try:
            try:
                data = json.loads(raw)
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                return self._fail(rid, f"malformed request: not JSON ({exc})", "malformed")
            if not isinstance(data, dict):
                return self._fail(rid, "malformed request: expected a JSON object", "malformed")
            if isinstance(data.get("id"), str):
                rid = data["id"]
            try:
                req = Request.model_validate(data)
            except ValidationError as exc:
                return self._fail(rid, f"malformed request: {_describe(exc)}", "malformed")
            if role is None:
                return self._fail(rid, "forbidden: unknown client key", "forbidden")
            if role != "operator" and req.op not in READ_ONLY_OPS:
                return self._fail(rid, FORBIDDEN, "forbidden")
            handler = self.handlers.get(req.op)
            if handler is None:
                return self._fail(rid, f"op {req.op!r} is not available in this daemon", "failed")
            try:
                result = handler(req.args)
            except InputError as exc:  # a bad ramp file, a bad path: one line naming file and field
                return self._fail(rid, str(exc), "input")
            except Exception as exc:  # a failing command must not take the control channel down
                return self._fail(rid, f"{req.op} failed: {type(exc).__name__}: {exc}", "failed")
            reply = Reply(id=rid, ok=True, result=result or {})
            json.dumps(reply.result)  # fail here, with a reply, rather than at send time
            return reply
        except Exception as exc:  # e.g. a handler returned something that is not a JSON dict
            return self._fail(rid, f"internal error: {type(exc).__name__}: {exc}", "internal")

    def _fail(self, rid: str, error: str, code: str = "failed") -> Reply:
        self.errors += 1
        return Reply(id=rid, ok=False, error=error, code=code)


class ControlClient:
    """Sends requests to a ControlServer; a DEALER socket, so a timed-out request never wedges it."""

    def __init__(self, endpoint: str, client_secret_file: str | Path | None = None,
                 server_public_file: str | Path | None = None, timeout_s: float = 2.0,
                 ctx: zmq.Context | None = None) -> None:
        if (client_secret_file is None) != (server_public_file is None):
            raise ValueError("CURVE needs both client_secret_file and server_public_file")
        self.timeout_s = timeout_s
        self.ctx = ctx or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        if client_secret_file is not None:
            public, secret = zmq.auth.load_certificate(str(client_secret_file))
            server_public, _ = zmq.auth.load_certificate(str(server_public_file))
            if not secret:
                raise ValueError(f"{client_secret_file} holds no secret key")
            self.sock.curve_secretkey = secret
            self.sock.curve_publickey = public
            self.sock.curve_serverkey = server_public
        self.sock.connect(endpoint)
        self._poller = zmq.Poller()
        self._poller.register(self.sock, zmq.POLLIN)

    def request(self, op: str, **args: Any) -> Reply:
        """Send one request and wait for its reply; TimeoutError if none comes (down, or refused by CURVE)."""
        rid = uuid.uuid4().hex
        self.sock.send_string(json.dumps({"op": op, "args": args, "id": rid}))
        deadline = time.monotonic() + self.timeout_s
        while (left := deadline - time.monotonic()) > 0:
            if not self._poller.poll(max(1, int(left * 1000))):
                continue
            reply = Reply.model_validate_json(self.sock.recv())
            if reply.id == rid:
                return reply
            # a late reply to an earlier, timed-out request: drop it
        raise TimeoutError(f"no reply to {op!r} within {self.timeout_s} s")

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
