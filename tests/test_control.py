"""Control channel: real sockets on 127.0.0.1, fake handlers, CURVE roles."""

from __future__ import annotations

import json
import math
import os
import random
import time
from collections import Counter
from pathlib import Path

import pytest
import zmq

from daq.daemon.control import (
    ARGS_MODELS,
    FINITE,
    FORBIDDEN,
    MAX_MSG_BYTES,
    ControlCfg,
    ControlClient,
    ControlServer,
    Reply,
    Request,
    generate_keys,
    is_local_endpoint,
)
from daq.errors import InputError



def test_libzmq_has_curve():
    """The daemon's keys need CURVE; pyzmq's wheels bundle it. A build without it fails here, not silently later."""
    assert zmq.has("curve")

ANY_PORT = "tcp://127.0.0.1:*"  # the OS picks a free port; the server reports it as .endpoint


class Calls:
    """Fake handlers that record what reached them."""

    def __init__(self) -> None:
        self.log: list[tuple[str, dict]] = []

    def handlers(self) -> dict:
        def make(op: str):
            def handler(args: dict) -> dict:
                self.log.append((op, args))
                if op == "ramp" and args["file"] == "explode.yaml":
                    raise RuntimeError("motor driver not ready")
                return {"op": op, "echo": args}
            return handler
        return {op: make(op) for op in ("status", "ramp", "stop", "estop", "record_start", "record_stop", "note")}

    def ops(self) -> list[str]:
        return [op for op, _ in self.log]


@pytest.fixture
def calls() -> Calls:
    return Calls()


@pytest.fixture
def server(calls):
    srv = ControlServer(calls.handlers(), ControlCfg(endpoint=ANY_PORT)).start()
    yield srv
    srv.stop()


@pytest.fixture
def client(server):
    with ControlClient(server.endpoint, timeout_s=5.0) as c:
        yield c


def _raw(endpoint: str, payload: bytes | list[bytes], timeout_s: float = 5.0) -> Reply:
    """Send arbitrary bytes (or frames), as a buggy or hostile client would; exactly one reply frame must come."""
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(endpoint)
    try:
        sock.send_multipart(payload if isinstance(payload, list) else [payload])
        assert sock.poll(int(timeout_s * 1000)), "no reply to a malformed request"
        frames = sock.recv_multipart()
        assert len(frames) == 1, frames
        return Reply.model_validate_json(frames[0])
    finally:
        sock.close()


# -- messages --------------------------------------------------------------------------------

def test_request_model_validates_args_per_op():
    assert Request(op="ramp", args={"file": "r.yaml"}, id="1").args == {"file": "r.yaml", "time_scale": 1.0}
    assert Request(op="record_start", args={}, id="1").args == {}
    for bad in ({"file": "r.yaml", "time_scale": 0}, {"file": "r.yaml", "time_scale": 1.5}, {}, {"file": 3}):
        with pytest.raises(ValueError):
            Request(op="ramp", args=bad, id="1")
    with pytest.raises(ValueError, match="text"):
        Request(op="note", args={"text": "  "}, id="1")
    with pytest.raises(ValueError):
        Request(op="stop", args={"force": True}, id="1")


def test_local_endpoint_policy():
    for ep in ("tcp://127.0.0.1:5570", "tcp://localhost:5570", "tcp://[::1]:5570", "ipc:///tmp/x", "inproc://x"):
        assert is_local_endpoint(ep), ep
    for ep in ("tcp://0.0.0.0:5570", "tcp://*:5570", "tcp://eth0:5570", "tcp://192.168.1.5:5570", "pgm://x"):
        assert not is_local_endpoint(ep), ep


# -- round trips -----------------------------------------------------------------------------

