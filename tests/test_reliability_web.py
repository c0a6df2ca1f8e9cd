"""Issue 29: a hostile viewer of the live page, through a raw HTTP client against ``daq daemon --sim --web``.

One real daemon with CURVE keys and the page (tests/test_web.py's ``Rig``: a page is an observer
unless it carries the operator token). Before the fixes: a 300 MB body was forwarded whole to the
daemon (8.8 s, 1.38 GB, a watchdog stop); a token-carrying POST from another site's page was
obeyed; an observer could reset the latency figures; 16 token-less WebSockets locked the operator's
page out (403); invalid UTF-8 on a WebSocket printed a uvicorn traceback into the operator's log.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import socket
import time
from urllib.parse import urlsplit

import pytest
from test_daemon_e2e import _wait_for
from test_web import Rig
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

MIB = 1 << 20


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    r = Rig(tmp_path_factory.mktemp("web-hostile"))
    yield r
    r.close()


def _conn(rig: Rig) -> http.client.HTTPConnection:
    u = urlsplit(rig.url)
    return http.client.HTTPConnection(u.hostname, u.port, timeout=30)


def _post(rig: Rig, path: str, body: bytes, headers: dict[str, str]) -> tuple[int, dict]:
    c = _conn(rig)
    try:
        c.request("POST", path, body=body, headers={"X-Daq-Page": "1", "Content-Type": "application/json",
                                                    **headers})
        r = c.getresponse()
        return r.status, json.loads(r.read() or b"{}")
    finally:
        c.close()


def _operator(rig: Rig) -> dict[str, str]:
    return {"Authorization": f"Bearer {rig.token}", "Origin": rig.url.rstrip("/")}


def _traceback_lines(rig: Rig) -> list[str]:
    return [line for line in rig.d.err if "Traceback" in line or "Error" in line.split(":")[0]]


def test_a_body_over_1_mib_is_refused_with_413_while_it_streams_and_never_reaches_the_daemon(rig):
    before = rig.status()["streams"]["motor"]["samples"]
    # declared: refused on the header, before a byte of the body is read
    c = _conn(rig)
    try:
        c.putrequest("POST", "/api/command")
        for k, v in {"X-Daq-Page": "1", "Content-Type": "application/json", "Content-Length": str(300 * MIB)}.items():
            c.putheader(k, v)
        c.endheaders()
        c.send(b'{"op": "status", "args": {"a": "' + b"x" * 65536)
        t0 = time.monotonic()
        r = c.getresponse()
        declared = (r.status, time.monotonic() - t0)
        r.read()
    finally:
        c.close()
    # chunked, no length: counted as it arrives, refused once past 1 MiB
    u = urlsplit(rig.url)
    s = socket.create_connection((u.hostname, u.port), timeout=30)
    sent = 0
    try:
        s.sendall(f"POST /api/command HTTP/1.1\r\nHost: {u.netloc}\r\nX-Daq-Page: 1\r\n"
                  "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n".encode())
        chunk = b"x" * 65536
        try:
            while sent < 64 * MIB:  # the server must answer long before this
                s.sendall(b"%x\r\n%s\r\n" % (len(chunk), chunk))
                sent += len(chunk)
                s.settimeout(0.0)
                try:
                    if s.recv(1, socket.MSG_PEEK):
                        break
                except BlockingIOError:
                    pass
                finally:
                    s.settimeout(30)
        except (BrokenPipeError, ConnectionResetError):
            pass
        s.settimeout(10)
        head = s.recv(4096).decode(errors="replace")
    finally:
        s.close()
    print(f"declared 300 MB: {declared[0]} after {declared[1] * 1000:.0f} ms; chunked: refused after "
          f"{sent / MIB:.1f} MiB sent: {head.splitlines()[0] if head else '(nothing)'}")
    assert declared[0] == 413
    assert head.startswith("HTTP/1.1 413"), head[:200]
    assert sent <= 8 * MIB  # refused near the limit (socket buffers hold a few MiB), not after the whole body
    time.sleep(1.0)
    st = rig.status()
    assert st["streams"]["motor"]["samples"] > before and st["streams"]["motor"]["rate_hz"] > 50
    assert not st["regulator"]["latched"]


def test_a_command_with_the_token_from_another_sites_page_is_refused(rig):
    body = json.dumps({"op": "note", "args": {"text": "from evil.example"}}).encode()
    status, reply = _post(rig, "/api/command", body, {**_operator(rig), "Origin": "http://evil.example"})
    assert status == 403 and reply["code"] == "forbidden" and "origin" in reply["error"], reply
    status, reply = _post(rig, "/api/command", body.replace(b"evil.example", b"our page"), _operator(rig))
    assert status == 200 and reply["ok"], reply  # the same request from the page itself is obeyed


def test_a_command_with_a_key_twice_is_refused_by_the_page_process(rig):
    raw = b'{"op": "status", "op": "estop", "args": {}}'
    status, reply = _post(rig, "/api/command", raw, _operator(rig))
    assert status == 400 and reply["code"] == "malformed" and "duplicate key 'op'" in reply["error"], reply
    assert not rig.status()["regulator"]["latched"]


def test_an_observer_cannot_reset_the_latency_figures(rig):
    status, reply = _post(rig, "/api/latency/reset", b"", {"Origin": rig.url.rstrip("/")})
    assert status == 403, reply
    status, reply = _post(rig, "/api/latency/reset", b"", _operator(rig))
    assert status == 200 and reply == {"reset": True}


def test_token_less_viewers_never_lock_out_the_operators_page(rig):
    ws_url = rig.url.replace("http://", "ws://") + "ws"
    viewers, refused = contextlib.ExitStack(), 0
    admitted = 0
    try:
        for _ in range(40):
            try:
                viewers.enter_context(connect(ws_url, open_timeout=10))
                admitted += 1
            except InvalidStatus:
                refused += 1
        assert refused > 0  # viewers are capped ...
        with connect(ws_url, subprotocols=["daq.v1", f"daq.token.{rig.token}"], open_timeout=10) as op:
            assert op.subprotocol == "daq.v1"
            op.send(json.dumps({"type": "view", "window_s": 10, "width": 500}))
            frame = json.loads(op.recv(timeout=10))  # ... and the operator's page is served all the same
            assert frame["type"] == "frame"
    finally:
        viewers.close()
    t0 = time.monotonic()
    _wait_for(lambda: rig.page_stats()["pages"] <= 1, 20, "closed viewers to free their places")
    print(f"{admitted} viewers admitted, {refused} refused; the operator's page connected; places free "
          f"{time.monotonic() - t0:.2f} s after the viewers closed")


def test_invalid_utf8_on_a_websocket_closes_it_without_a_traceback(rig):
    before = len(rig.d.err)
    with connect(rig.url.replace("http://", "ws://") + "ws", open_timeout=10) as ws:
        ws.send(b'{"type": "view", "window_s": 10, "width": 500}\xff\xfe', text=True)
        with pytest.raises(ConnectionClosed):
            for _ in range(1000):
                ws.recv(timeout=5)
    time.sleep(1.0)
    new = rig.d.err[before:]
    assert not [line for line in new if "Traceback" in line or "Exception" in line], "".join(new)
    _wait_for(lambda: rig.page_stats()["pages"] <= 1, 5, "the session to be gone")
