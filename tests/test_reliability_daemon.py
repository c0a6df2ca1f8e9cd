"""Issue 29 against a real ``daq daemon --sim``: status that tells a watchdog trip at once, one daemon per rig.

The trip is provoked as the crash tests do it, by silencing the daemon's heartbeat, but with the
daemon alive: SIGSTOP for 1.2 s (the regulator's watchdog is 500 ms), then SIGCONT, as a 0.46 s
stall did in the issue. Before the fix status said DISABLED, 0 trips and motion allowed for as
long as the daemon lived, nothing reached stderr, and the ``watchdog`` event was written only at
``reset``. A second daemon for the same rig with another ``--data-dir`` started its own bench and
died with a 17-line ``ZMQError: Address already in use`` traceback.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import h5py
import pytest
from helpers import LONG, ROOT, DaemonProc, event_kinds, free_port, wait_for

from daq.daemon.control import ControlClient

pytestmark = pytest.mark.slow  # every test here starts a real daemon


def test_a_watchdog_trip_while_the_daemon_lives_is_in_status_stderr_and_the_events_within_1_s(tmp_path):
    d = DaemonProc(tmp_path)
    try:
        out = tmp_path / "trip.h5"
        d.run_long_ramp(out)
        with ControlClient(d.endpoint, timeout_s=10.0) as c:
            os.kill(d.proc.pid, signal.SIGSTOP)  # no heartbeat: the regulator's watchdog stops the belt
            try:
                wait_for(lambda: d.sim()["motor_state"] == "WATCHDOG", 10, "the watchdog to trip")
                time.sleep(0.2)
            finally:
                os.kill(d.proc.pid, signal.SIGCONT)
            t_cont = time.monotonic()
            st = wait_for(lambda: (r := c.request("status").result)["regulator"]["latched"] and r, 5,
                          "status to say the regulator latched")
            status_s = time.monotonic() - t_cont
            line = wait_for(lambda: next((x for x in d.err if "WATCHDOG" in x), None), 5, "a stderr line")
            stderr_s = time.monotonic() - t_cont
            reg = st["regulator"]
            assert reg["state"] == "WATCHDOG" and reg["watchdog_trips"] == 1
            assert not st["motion"]["allowed"] and "reset" in st["motion"]["refused_because"]
            ramp = tmp_path / "long.toml"
            refused = c.request("ramp", file=str(ramp))  # motion refused at once
            assert not refused.ok and "latched in WATCHDOG" in refused.error, refused
            assert c.request("record_stop").ok
        with h5py.File(out, "r") as f:
            kinds = event_kinds(f)
            t_event = float(f["events"]["host_time"][kinds.index("watchdog")])
        event_s = t_event - t_cont
        print(f"after SIGCONT: status {status_s:.2f} s, stderr {stderr_s:.2f} s, event {event_s:.2f} s")
        assert status_s < 1.0 and stderr_s < 1.0 and event_s < 1.0
        assert line.count("\n") == 1 and "daq ctl reset" in line and "Traceback" not in "".join(d.err)
        assert kinds.count("watchdog") == 1  # once, not once per poll
        assert d.ctl("reset").returncode == 0
        ramp.write_text(LONG)
        assert d.ctl("ramp", str(ramp), "--no-wait").returncode == 0  # after reset the belt moves again
        wait_for(lambda: d.sim()["belt_speed"] > 0.05, 30, "the belt moving")
        assert d.ctl("stop").returncode == 0
    finally:
        d.close()


def test_a_second_daemon_for_the_same_rig_with_another_data_dir_is_refused_in_one_line(tmp_path):
    control, bus = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    first = DaemonProc(tmp_path / "a", "--control", control, "--bus", bus)
    try:
        t0 = time.monotonic()
        r = subprocess.run([sys.executable, "-m", "daq.cli", "daemon", "--rig", "brake-2dof", "--sim",
                            "--data-dir", str(tmp_path / "b" / "data"), "--control", control, "--bus", bus,
                            "--workdir", str(tmp_path / "b" / "dev")],
                           cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)
        took = time.monotonic() - t0
        print(f"second daemon: exit {r.returncode} after {took:.1f} s: {r.stderr.strip()}")
        assert r.returncode == 1, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in r.stderr and "ZMQError" not in r.stderr, r.stderr
        assert "brake-2dof" in lines[0] and f"pid {first.proc.pid}" in lines[0], lines[0]
        assert not (tmp_path / "b" / "dev").exists()  # refused before it started a bench of its own
        # the first goes on (its rate is measured over its first seconds: 0.0 when read 0.8 s after its start)
        wait_for(lambda: first.status()["streams"]["motor"]["rate_hz"] > 50, 15, "the first daemon's motor at rate")
    finally:
        first.close()