def test_round_trips(client, calls):
    r = client.request("status")
    assert r.ok and r.error is None and r.result == {"op": "status", "echo": {}}
    r = client.request("ramp", file="sweep.yaml", time_scale=0.5)
    assert r.ok and r.result["echo"] == {"file": "sweep.yaml", "time_scale": 0.5}
    r = client.request("note", text="pad changed")
    assert r.ok and r.result["echo"] == {"text": "pad changed"}
    assert calls.ops() == ["status", "ramp", "note"]


def test_malformed_requests_get_errors_and_server_keeps_going(server, client, calls):
    r = _raw(server.endpoint, b"{not json")
    assert not r.ok and "not JSON" in r.error
    r = _raw(server.endpoint, b"\xff\xfe")
    assert not r.ok and "not JSON" in r.error
    r = _raw(server.endpoint, b"[1, 2]")
    assert not r.ok and "JSON object" in r.error
    r = _raw(server.endpoint, json.dumps({"op": "status", "args": {}}).encode())
    assert not r.ok and "id" in r.error

    r = client.request("launch")
    assert not r.ok and "op" in r.error
    r = client.request("ramp", time_scale=0.5)
    assert not r.ok and "args.file" in r.error
    r = client.request("ramp", file="sweep.yaml", time_scale=2.0)
    assert not r.ok and "args.time_scale" in r.error
    r = client.request("note", text="")
    assert not r.ok and "args.text" in r.error
    r = client.request("estop", now=True)
    assert not r.ok and "args.now" in r.error
    assert calls.log == []  # nothing malformed reached a handler

    assert client.request("status").ok
    assert calls.ops() == ["status"]


def test_handler_exception_becomes_error_reply(client, calls):
    r = client.request("ramp", file="explode.yaml")
    assert not r.ok and "motor driver not ready" in r.error and "RuntimeError" in r.error
    assert client.request("stop").ok
    assert calls.ops() == ["ramp", "stop"]


def test_missing_handler_is_an_error_not_a_crash(calls):
    with ControlServer({"status": lambda a: {"state": "idle"}}, ControlCfg(endpoint=ANY_PORT)) as srv:
        with ControlClient(srv.endpoint, timeout_s=5.0) as c:
            r = c.request("estop")
            assert not r.ok and "estop" in r.error
            assert c.request("status").result == {"state": "idle"}


def test_non_loopback_without_curve_is_refused():
    for ep in ("tcp://0.0.0.0:*", "tcp://*:*"):
        srv = ControlServer({}, ControlCfg(endpoint=ep))
        with pytest.raises(ValueError, match="without CURVE"):
            srv.start()
        assert srv.endpoint is None


def test_half_curve_config_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="server_secret_file"):
        ControlCfg(operators_dir=tmp_path)
    with pytest.raises(ValueError, match="operators_dir"):
        ControlCfg(server_secret_file=tmp_path / "s.key_secret")


def test_client_timeout_when_nobody_listens():
    with ControlClient("tcp://127.0.0.1:1", timeout_s=0.3) as c, pytest.raises(TimeoutError):
        c.request("status")


# -- CURVE -----------------------------------------------------------------------------------

@pytest.fixture
def keys(tmp_path) -> dict[str, tuple[Path, Path]]:
    """Server, operator, observer and stranger key pairs, each in its own directory."""
    return {name: generate_keys(tmp_path / name, name) for name in ("server", "operator", "observer", "stranger")}


@pytest.fixture
def curve_server(keys, calls):
    cfg = ControlCfg(endpoint="tcp://0.0.0.0:*", server_secret_file=keys["server"][1],
                     operators_dir=keys["operator"][0].parent, observers_dir=keys["observer"][0].parent)
    srv = ControlServer(calls.handlers(), cfg).start()  # non-loopback is allowed with CURVE
    yield srv
    srv.stop()


def _local(endpoint: str) -> str:
    return endpoint.replace("0.0.0.0", "127.0.0.1")


