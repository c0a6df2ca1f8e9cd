"""The daemon end to end through its command line and control socket, against a simulated bench.

Each daemon here is a real ``daq daemon --sim`` process: the simulated bench runs in its own
process (it outlives the daemon), the estimator and the recorder in theirs. Waits are
event-based (ready lines, status polls) with generous timeouts; no assertion depends on
how fast this machine is, except the watchdog bound, which is seconds wide.
"""

from __future__ import annotations

import json
import os
import signal
import time

import h5py
import numpy as np
import pytest
import zmq
from helpers import SHORT, TOO_FAST, DaemonProc, daq_process, event_kinds, wait_for, wait_gone

from daq.config import load_rig
from daq.daemon.control import FORBIDDEN, ControlClient, Reply

pytestmark = pytest.mark.slow  # every test here runs against a real daemon


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = DaemonProc(tmp_path_factory.mktemp("e2e"))
    yield d
    d.close()


# ----------------------------------------------------------------------------- a ramp, recorded


def test_record_start_in_a_folder_that_cannot_be_written_is_one_input_error(daemon):
    """Issue 16: it was answered 'failed' with a raw FileNotFoundError (or the recorder died later)."""
    for bad in ("/proc/self/run.h5", "/proc/no-such/run.h5"):
        r = daemon.ctl("record", "start", "--path", bad)
        assert r.returncode == 2, r.stdout + r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"daq: error: {bad}: path: cannot write in "), r.stderr
    r = daemon.ctl("status", "--json")  # (the other tests read status over the socket: DaemonProc.status)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["recording"] is None  # nothing started, nothing left half-open


def test_ctl_ramp_runs_and_the_recording_holds_every_channel_and_the_estimator(daemon):
    ramp = daemon.tmp / "short.toml"
    ramp.write_text(SHORT)
    out = daemon.tmp / "run.h5"
    r = daemon.ctl("record", "start", "--path", str(out))
    assert r.returncode == 0, r.stderr
    r = daemon.ctl("ramp", str(ramp))
    assert r.returncode == 0, r.stderr + r.stdout
    assert "finished" in r.stdout and "running" in r.stdout  # progress shown until the end
    assert daemon.ctl("note", "pad", "conditioned").returncode == 0
    st = daemon.status()
    assert st["ramp"]["state"] == "finished" and st["estimator"]["alive"]
    assert st["estimator"]["blocks_per_s"] > 50  # its own process keeps up with the ~100 blocks/s laser stream
    assert st["recording"]["path"] == str(out)
    r = daemon.ctl("record", "stop")
    assert r.returncode == 0, r.stderr
    rig = load_rig("brake-2dof")
    with h5py.File(out) as f:  # closed cleanly: a plain open works
        streams = f["streams"]
        channels = {c for s in streams.values() for c in s.keys()} - {"t", "device_t"}
        assert set(rig.channels) <= channels, set(rig.channels) - channels  # every channel of the rig
        kinds = event_kinds(f)
        for bad in ("lost_frames", "lost_blocks", "gap", "disconnected", "rejected", "stop_truncated"):
            assert bad not in kinds, bad  # nothing that would explain (or hide) a gap
        laser = streams["laser_serial"]
        dev, rate = laser["device_t"][()], laser.attrs["rate_hz"]
        assert dev.size > 2000 and np.max(np.diff(dev)) < 1.5 / rate  # not one laser frame missing
        for name in ("laser_serial", "motor", "thermocouple", "estimator"):
            t = streams[name]["t"][()]
            assert t.size > 10 and np.all(np.diff(t) >= 0) and np.max(np.diff(t)) < 1.0, name  # steady, in order
        f_est = streams["estimator/F_est"][()]
        assert f_est.size > 1000 and np.isfinite(f_est).mean() > 0.9  # the estimator's output is in the file
        vb_set, vb = streams["motor/vb_set"][()], streams["motor/vb"][()]
        assert np.max(vb_set) == pytest.approx(0.15, abs=1e-4) and np.max(vb) > 0.14
        assert kinds.count("ramp_segment") >= 6 and "ramp_finished" in kinds and "note" in kinds


