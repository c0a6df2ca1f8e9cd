"""Issue 29, the fast part: what a stray byte, a doubled key or a null field may not do (no daemon needed).

Each test here failed before its fix: a NUL in a note was answered ok and then ended the
recorder ("VLEN strings do not support embedded NULLs"); a request with ``op`` twice ran the
last one; ``daq ctl status`` crashed on a null ``gamma_se``; ``daq compare --rig my-rig.toml``
refused the very rig file ``daq model init my-rig.toml`` had made the model from.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest

from daq.cli.daemon import format_status
from daq.config import load_rig
from daq.daemon.control import ControlServer
from daq.errors import InputError
from daq.io.runfile import RunWriter, WriterCfg
from daq.io.stream_format import BusEvent
from daq.models.fit.session import Session
from daq.models.spec import load_model
from daq.streaming.recorder import Recorder, RecorderCfg

ROOT = Path(__file__).resolve().parent.parent


def _server() -> tuple[ControlServer, list[dict]]:
    """A control server (never started: handle() is what every transport calls) that records what ran."""
    ran: list[dict] = []

    def note(args: dict) -> dict:
        ran.append({"note": args})
        return {"noted": args["text"]}

    def estop(args: dict) -> dict:
        ran.append({"estop": args})
        return {"estop": True}

    return ControlServer({"note": note, "estop": estop, "status": lambda a: {"ok": 1}}), ran


# ----------------------------------------------------------------------------- item 1: text HDF5 cannot store


@pytest.mark.parametrize("text", ["pad\u0000 ok", "\u0000"])
def test_a_note_with_a_nul_is_refused_naming_the_field_and_never_reaches_a_handler(text):
    server, ran = _server()
    reply = server.handle(json.dumps({"op": "note", "args": {"text": text}, "id": "n1"}).encode(), "operator")
    assert not reply.ok and reply.code == "malformed" and reply.id == "n1", reply
    assert "args.text" in reply.error and "NUL" in reply.error and "\n" not in reply.error
    assert ran == []


@pytest.mark.parametrize("raw", [
    '{"op": "status", "op": "estop", "args": {}, "id": "d1"}',
    '{"op": "note", "args": {"text": "a", "text": "b"}, "id": "d1"}',
    '{"op": "estop", "args": {}, "id": "d0", "id": "d1"}',
])
def test_a_request_with_a_key_twice_is_refused_not_last_wins(raw):
    server, ran = _server()
    reply = server.handle(raw.encode(), "observer" if '"status"' in raw else "operator")
    assert not reply.ok and reply.code == "malformed", reply
    assert "duplicate key" in reply.error and "\n" not in reply.error
    assert ran == []  # before: the observer's status request ran as an e-stop


def test_a_nul_that_reaches_the_recorder_from_elsewhere_does_not_end_the_recording(tmp_path):
    """The control API refuses a NUL; any other source (a driver's text, an old client) is made storable."""
    w = RunWriter(WriterCfg(flush_s=0.01))
    rec = Recorder(w, RecorderCfg(endpoint="tcp://127.0.0.1:1"))
    try:
        w.open(tmp_path / "nul.h5", load_rig("brake-2dof"))
        rec._handle(BusEvent(kind="note\u0000x", source="op\u0000", host_time=time.monotonic(),
                             detail="pad\u0000 ok"))
        w.note("after", "still recording")
        w.flush()
        w.close()
    finally:
        rec.close()
    with h5py.File(tmp_path / "nul.h5", "r") as f:
        ev = f["events"][()]
        details = [d.decode() if isinstance(d, bytes) else d for d in ev["detail"]]
    assert "pad\\x00 ok" in details and "still recording" in details


# ----------------------------------------------------------------------------- item 2: status text and nulls


def _status(**over) -> dict:
    st = {"rig": "brake-2dof", "sim": True, "pid": 7, "uptime_s": 3.0, "bus": "tcp://x",
          "belt": {"measured": None, "age_s": None, "setpoint": None, "commanded": None, "regulator": None},
          "streams": {"motor": {"rate_hz": None, "samples": None, "blocks": None}},
          "sources": {"can": {"state": None, "lost_frames": None, "checksum_errors": None, "reconnects": None}},
          "drops": {"bus_queue": None},
          "estimator": {"pid": 8, "alive": True, "blocks_per_s": None, "lost_blocks": None, "gaps": None,
                        "cycles": None, "last": {"F_est": None, "mu_est": None, "v_rel": None, "t": 1.0},
                        "fit": {"mu_s": 0.5, "gamma": 2.0, "gamma_se": None, "t": 1.0}},
          "recording": None, "ramp": {"state": "aborted", "fraction": None, "t": None, "duration": None,
                                      "commanded": None, "measured": None, "reason": None},
          "motion": {"allowed": False, "refused_because": "..."},
          "regulator": {"state": "WATCHDOG", "latched": True, "watchdog_trips": None, "read_at": None},
          "last_session": None, "recording_failure": None}
    st.update(over)
    return st


def test_status_text_shows_null_fields_as_a_dash_instead_of_crashing():
    text = format_status(_status())  # before: TypeError: unsupported format string passed to NoneType.__format__
    assert "gamma_se -" in text and "mu_s 0.5" in text and "regulator WATCHDOG LATCHED" in text
    assert "ramp      aborted" in text


def test_ctl_status_never_prints_a_traceback_on_a_reply_it_cannot_show(monkeypatch, capsys):
    """Whatever a daemon (or an older one) sends, the operator gets one line, not a traceback."""
    import daq.cli.daemon as cli

    monkeypatch.setattr(cli, "_call", lambda a, op, client=None, **kw: {"rig": "x"})  # no pid, no uptime
    args = type("A", (), {"json": False, "endpoint": "tcp://127.0.0.1:1", "timeout": 1.0})()
    assert cli.cmd_ctl_status(args) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and err.startswith("daq ctl: ")


# ----------------------------------------------------------------------------- item 6: the model's own rig file


def test_compare_accepts_the_rig_file_the_model_was_made_from(tmp_path, monkeypatch):
    def daq(*args: str) -> None:
        r = subprocess.run([sys.executable, "-m", "daq.cli", *args], cwd=tmp_path, capture_output=True, text=True,
                           timeout=120, check=False)
        assert r.returncode == 0, r.stderr

    daq("rig", "init", "belt-ndof", "-o", "my-rig.toml")
    daq("model", "init", "my-rig.toml", "-o", "m.toml")
    model = load_model(tmp_path / "m.toml")
    missing = tmp_path / "run.h5"
    for rig in ("my-rig.toml", str(tmp_path / "my-rig.toml"), "belt-ndof"):
        monkeypatch.chdir(tmp_path)  # as the user typed it, in the folder of the files
        with pytest.raises(InputError) as exc:  # the data file is missing: that, and only that, is the error
            Session.open(missing, model, rig)
        assert exc.value.field != "--rig", str(exc.value)
    with pytest.raises(InputError, match="the model is for belt-ndof"):
        Session.open(missing, model, "brake-2dof")


# ----------------------------------------------------------------------------- item 5: one daemon per rig


def test_real_instruments_are_locked_per_rig_and_per_endpoint_whatever_the_data_dir(tmp_path, monkeypatch):
    from daq.daemon.rig_lock import LOCK_DIR_ENV, RigBusy, RigLocks, lock_keys

    monkeypatch.setenv(LOCK_DIR_ENV, str(tmp_path / "locks"))
    rig = load_rig("brake-2dof")
    keys = lock_keys(rig, sim=False, endpoints=["tcp://127.0.0.1:5570", "tcp://127.0.0.1:0"])
    assert f"rig {rig.rig}" in keys and "socket tcp://127.0.0.1:5570" in keys
    assert not any(k.endswith(":0") for k in keys) and len(keys) > 2  # every instrument, no port-0 socket
    first = RigLocks(keys, "daemon pid 1 for rig brake-2dof (data dir /a)").acquire()
    try:
        with pytest.raises(RigBusy, match=r"in use by daemon pid 1 for rig brake-2dof \(data dir /a\)"):
            RigLocks(keys, "daemon pid 2 (data dir /b)").acquire()
        serial = next(k for k in keys if k.startswith("serial "))
        with pytest.raises(RigBusy, match="one daemon per rig"):  # another rig config naming the same port
            RigLocks([serial], "daemon pid 3").acquire()
    finally:
        first.release()
    RigLocks(keys, "daemon pid 4").acquire().release()  # released: free again
    assert lock_keys(rig, sim=True, endpoints=["tcp://127.0.0.1:0"]) == []  # a sim bench's ptys are its own