def _curve_client(srv, keys, who: str | None, timeout_s: float = 5.0) -> ControlClient:
    if who is None:
        return ControlClient(_local(srv.endpoint), timeout_s=timeout_s)
    return ControlClient(_local(srv.endpoint), client_secret_file=keys[who][1],
                         server_public_file=keys["server"][0], timeout_s=timeout_s)


def test_generate_keys(keys):
    public, secret = keys["operator"]
    assert public.name == "operator.key" and secret.name == "operator.key_secret"
    assert zmq.auth.load_certificate(str(secret))[1] is not None
    assert zmq.auth.load_certificate(str(public))[1] is None


def test_curve_client_without_keys_gets_no_reply(curve_server, keys, calls):
    with _curve_client(curve_server, keys, None, timeout_s=1.0) as c, pytest.raises(TimeoutError):
        c.request("estop")
    with _curve_client(curve_server, keys, "operator") as ok:  # the server was up and answering all along
        assert ok.request("status").ok
    assert calls.ops() == ["status"]  # the refused estop never reached a handler


def test_curve_unknown_key_gets_no_reply(curve_server, keys, calls):
    with _curve_client(curve_server, keys, "stranger", timeout_s=1.0) as c, pytest.raises(TimeoutError):
        c.request("estop")
    with _curve_client(curve_server, keys, "operator") as ok:  # the server was up and answering all along
        assert ok.request("status").ok
    assert calls.ops() == ["status"]  # the refused estop never reached a handler


def test_curve_observer_reads_but_cannot_command(curve_server, keys, calls):
    with _curve_client(curve_server, keys, "observer") as c:
        assert c.request("status").ok
        for op, args in (("estop", {}), ("stop", {}), ("ramp", {"file": "sweep.yaml"}), ("note", {"text": "hi"})):
            r = c.request(op, **args)
            assert not r.ok and r.error == FORBIDDEN, op
    assert calls.ops() == ["status"]


def test_curve_operator_can_estop(curve_server, keys, calls):
    with _curve_client(curve_server, keys, "operator") as c:
        assert c.request("status").ok
        r = c.request("estop")
        assert r.ok and r.result["op"] == "estop"
    assert calls.ops() == ["status", "estop"]


def test_curve_role_comes_from_user_id(curve_server, keys):
    """The authenticator's User-Id is the client's Z85 public key; map it both ways."""
    op_pub = zmq.auth.load_certificate(str(keys["operator"][0]))[0].decode()
    ob_pub = zmq.auth.load_certificate(str(keys["observer"][0]))[0].decode()
    assert curve_server.role_of(op_pub) == "operator"
    assert curve_server.role_of(ob_pub) == "observer"
    assert curve_server.role_of(None) is None and curve_server.role_of("x" * 40) is None


def test_error_codes_tell_bad_input_from_refusals(calls):
    """``daq ctl`` exits 2 for the client's own mistakes (malformed, bad file) and 1 for refusals."""
    def bad_ramp(args: dict) -> dict:
        raise InputError(args["file"], "segment[0].kind", "unknown kind 'warp'")

    handlers = {**calls.handlers(), "ramp": bad_ramp}
    with ControlServer(handlers, ControlCfg(endpoint=ANY_PORT)) as srv, ControlClient(srv.endpoint, timeout_s=5.0) as c:
        r = c.request("ramp", file="r.toml")
        assert not r.ok and r.code == "input" and r.error == "r.toml: segment[0].kind: unknown kind 'warp'"
        r = c.request("ramp", file=7)
        assert not r.ok and r.code == "malformed" and "args.file" in r.error
        r = c.request("record_start", path="x.h5")
        assert r.ok and r.code is None
        assert srv.role_of(None) == "operator"  # no CURVE: only local clients can connect, all operate
    with ControlServer({"status": lambda a: 1 / 0}, ControlCfg(endpoint=ANY_PORT)) as srv:
        with ControlClient(srv.endpoint, timeout_s=5.0) as c:
            r = c.request("status")
            assert not r.ok and r.code == "failed" and "ZeroDivisionError" in r.error
            assert c.request("stop").code == "failed"  # no handler: an error, not a crash