def test_record_rotate_starts_the_next_file_before_the_last_one_closes(daemon):
    """Make before break (handlers.handle_record_rotate): the second file's recorder is up before the first one
    stops, so the two files overlap and no laser frame falls between them; both close cleanly and say so. With
    nothing recording there is nothing to rotate, and a rotation to a bad path is refused with the first file
    still recording: nothing started, nothing lost."""
    r = daemon.ctl("record", "rotate", "--path", str(daemon.tmp / "none.h5"))
    assert r.returncode != 0 and "not recording" in r.stderr + r.stdout, r.stderr + r.stdout
    assert not (daemon.tmp / "none.h5").exists() and daemon.status()["recording"] is None
    first, second = daemon.tmp / "rot-1.h5", daemon.tmp / "rot-2.h5"
    assert daemon.ctl("record", "start", "--path", str(first)).returncode == 0
    r = daemon.ctl("record", "rotate", "--path", "/proc/self/run.h5")  # a rotation that fails loses nothing
    assert r.returncode == 2 and "cannot write in" in r.stderr, r.stderr
    assert daemon.status()["recording"]["path"] == str(first)
    time.sleep(1.0)
    r = daemon.ctl("record", "rotate", "--path", str(second))
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"recording to {second}; closed {first}"
    assert daemon.status()["recording"]["path"] == str(second)
    time.sleep(1.0)
    assert daemon.ctl("record", "stop").returncode == 0
    with h5py.File(first) as a, h5py.File(second) as b:  # both closed cleanly: a plain open works
        assert event_kinds(a)[-1] == "stop" and event_kinds(b)[-1] == "stop"
        assert "record_rotate" in event_kinds(a) and "record_rotate" in event_kinds(b)
        ta, tb = a["streams/laser_serial/device_t"][()], b["streams/laser_serial/device_t"][()]
        rate = a["streams/laser_serial"].attrs["rate_hz"]
        assert tb[0] < ta[-1]  # they overlap...
        joined = np.union1d(ta, tb)  # ...and together miss no frame
        assert np.max(np.diff(joined)) < 1.5 / rate


def test_ramp_beyond_limits_is_refused_before_motion(daemon):
    ramp = daemon.tmp / "fast.toml"
    ramp.write_text(TOO_FAST)
    before = daemon.sim()
    r = daemon.ctl("ramp", str(ramp))
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and str(ramp) in r.stderr and "acceleration" in r.stderr
    time.sleep(0.5)
    after = daemon.sim()
    assert after["belt_speed"] == 0.0 and after["setpoint"] == 0.0 and after["target"] == 0.0
    assert after["motor_state"] == before["motor_state"] != "RUNNING"  # the regulator was never enabled


def test_bad_ctl_input_exits_2_naming_the_file(daemon):
    r = daemon.ctl("ramp", str(daemon.tmp / "missing.toml"))
    assert r.returncode == 2 and "missing.toml" in r.stderr and r.stderr.count("\n") == 1
    bad = daemon.tmp / "bad.toml"
    bad.write_text('[[segment]]\nkind = "warp"\n')
    r = daemon.ctl("ramp", str(bad))
    assert r.returncode == 2 and "bad.toml" in r.stderr and "kind" in r.stderr


def test_malformed_requests_get_error_replies_and_the_daemon_keeps_running(daemon):
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(daemon.endpoint)
    try:
        for payload, expect in ((b"\x00\xff garbage", "not JSON"), (b"[]", "JSON object"),
                                (json.dumps({"op": "launch", "args": {}, "id": "1"}).encode(), "op"),
                                (json.dumps({"op": "ramp", "args": {"file": 5}, "id": "2"}).encode(), "args.file"),
                                (json.dumps({"op": "note", "args": {"text": ["x"]}, "id": "3"}).encode(), "args.text"),
                                (json.dumps({"op": "status", "args": {}, "id": 4}).encode(), "id")):
            sock.send(payload)
            assert sock.poll(30_000), payload
            reply = Reply.model_validate_json(sock.recv())
            assert not reply.ok and reply.code == "malformed" and expect in reply.error, (payload, reply)
    finally:
        sock.close()
    st = daemon.status()  # still answering, still acquiring
    assert st["streams"]["laser_serial"]["rate_hz"] > 500 and st["estimator"]["alive"]


def test_status_text_shows_streams_rates_drops_belt_and_estimator(daemon):
    r = daemon.ctl("status")
    assert r.returncode == 0, r.stderr
    for word in ("laser_serial", "samples/s", "drops", "belt", "measured", "estimator", "F_est"):
        assert word in r.stdout, word


# ----------------------------------------------------------------------------- faults
# kill -9 of the daemon, and the restart after it: tests/test_crash_recovery.py


