"""Control channel: real sockets on 127.0.0.1, fake handlers, CURVE roles."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zmq

from daq.daemon.control import (
    FORBIDDEN,
    ControlCfg,
    ControlClient,
    ControlServer,
    Reply,
    Request,
    generate_keys,
    is_local_endpoint,
)

pytestmark = pytest.mark.skipif(not zmq.has("curve"), reason="libzmq built without CURVE")

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


def _raw(endpoint: str, payload: bytes, timeout_s: float = 5.0) -> Reply:
    """Send arbitrary bytes, as a buggy or hostile client would."""
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(endpoint)
    try:
        sock.send(payload)
        assert sock.poll(int(timeout_s * 1000)), "no reply to a malformed request"
        return Reply.model_validate_json(sock.recv())
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
    from daq.errors import InputError

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