# -- hostile and broken requests (issue 16) --------------------------------------------------

def _request_bytes(op: str, args: dict, rid: str = "1") -> bytes:
    """A request as ControlClient writes it (json.dumps writes NaN/Infinity for non-finite floats)."""
    return json.dumps({"op": op, "args": args, "id": rid}).encode()


def test_oversize_request_is_answered_with_the_limit_and_server_keeps_serving(server, client, calls):
    big = "x" * (2 * MAX_MSG_BYTES)
    t0 = time.monotonic()
    r = client.request("note", text=big)  # ControlClient matches the reply by id: the server recovered it
    assert time.monotonic() - t0 < client.timeout_s
    assert not r.ok and r.code == "malformed" and f"the limit is {MAX_MSG_BYTES} bytes" in r.error, r
    r = _raw(server.endpoint, b"[" * (MAX_MSG_BYTES + 1))  # not even JSON: still answered, without an id
    assert not r.ok and r.code == "malformed" and "too large" in r.error and r.id == ""
    assert client.request("status").ok
    assert calls.ops() == ["status"]


def test_request_limit_is_configurable_and_beyond_the_hard_cap_the_connection_drops(calls):
    cfg = ControlCfg(endpoint=ANY_PORT, max_request_bytes=4096)
    assert ControlCfg().max_request_bytes == MAX_MSG_BYTES and cfg.hard_cap_bytes == 4 * 4096
    with ControlServer(calls.handlers(), cfg) as srv, ControlClient(srv.endpoint, timeout_s=5.0) as c:
        assert c.request("note", text="y" * 4000).ok
        r = c.request("note", text="y" * 5000)
        assert not r.ok and r.code == "malformed" and "the limit is 4096 bytes" in r.error
        # beyond the hard cap libzmq drops the connection unread: documented, no reply
        sock = zmq.Context.instance().socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(srv.endpoint)
        try:
            sock.send(_request_bytes("note", {"text": "z" * cfg.hard_cap_bytes}))
            assert not sock.poll(500)
            sock.send(_request_bytes("status", {}, "after"))  # the same client reconnects and is served
            assert sock.poll(5000)
            assert Reply.model_validate_json(sock.recv()).id == "after"
        finally:
            sock.close()
        assert c.request("status").ok
    with pytest.raises(ValueError):
        ControlCfg(max_request_bytes=0)


def test_deeply_nested_json_is_malformed_not_internal(server, client):
    for payload in (b"[" * 100_000 + b"]" * 100_000, b'{"a":' * 100_000 + b"1" + b"}" * 100_000,
                    b'{"op": "note", "args": {"text": ' + b"[" * 5000 + b"]" * 5000 + b'}, "id": "d"}'):
        r = _raw(server.endpoint, payload)
        assert not r.ok and r.code == "malformed" and "nested too deep" in r.error, r
    assert client.request("status").ok


def test_non_finite_numbers_are_refused_as_such(server, client, calls):
    for literal in (b"NaN", b"Infinity", b"-Infinity", b"1e999", b"1" + b"0" * 400):
        payload = b'{"op": "ramp", "args": {"file": "r.yaml", "time_scale": ' + literal + b'}, "id": "n"}'
        r = _raw(server.endpoint, payload)
        assert not r.ok and r.code == "malformed" and r.error == f"malformed request: args.time_scale: {FINITE}", r
    for value in (math.nan, math.inf, -math.inf):
        r = client.request("ramp", file="r.yaml", time_scale=value)
        assert not r.ok and r.code == "malformed" and f"args.time_scale: {FINITE}" in r.error
    assert calls.log == []