def test_kill9_of_the_recorder_status_says_so_the_file_opens_and_a_new_recording_starts(daemon):
    out = daemon.tmp / "crashed.h5"
    assert daemon.ctl("record", "start", "--path", str(out)).returncode == 0
    time.sleep(1.0)  # a few flushes reach the file
    pid = daemon.status()["recording"]["pid"]
    with ControlClient(daemon.endpoint, timeout_s=10.0) as c:
        os.kill(pid, signal.SIGKILL)
        t0 = time.monotonic()
        st = wait_for(lambda: (r := c.request("status").result)["recording_failure"] and
                      r["recording_failure"]["recovered"] and r, 10, "status to report the dead recorder")
        said_s = time.monotonic() - t0
    print(f"status reported the dead recorder {said_s:.2f} s after kill -9, file recovered in "
          f"{1000 * st['recording_failure']['recovery_s']:.1f} ms")
    assert said_s < 2.0
    fail = st["recording_failure"]
    assert (fail["pid"], fail["path"], fail["exit"], fail["returncode"]) == (pid, str(out), "killed by SIGKILL", -9)
    assert st["recording"] is None
    text = daemon.ctl("status").stdout
    assert "recording ENDED UNEXPECTEDLY" in text and "SIGKILL" in text and "recovered" in text
    assert f"(pid {pid})" not in text and "recording off" in text
    with h5py.File(out, "r") as f:  # a plain open, as MATLAB's would be: no recover() by hand
        assert f["streams/laser_serial/x1"].size > 100 and "start" in event_kinds(f)
    after = daemon.tmp / "after-crash.h5"
    r = daemon.ctl("record", "start", "--path", str(after))
    assert r.returncode == 0, r.stderr
    st = daemon.status()
    assert st["recording"]["alive"] and st["recording_failure"] is None
    assert daemon.ctl("record", "stop").returncode == 0
    with h5py.File(after) as f:  # the new run keeps the record of the lost one
        assert "previous_recording_lost" in event_kinds(f)


def test_after_stop_status_commands_0_and_measures_the_belt_at_rest(daemon):
    daemon.run_long_ramp()
    assert daemon.status()["belt"]["commanded"] == pytest.approx(0.15)
    assert daemon.ctl("stop").returncode == 0
    st = wait_for(lambda: abs((s := daemon.status())["belt"]["measured"]) < 2e-3 and s, 30, "the belt at rest")
    belt, ramp_st = st["belt"], st["ramp"]
    assert ramp_st["state"] == "stopped" and ramp_st["commanded"] == 0.0 and belt["commanded"] == 0.0
    assert belt["setpoint"] == 0.0 and ramp_st["measured"] == belt["measured"] and belt["age_s"] < 1.0
    text = daemon.ctl("status").stdout
    assert "commanded 0.1500" not in text and "commanded 0.0000 m/s" in text


def test_sigterm_ramps_down_exits_0_and_closes_the_recording(tmp_path):
    d = DaemonProc(tmp_path)
    try:
        out = tmp_path / "term.h5"
        d.run_long_ramp(out)
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(60) == 0
        assert any("controlled ramp-down" in line for line in d.rest)
        assert wait_gone(d.sim_pid, 30)  # a clean shutdown also ends the bench it started (at rest)
        with h5py.File(out) as f:  # closed and readable
            kinds = event_kinds(f)
            vb = f["streams/motor/vb"][()]
        assert "ramp_stopped" in kinds and kinds[-1] == "stop" and "watchdog" not in kinds
        assert vb.max() > 0.14 and abs(vb[-1]) < 5e-3  # the ramp-down is in the file, down to rest
    finally:
        d.close()


# ----------------------------------------------------------------------------- CURVE


def test_curve_socket_no_keys_refused_observer_reads_operator_commands(tmp_path):
    keys = tmp_path / "keys"
    r = daq_process("ctl", "keygen", str(keys), "--operator", "alice", "--observer", "olga")
    assert r.returncode == 0, r.stderr
    d = DaemonProc(tmp_path, "--keys", str(keys))  # CURVE forced on loopback
    try:
        with ControlClient(d.endpoint, timeout_s=1.5) as c, pytest.raises(TimeoutError):
            c.request("stop")  # no keys: the handshake fails, nothing reaches a handler
        with ControlClient(d.endpoint, timeout_s=1.5) as c:
            time.sleep(1.0)  # the handshake fails before the first send: the send must not block forever
            t0 = time.monotonic()
            with pytest.raises(TimeoutError):
                c.request("status")
            assert time.monotonic() - t0 < 5.0
        r = d.ctl("--timeout", "1.5", "status")  # ctl without keys: no answer, exit 1
        assert r.returncode == 1 and "no reply" in r.stderr
        olga = str(keys / "clients" / "olga")
        r = daq_process("ctl", "--endpoint", d.endpoint, "--keys", olga, "status", "--json")
        assert r.returncode == 0 and json.loads(r.stdout)["rig"] == "brake-2dof"
        ramp = tmp_path / "short.toml"
        ramp.write_text(SHORT)
        for args in (("ramp", str(ramp)), ("stop",), ("estop",), ("record", "start")):
            r = daq_process("ctl", "--endpoint", d.endpoint, "--keys", olga, *args)
            assert r.returncode == 1 and FORBIDDEN in r.stderr, args
        assert d.sim()["motor_state"] == "DISABLED"  # the observer's ramp never reached the motor
        r = daq_process("ctl", "--endpoint", d.endpoint, "--keys", str(keys / "clients" / "alice"), "stop")
        assert r.returncode == 0 and json.loads(r.stdout) == {"stopping": True}
    finally:
        d.close()
