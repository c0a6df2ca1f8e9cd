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
stops the server. Every request that reaches the server gets exactly one reply whose
``code`` says whose problem it is (the table in docs/daemon.md): a request larger than
``ControlCfg.max_request_bytes`` is refused as ``malformed`` without being parsed, so the
limit protects memory and still answers the client. libzmq itself drops (unanswered) a
connection that sends a frame larger than ``HARD_CAP_FACTOR`` times that limit; the
factor leaves room to answer near misses while a client streaming a gigabyte is cut off
after the frame header.

Decision record: docs/decisions/0014-safety-in-the-regulator.md.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import math
import os
import re
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal, get_args

import zmq
import zmq.auth
from pydantic import (
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from zmq.auth.thread import ThreadAuthenticator

from daq.errors import InputError
from daq.strict import Closed

Op = Literal["status", "ramp", "stop", "estop", "reset", "record_start", "record_stop", "record_rotate", "note"]
READ_ONLY_OPS: frozenset[str] = frozenset({"status"})
FORBIDDEN = "forbidden: observers may only read status"
MAX_MSG_BYTES = 1 << 20  # default request limit: a control request is small; refuse anything that could exhaust memory
HARD_CAP_FACTOR = 4  # libzmq's MAXMSGSIZE = this x the limit: larger frames drop the connection, unanswered
RCVHWM = 32  # queued requests per connection; with the hard cap this bounds what one client can make us hold
POLL_MS = 100  # how often the server thread checks for stop()
MAX_ERROR_CHARS = 1000  # an error text is for a person: one line, bounded even for a hostile request
MAX_LISTED_ERRORS = 5  # validation problems named in one reply (a request with 10^5 bad keys gets a short one)
MAX_LOC_CHARS = 64  # a field name quoted back from the request is clipped to this
FINITE = "must be a finite number"
# the request's own id, for a reply to a request too large to parse: first key, or last key of the top-level object
_ID_FIRST = re.compile(rb'\A\s*\{\s*"id"\s*:\s*"([\x20-\x21\x23-\x5b\x5d-\x7e]{1,128})"')
_ID_LAST = re.compile(rb'"id"\s*:\s*"([\x20-\x21\x23-\x5b\x5d-\x7e]{1,128})"\s*\}\s*\Z')
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")

log = logging.getLogger(__name__)

Handler = Callable[[dict], dict]


def _accepts(annotation: Any, kinds: tuple[type, ...]) -> bool:
    """True if a field's type is one of ``kinds`` or a union containing one (``float | None``)."""
    return annotation in kinds or any(a in kinds for a in get_args(annotation))


class _Args(Closed):
    """Base for per-op arguments: strict types, no unknown keys (a typo must not be ignored)."""

    model_config = ConfigDict(strict=True)

    @field_validator("*", mode="before")
    @classmethod
    def _finite(cls, v: Any, info: ValidationInfo) -> Any:
        """Every numeric arg must be finite, with a message that says so.

        Why here, for all fields: JSON as Python parses it allows ``NaN``/``Infinity`` (and
        ``1e999``), NaN fails every comparison, so a bound like ``le=1`` reported NaN as "should
        be less than or equal to 1" and a field without bounds would let it through to the
        motor. A huge integer for a float field is the same mistake (it has no float value).
        """
        field = cls.model_fields.get(info.field_name or "")
        if field is None or isinstance(v, bool) or not _accepts(field.annotation, (float, int)):
            return v
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(FINITE)
        if isinstance(v, int) and _accepts(field.annotation, (float,)):
            try:
                float(v)
            except OverflowError:
                raise ValueError(FINITE) from None
        return v


def _path_text(v: str | None) -> str | None:
    """A file name with a NUL can never be opened, and a text with one cannot be stored (HDF5's variable-length
    strings end at a NUL: a note with one ended the recorder, issue 29); say so here, before any handler."""
    if v is not None and "\x00" in v:
        raise ValueError("must not contain a NUL character")
    return v


class NoArgs(_Args):
    """Ops that take no arguments."""


class RampArgs(_Args):
    file: str = Field(min_length=1, description="ramp definition file to run")
    time_scale: float = Field(1.0, gt=0, le=1, description="slow a ramp down, never speed it up")

    _file_ok = field_validator("file")(_path_text)


class NoteArgs(_Args):
    text: str = Field(description="free text for the run log")

    @field_validator("text")
    @classmethod
    def _not_blank(cls, v: str) -> str:
        """A blank note is almost certainly a client bug."""
        if not v.strip():
            raise ValueError("must not be empty")
        return _path_text(v)


class RecordStartArgs(_Args):
    path: str | None = Field(None, min_length=1, description="output file; the recorder picks one if absent")

    _path_ok = field_validator("path")(_path_text)


ARGS_MODELS: dict[str, type[_Args]] = {
    "status": NoArgs, "ramp": RampArgs, "stop": NoArgs, "estop": NoArgs, "reset": NoArgs,
    "record_start": RecordStartArgs, "record_stop": NoArgs, "record_rotate": RecordStartArgs, "note": NoteArgs,
}


class Request(Closed):
    """One control request; ``args`` is validated against the op's own model and normalised."""

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


class Reply(Closed):
    """One control reply; ``error`` is set exactly when ``ok`` is False."""

    id: str
    ok: bool
    result: dict[str, Any] = Field(default_factory=dict)
    error: str | None = None
    code: Literal["malformed", "forbidden", "input", "failed", "internal"] | None = Field(
        None, description="kind of error: 'malformed'/'input' are the client's to fix (bad request, bad file)")


class ControlCfg(Closed):
    """Where the control socket binds and, optionally, the CURVE keys that allow remote use."""

    model_config = ConfigDict(frozen=True)
    endpoint: str = Field("tcp://127.0.0.1:5570", description="where the server binds; loopback unless CURVE")
    max_request_bytes: int = Field(
        MAX_MSG_BYTES, ge=1024, le=1 << 28,
        description=f"larger requests get a 'malformed' reply unparsed; beyond {HARD_CAP_FACTOR}x this, no reply")
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

    @property
    def hard_cap_bytes(self) -> int:
        """libzmq's MAXMSGSIZE: a frame above this drops the connection before it is buffered."""
        return self.max_request_bytes * HARD_CAP_FACTOR


def _one_line(text: str, limit: int = MAX_ERROR_CHARS) -> str:
    """An error text as one bounded line: a multi-line exception text must not read like a traceback."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _describe(exc: ValidationError, prefix: str = "") -> str:
    """Turn a pydantic error into 'field: problem' lines a client can act on (the first few, clipped)."""
    errors = exc.errors(include_url=False)
    parts = []
    for err in errors[:MAX_LISTED_ERRORS]:
        loc = ".".join(_one_line(str(p), MAX_LOC_CHARS) for p in ((prefix,) if prefix else ()) + tuple(err["loc"]))
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{loc}: {msg}" if loc else msg)
    if len(errors) > MAX_LISTED_ERRORS:
        parts.append(f"and {len(errors) - MAX_LISTED_ERRORS} more")
    return _one_line("; ".join(parts))


class _Malformed(Exception):
    """A request that is not a JSON object; the message says why, for the reply."""


class DuplicateKey(ValueError):
    """A JSON object with a key twice: refused, because "the last one wins" let ``op`` be swapped unseen."""


def _unique_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json.loads``' object hook: the object, or DuplicateKey naming the first key given twice."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise DuplicateKey(f"duplicate key {_one_line(key, MAX_LOC_CHARS)!r}")
        out[key] = value
    return out


def loads_strict(text: str | bytes) -> Any:
    """``json.loads`` that refuses an object with a key twice (DuplicateKey); for every request that commands."""
    return json.loads(text, object_pairs_hook=_unique_pairs)


def _decode(raw: bytes) -> Any:
    """Parse one request frame as UTF-8 JSON; raises _Malformed with a client-facing reason.

    Why so careful: ``json.loads(bytes)`` guesses UTF-16/32 from NUL bytes, raises
    RecursionError on deep nesting and a bare ValueError for a number of more than 4300
    digits; each of those must be the client's ``malformed``, not the server's ``internal``.
    """
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _Malformed(f"not JSON (not UTF-8: byte {exc.start} is {raw[exc.start:exc.start + 1]!r})") from None
    try:
        data = loads_strict(text)
    except DuplicateKey as exc:
        raise _Malformed(f"not one meaning ({exc})") from None
    except RecursionError:
        raise _Malformed("not JSON (nested too deep)") from None
    except json.JSONDecodeError as exc:
        raise _Malformed(f"not JSON ({exc})") from None
    except ValueError as exc:  # the int digits limit (CVE-2020-10735): "Exceeds the limit (4300 digits) ..."
        raise _Malformed(f"not JSON (number too long: {str(exc).split(';')[0]})") from None
    if _SURROGATE_ESCAPE.search(text) and _has_lone_surrogate(data):  # the walk only if an escape could be one
        raise _Malformed("not JSON (a \\u escape is a lone UTF-16 surrogate, not a character)")
    return data


def _has_lone_surrogate(data: Any) -> bool:
    """True if a string (key or value) holds an unpaired surrogate, which no reply could encode as UTF-8.

    Why: ``"\\ud800"`` is valid JSON syntax, but echoing it (in the id, or in a handler's
    result) made the reply unserialisable and killed the server thread. Iterative, so it is
    safe at any depth the parser accepted.
    """
    stack = [data]
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            try:
                item.encode("utf-8")
            except UnicodeEncodeError:
                return True
        elif isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
    return False


def _peek_id(raw: bytes) -> str:
    """Best-effort request id of a frame too large to parse, so the client can match the refusal.

    Only an ``"id"`` that is the first key, or the last key of the top-level object (where
    ``json.dumps({"op", "args", "id"})`` puts it), is taken; anything else gives "".
    """
    m = _ID_FIRST.match(raw[:256]) or _ID_LAST.search(raw[-256:])
    return m.group(1).decode("ascii") if m else ""


def _path_field(args: dict[str, Any], filename: str) -> str:
    """The request arg naming ``filename`` (or a file below it, e.g. a missing directory), else '(file)'."""
    target = Path(filename)
    for key, value in args.items():
        if isinstance(value, str) and value:
            p = Path(value)
            if any(target == c or target in c.parents for c in (p, p.absolute())):
                return key
    return "(file)"


def _split_frames(frames: list[Any]) -> tuple[list[Any], list[Any]]:
    """Routing envelope and request body of one ROUTER message.

    Why: a DEALER sends ``[body]``, a REQ ``["", body]`` (ROUTER prepends the peer id), a
    proxy may add more. Everything up to the last empty frame before the final one is
    envelope, echoed back so each kind of client gets its reply; the rest must be one frame.
    """
    for i in range(len(frames) - 2, 0, -1):
        if len(frames[i]) == 0:
            return frames[: i + 1], frames[i + 1:]
    return frames[:1], frames[1:]


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
            # above the request limit, so a too-large request still reaches handle() and is answered
            sock.setsockopt(zmq.MAXMSGSIZE, self.cfg.hard_cap_bytes)
            sock.setsockopt(zmq.RCVHWM, RCVHWM)
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
            envelope, body = _split_frames(frames)
            try:
                out = self._answer(body).model_dump_json().encode()
            except Exception:  # handle() never raises and its replies serialise; this is the last line
                log.exception("control request")
                out = Reply(id="", ok=False, error="internal error: see the daemon log", code="internal") \
                    .model_dump_json().encode()
            try:
                sock.send_multipart([f.bytes for f in envelope] + [out])
            except zmq.ZMQError:
                pass  # the client went away; nothing to tell it

    def _answer(self, body: list[zmq.Frame]) -> Reply:
        """The reply to one request body (normally one frame), with the client's role from CURVE."""
        if len(body) != 1:
            self.requests += 1
            return self._fail("", f"malformed request: expected one JSON frame, got {len(body)} frames", "malformed")
        payload = body[0]
        try:
            user_id = payload.get("User-Id") if self.cfg.curve else None
        except zmq.ZMQError:
            user_id = None
        return self.handle(payload.bytes, self.role_of(user_id))

    def handle(self, raw: bytes, role: Literal["operator", "observer"] | None) -> Reply:
        """Turn one raw request into a reply that serialises; never raises.

        Codes: ``malformed`` (the request itself: size, encoding, JSON, fields), ``forbidden``
        (role), ``input`` (a handler's InputError, or an OSError naming a file: ``FILE: FIELD:
        message``), ``failed`` (any other handler exception, or no handler; the text names the
        op), ``internal`` (a bug here or a handler result that is not a JSON object).
        """
        self.requests += 1
        rid = ""
        op = "request"
        try:
            limit = self.cfg.max_request_bytes
            if len(raw) > limit:  # refused unparsed: the limit is there to bound the work a request can cause
                return self._fail(_peek_id(raw), f"malformed request: size: {len(raw)} bytes is too large "
                                  f"(the limit is {limit} bytes)", "malformed")
            try:
                data = _decode(raw)
            except _Malformed as exc:
                return self._fail(rid, f"malformed request: {exc}", "malformed")
            if not isinstance(data, dict):
                return self._fail(rid, "malformed request: expected a JSON object", "malformed")
            if isinstance(data.get("id"), str):
                rid = data["id"]
            try:
                req = Request.model_validate(data)
            except ValidationError as exc:
                return self._fail(rid, f"malformed request: {_describe(exc)}", "malformed")
            op = req.op
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
                return self._fail(rid, _one_line(str(exc)), "input")
            except OSError as exc:
                if exc.filename is None:  # a socket, a pipe, a timeout: the daemon's problem, not the request's
                    return self._fail(rid, _one_line(f"{op} failed: {type(exc).__name__}: {exc}"), "failed")
                name = os.fsdecode(exc.filename) if isinstance(exc.filename, (str, bytes)) else str(exc.filename)
                return self._fail(rid, _one_line(f"{name}: {_path_field(req.args, name)}: {exc.strerror or exc}"),
                                  "input")
            except Exception as exc:  # a failing command must not take the control channel down
                return self._fail(rid, _one_line(f"{op} failed: {type(exc).__name__}: {exc}"), "failed")
            reply = Reply(id=rid, ok=True, result=result or {})
            reply.model_dump_json()  # fail here, with a reply, rather than at send time
            return reply
        except Exception as exc:  # e.g. a handler returned something that is not a JSON dict
            return self._fail(rid, _one_line(f"internal error: {op}: {type(exc).__name__}: {exc}"), "internal")

    def _fail(self, rid: str, error: str, code: str = "failed") -> Reply:
        """An error reply; a file name that is not UTF-8 (surrogate-escaped by Python) is written as ``\\udcff``."""
        self.errors += 1
        return Reply(id=rid, ok=False, error=error.encode("utf-8", "backslashreplace").decode("utf-8"), code=code)


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
        # A DEALER with no attached peer blocks in send (its CURVE handshake refused and the pipe
        # torn down between reconnects: CI saw `daq ctl status` hang 120 s): the send waits as the reply does.
        self.sock.setsockopt(zmq.SNDTIMEO, max(1, int(timeout_s * 1000)))
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
        deadline = time.monotonic() + self.timeout_s
        try:
            self.sock.send_string(json.dumps({"op": op, "args": args, "id": rid}))
        except zmq.Again:
            raise TimeoutError(f"could not send {op!r} within {self.timeout_s} s (no peer)") from None
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