def test_every_numeric_arg_in_the_request_models_must_be_finite():
    numeric = [(op, name) for op, model in ARGS_MODELS.items() for name, f in model.model_fields.items()
               if f.annotation in (int, float) or any(a in (int, float) for a in getattr(f.annotation, "__args__", ()))]
    assert ("ramp", "time_scale") in numeric  # the check below would be vacuous without it
    for op, name in numeric:
        for bad in (math.nan, math.inf, -math.inf, 10**400):
            with pytest.raises(ValueError, match=f"args.{name}: {FINITE}"):
                Request(op=op, args={name: bad}, id="1")


def _open_like_the_daemon(args: dict) -> dict:
    """record_start's file handling in the daemon: absolute path, create the directory, never overwrite."""
    path = Path(args["path"]).absolute()
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "xb"):
        pass
    return {"recording": str(path)}


def test_unwritable_record_path_is_input_naming_the_path(calls, tmp_path, monkeypatch):
    (tmp_path / "afile").write_text("a file, not a directory")
    (tmp_path / "exists.h5").write_bytes(b"")

    def internal_file(args: dict) -> dict:
        open("/proc/no-such-daemon-state")  # a file the request did not name
        return {}

    def no_filename(args: dict) -> dict:
        raise ConnectionRefusedError(111, "Connection refused")

    handlers = {**calls.handlers(), "record_start": _open_like_the_daemon, "record_stop": internal_file,
                "stop": no_filename}
    monkeypatch.chdir(tmp_path)
    with ControlServer(handlers, ControlCfg(endpoint=ANY_PORT)) as srv, ControlClient(srv.endpoint, timeout_s=5.0) as c:
        cases = [(str(tmp_path / "afile" / "x.h5"), f"{tmp_path / 'afile'}: path: File exists"),
                 ("afile/y.h5", f"{tmp_path / 'afile'}: path: File exists"),  # relative, made absolute by the handler
                 (str(tmp_path / "exists.h5"), f"{tmp_path / 'exists.h5'}: path: File exists")]
        if Path("/proc/self").exists():
            cases.append(("/proc/nonexistent/dir/x.h5", "/proc/nonexistent: path: No such file or directory"))
        if os.geteuid() != 0:  # root writes anywhere
            ro = tmp_path / "ro"
            ro.mkdir(mode=0o500)
            cases.append((str(ro / "x.h5"), f"{ro / 'x.h5'}: path: Permission denied"))
        for path, expect in cases:
            r = c.request("record_start", path=path)
            assert not r.ok and r.code == "input" and r.error == expect, (path, r)
        if Path("/proc/self").exists():
            r = c.request("record_stop")
            assert r.code == "input" and r.error == "/proc/no-such-daemon-state: (file): No such file or directory"
        r = c.request("stop")  # an OSError without a file is the daemon's failure, and says which op
        assert r.code == "failed" and r.error.startswith("stop failed: ConnectionRefusedError")
        r = c.request("record_start", path=str(tmp_path / "new" / "ok.h5"))
        assert r.ok and Path(r.result["recording"]).is_file()


def test_bad_request_shapes_each_get_one_reply(calls):
    def bad_result(args: dict) -> dict:
        return {"text": json.loads('"\\udc80"')}  # a lone surrogate: the reply cannot be encoded

    def undecodable_name(args: dict) -> dict:
        raise FileNotFoundError(2, "No such file or directory", os.fsdecode(b"/data/run-\xff.h5"))

    handlers = {**calls.handlers(), "record_stop": lambda a: ["not", "a", "dict"], "estop": bad_result,
                "stop": undecodable_name}
    with ControlServer(handlers, ControlCfg(endpoint=ANY_PORT)) as srv, ControlClient(srv.endpoint, timeout_s=5.0) as c:
        ep = srv.endpoint
        cases = [
            (b"[1, 2]", "malformed", "expected a JSON object"),
            (b'"status"', "malformed", "expected a JSON object"),
            (b"null", "malformed", "expected a JSON object"),
            (b"\xff\xfe\x00", "malformed", "not UTF-8"),
            (json.dumps({"op": "status", "args": {}, "id": "u"}).encode("utf-16"), "malformed", "not UTF-8"),
            (b"\xef\xbb\xbf" + _request_bytes("status", {}), "malformed", "not JSON"),
            (b"", "malformed", "not JSON"),
            (b'{"op": "status", "args": [], "id": "a"}', "malformed", "args"),
            (b'{"op": "status", "args": null, "id": "a"}', "malformed", "args"),
            (b'{"op": "status", "args": {}, "id": "a", "x": ' + b"9" * 5000 + b"}", "malformed", "number too long"),
            (b'{"op": "status", "args": {}, "id": ' + b"9" * 4000 + b"}", "malformed", "id"),
            (b'{"op": "status", "args": {}, "id": "\\ud800"}', "malformed", "surrogate"),
            (_request_bytes("note", {"text": "ok", "k" * 100_000: 1}), "malformed", "Extra inputs"),
            (_request_bytes("note", {f"k{i}": i for i in range(10_000)}), "malformed", "more"),
            (_request_bytes("record_start", {"path": "x\x00.h5"}), "malformed", "NUL"),
            (_request_bytes("record_stop", {}), "internal", "record_stop"),
            (_request_bytes("estop", {}), "internal", "estop"),
            ([b"{}", b"{}"], "malformed", "one JSON frame"),
            (_request_bytes("stop", {}), "input", "/data/run-\\udcff.h5: (file): No such file"),
        ]
        for payload, code, expect in cases:
            r = _raw(ep, payload)
            assert not r.ok and r.code == code and expect in r.error, (payload[:80], r)
            assert len(r.error) <= 1000 and "\n" not in r.error
        r = _raw(ep, _request_bytes("note", {"text": "long " * 100_000}, "L" * 10_000))  # big but under the limit
        assert r.ok and r.id == "L" * 10_000 and len(r.result["echo"]["text"]) == 500_000
        req = zmq.Context.instance().socket(zmq.REQ)  # a REQ client: the empty delimiter frame is echoed
        req.setsockopt(zmq.LINGER, 0)
        req.connect(ep)
        try:
            req.send(_request_bytes("status", {}, "req"))
            assert req.poll(5000) and Reply.model_validate_json(req.recv()).id == "req"
        finally:
            req.close()
        assert c.request("status").ok


# -- fuzz ------------------------------------------------------------------------------------

FUZZ_CASES = 300
FUZZ_LIMIT = 64 * 1024  # small, so oversize cases are cheap; the hard cap is 4x this
FUZZ_OPS = ["status", "ramp", "stop", "estop", "record_start", "record_stop", "note",
            "launch", "", "STATUS", None, 3, ["status"], {"op": "status"}]
FUZZ_KEYS = ["file", "time_scale", "text", "path", "force", "", "x" * 300, "\u0000", "é☃😀"]
VALID_ARGS = {"ramp": {"file": "sweep.yaml", "time_scale": 0.5}, "note": {"text": "pad changed"},
              "record_start": {"path": "/nonexistent/fuzz/x.h5"}}
TEXT_TRICKS = [b"NaN", b"Infinity", b"-Infinity", b"1e999", b"-0", b"1" * 5000, b'"\\ud800"', b'"\\udfff\\ud800"',
               b'"\\ud83d\\ude00"', b'"\\u0000"', b"[" * 3000 + b"]" * 3000, b"{}", b"[]", b"true", b"null",
               b'"' + b"s" * 20_000 + b'"', b"1.7976931348623157e309", b"0x10", b"01", b"'single'", b"undefined"]


def _nasty(rng: random.Random, depth: int = 0) -> object:
    """A JSON-serialisable value a fuzzer would try in a field."""
    pool = [math.nan, math.inf, -math.inf, -0.0, 0.0, 5e-324, 0.5, 1.5, 1, 0, -1, 2**63, 10**400, True, False, None,
            "", " ", "sweep.yaml", "explode.yaml", "/", "\x00", "é☃😀", "/nonexistent/dir/x.h5", "../etc/passwd",
            "x" * rng.randint(0, 3000)]
    if depth < 3:
        pool += [[_nasty(rng, depth + 1)], {"k": _nasty(rng, depth + 1)}, []]
    return rng.choice(pool)


def _structured(rng: random.Random) -> bytes:
    """A request object, valid about a third of the time, else with wrong, missing or extra parts."""
    op = rng.choice(FUZZ_OPS[:7]) if rng.random() < 0.8 else rng.choice(FUZZ_OPS)
    req: dict = {}
    if rng.random() < 0.95:
        req["op"] = op
    if rng.random() < 0.9:
        args = dict(VALID_ARGS.get(op, {})) if isinstance(op, str) else {}
        for _ in range(rng.choice((0, 0, 0, 0, 1, 1, 2, 3))):
            if rng.random() < 0.5 and args:
                args[rng.choice(list(args))] = _nasty(rng)
            else:
                args[rng.choice(FUZZ_KEYS)] = _nasty(rng)
        req["args"] = args if rng.random() < 0.9 else _nasty(rng)
    if rng.random() < 0.9:
        req["id"] = rng.choice([str(rng.randrange(10**6)), "", "é☃😀", "i" * rng.randint(1, 2000)]) \
            if rng.random() < 0.85 else _nasty(rng)
    if rng.random() < 0.1:
        req[rng.choice(FUZZ_KEYS)] = _nasty(rng)
    items = list(req.items())
    rng.shuffle(items)
    return json.dumps(dict(items)).encode()


def _mutate(rng: random.Random, data: bytes) -> bytes:
    b = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        pos = rng.randrange(len(b) + 1)
        how = rng.randrange(5)
        if how == 0 and b:
            b[min(pos, len(b) - 1)] = rng.randrange(256)
        elif how == 1:
            b[pos:pos] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        elif how == 2:
            del b[pos:pos + rng.randint(1, 8)]
        elif how == 3:
            b = b[:pos]
        else:
            b[pos:pos] = rng.choice(TEXT_TRICKS)
    return bytes(b)


def _fuzz_case(rng: random.Random, limit: int) -> tuple[list[bytes], list[bytes]]:
    """One request (frames to send) and the envelope frames its reply must come back with."""
    k = rng.random()
    if k < 0.45:
        return [_structured(rng)], []
    if k < 0.65:
        return [_mutate(rng, _structured(rng))], []
    if k < 0.72:
        return [bytes(rng.randrange(256) for _ in range(rng.randint(0, 200)))], []
    if k < 0.82:  # a literal json.dumps cannot write, put where a value goes
        trick = rng.choice(TEXT_TRICKS)
        where = rng.choice([b'{"op": "ramp", "args": {"file": "r.yaml", "time_scale": %s}, "id": "t"}',
                            b'{"op": "note", "args": {"text": %s}, "id": "t"}',
                            b'{"op": "status", "args": {}, "id": %s}',
                            b'{"op": %s, "args": {}, "id": "t"}', b"%s"])
        return [where.replace(b"%s", trick)], []
    if k < 0.87:
        depth = rng.choice((900, 1000, 2000, 30_000))
        return [rng.choice((b"[" * depth + b"]" * depth, b'{"a":' * depth + b"0" + b"}" * depth))], []
    if k < 0.93:
        pad = rng.randint(limit + 1, 4 * limit - 100) - 60
        return [_request_bytes("note", {"text": "o" * pad}, rng.choice(["big", ""]))], []
    body = _structured(rng)
    shape = rng.randrange(4)
    if shape == 0:
        return [body, body], []
    if shape == 1:
        return [b"", body], [b""]  # REQ-style envelope: the delimiter comes back
    if shape == 2:
        return [b""], []
    return [b"", body, body], [b""]


def _expected_id(frames: list[bytes], envelope: list[bytes], limit: int) -> str | None:
    """The id the reply must carry, if the request is a parseable JSON object with a clean string id."""
    body = frames[len(envelope):]
    if len(body) != 1 or len(body[0]) > limit:
        return None
    try:
        data = json.loads(body[0].decode("utf-8"))
        json.dumps(data, ensure_ascii=False).encode("utf-8")  # a lone surrogate anywhere: refused without id
    except Exception:
        return None
    return data["id"] if isinstance(data, dict) and isinstance(data.get("id"), str) else None


def _fuzz_handlers() -> dict:
    """Handlers that fail the ways the daemon's do; read-only (os.stat), so a fuzzed path creates nothing."""
    def ramp(args: dict) -> dict:
        if args["file"] == "explode.yaml":
            raise RuntimeError("motor driver not ready\nsecond line")
        if args["file"] != "sweep.yaml":
            os.stat(args["file"])
        return {"started": True}

    def record_start(args: dict) -> dict:
        if "path" in args:
            os.stat(args["path"])
        return {"recording": args.get("path", "auto.h5")}

    def stop(args: dict) -> dict:
        raise ConnectionRefusedError(111, "motor regulator not answering")

    handlers = {op: (lambda args, op=op: {"op": op}) for op in ("status", "estop", "record_stop")}
    return {**handlers, "ramp": ramp, "stop": stop, "record_start": record_start, "note": lambda args: {"echo": args}}


def run_fuzz(n: int, seed: int, limit: int = FUZZ_LIMIT) -> dict:
    """Send ``n`` fuzzed requests to a real server, check each reply; returns the figures (cases, replies, codes)."""
    rng = random.Random(seed)
    codes: Counter[str] = Counter()
    replies = 0
    with ControlServer(_fuzz_handlers(), ControlCfg(endpoint=ANY_PORT, max_request_bytes=limit)) as srv:
        sock = zmq.Context.instance().socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(srv.endpoint)
        t0 = time.monotonic()
        try:
            for i in range(n):
                frames, envelope = _fuzz_case(rng, limit)
                sock.send_multipart(frames)
                assert sock.poll(5000), (i, [f[:100] for f in frames])
                back = sock.recv_multipart()
                assert back[:-1] == envelope, (i, back)
                r = Reply.model_validate_json(back[-1])
                replies += 1
                codes["ok" if r.ok else str(r.code)] += 1
                assert r.ok == (r.error is None) == (r.code is None), (i, r)
                if not r.ok:
                    assert r.code != "internal" and "Traceback" not in r.error and "\n" not in r.error, (i, frames, r)
                    assert len(r.error) <= 1000, (i, r)
                if len(frames) == 1 and len(frames[0]) > limit:
                    assert r.code == "malformed" and "too large" in r.error, (i, r)
                rid = _expected_id(frames, envelope, limit)
                if rid is not None:
                    assert r.id == rid, (i, frames[-1][:200], r)
            sock.send(_request_bytes("status", {}, "end"))
            assert sock.poll(5000)
            r = Reply.model_validate_json(sock.recv())
            assert r.ok and r.id == "end"
            assert not sock.poll(50), "a request got more than one reply"
        finally:
            sock.close()
    return {"cases": n, "replies": replies, "codes": dict(codes), "seconds": round(time.monotonic() - t0, 2)}


def test_fuzzed_requests_each_get_one_well_formed_reply():
    figures = run_fuzz(FUZZ_CASES, seed=16)
    assert figures["replies"] == FUZZ_CASES and figures["codes"].get("internal", 0) == 0
    assert {"ok", "malformed", "input", "failed"} <= set(figures["codes"]), figures  # the fuzz reaches every path
