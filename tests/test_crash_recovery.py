"""The operator is told the truth after a crash (issue 16): kill -9 of the daemon, the restart, the reset.

End to end: a real ``daq daemon --sim`` is killed -9 mid-ramp while recording (the regulator's
watchdog stops the belt and latches); a daemon restarted on the same rig reports the unclean
end and the latched regulator (it reattaches to the bench, which outlived the first daemon),
refuses motion, and moves again only after ``daq ctl reset``. Module-scoped fixtures, so the
killed daemon's bench is the restarted daemon's, and both end with this module.

Below them, fast tests of the pieces: the session state file and its lock, the status text,
and the ramp runner's commanded speed after a stop.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import h5py
import pytest
from helpers import SHORT, DaemonProc, event_kinds, wait_for, wait_gone

from daq.cli.daemon import format_status
from daq.daemon.ramp_runner import RampRunner
from daq.daemon.session_state import (
    RecordingRef,
    SessionBusy,
    SessionFile,
    SessionKeeper,
    UncleanEnd,
    utcnow,
)
from drivers.motor import MotorDrive
from drivers.motor_protocol import Status

# ----------------------------------------------------------------------------- kill -9 of the daemon, restart


@dataclass
class Killed:
    d: DaemonProc
    pid: int
    children: list[int]
    recording: Path
    sim: dict
    stopped_s: float


@pytest.fixture(scope="module")
def killed(tmp_path_factory):
    """A daemon killed -9 at 0.15 m/s while recording; its bench (and the regulator's latch) lives on."""
    tmp = tmp_path_factory.mktemp("crash")
    d = DaemonProc(tmp)
    try:
        out = tmp / "killed.h5"
        d.run_long_ramp(out)
        st = d.status()
        children = [st["estimator"]["pid"], st["recording"]["pid"]]
        os.kill(d.proc.pid, signal.SIGKILL)
        t0 = time.monotonic()
        d.proc.wait(10)
        sim = wait_for(lambda: (s := d.sim())["belt_speed"] <= 1e-3 and s, 30, "the belt at rest")
        stopped_s = time.monotonic() - t0
        print(f"belt at rest {stopped_s:.2f} s after kill -9")  # 0.5 s watchdog + 0.3 s ramp at max_accel
    except BaseException:
        d.close()
        raise
    yield Killed(d, d.proc.pid, children, out, sim, stopped_s)
    d.close()


@pytest.fixture(scope="module")
def restarted(killed):
    d = DaemonProc(killed.d.tmp)  # same data dir (state file) and workdir (the bench)
    yield d
    d.close()


@pytest.mark.slow
def test_kill9_of_the_daemon_the_regulator_watchdog_stops_the_belt(killed):
    assert killed.sim["motor_state"] == "WATCHDOG" and killed.sim["watchdog_trips"] == 1
    assert killed.stopped_s < 10.0  # bounded by the watchdog, not by anything the dead daemon could do
    for pid in killed.children:  # estimator and recorder notice their parent is gone and exit
        assert wait_gone(pid, 30), pid
    with h5py.File(killed.recording) as f:  # the orphaned recorder closed its file cleanly
        assert "parent_gone" in event_kinds(f) and f["streams/laser_serial/x1"].size > 500
    state = SessionFile.model_validate_json((killed.d.data / ".daq-daemon" / "brake-2dof.session.json").read_text())
    assert state.state == "running" and state.pid == killed.pid and state.recording is not None


@pytest.mark.slow
def test_restart_after_kill9_reports_the_unclean_end_and_refuses_motion(killed, restarted):
    # stderr is read by its own thread, which a loaded machine may run after the ready line (stdout) was parsed
    wait_for(lambda: any("ended uncleanly" in line for line in restarted.err), 10, "the unclean-end warning")
    warning = [line for line in restarted.err if "ended uncleanly" in line]
    assert len(warning) == 1, restarted.err
    line = warning[0]
    for part in (f"daemon pid {killed.pid}", "WATCHDOG (latched)", "1 watchdog trip", str(killed.recording),
                 "daq ctl reset", "running ramp"):
        assert part in line, (part, line)
    st = restarted.status()
    assert st["sim_bench"]["attached"] and st["sim_bench"]["pid"] == killed.d.sim_pid  # the same regulator
    last = st["last_session"]
    assert last["pid"] == killed.pid and last["recording"]["path"] == str(killed.recording)
    assert "closed cleanly" in last["recording_outcome"] and last["regulator"]["state"] == "WATCHDOG"
    assert st["regulator"]["latched"] and st["regulator"]["watchdog_trips"] == 1
    assert not st["motion"]["allowed"] and "daq ctl reset" in st["motion"]["refused_because"]
    text = restarted.ctl("status").stdout
    assert "LAST SESSION ENDED UNCLEANLY" in text and "WATCHDOG LATCHED" in text and "REFUSED" in text
    ramp = restarted.tmp / "short.toml"
    ramp.write_text(SHORT)
    r = restarted.ctl("ramp", str(ramp), "--no-wait")
    assert r.returncode == 1 and "motion refused until `daq ctl reset`" in r.stderr and "ended uncleanly" in r.stderr
    time.sleep(0.3)
    sim = restarted.sim()
    assert sim["motor_state"] == "WATCHDOG" and sim["belt_speed"] == 0.0  # nothing reached the motor


@pytest.mark.slow
def test_reset_at_standstill_clears_the_latch_and_the_belt_moves_again(restarted):
    r = restarted.ctl("reset")
    assert r.returncode == 0, r.stderr
    assert "WATCHDOG -> DISABLED" in r.stdout and "ended uncleanly" in r.stdout
    st = restarted.status()
    assert st["motion"]["allowed"] and st["last_session"] is None and not st["regulator"]["latched"]
    ramp = restarted.tmp / "long.toml"
    assert restarted.ctl("ramp", str(ramp), "--no-wait").returncode == 0
    wait_for(lambda: restarted.sim()["belt_speed"] > 0.05, 30, "the belt moving")
    assert restarted.ctl("stop").returncode == 0
    state = json.loads((restarted.data / ".daq-daemon" / "brake-2dof.session.json").read_text())
    assert state["unclean_end"] is None  # acknowledged: the next start will not report it again


# ----------------------------------------------------------------------------- the pieces


def test_session_state_reports_an_unclean_end_until_reset_even_across_a_clean_session(tmp_path):
    first = SessionKeeper(tmp_path, "rig-a")
    first.acquire()
    assert first.previous is None and first.unclean_end(utcnow()) is None
    first.begin(utcnow(), None, None)
    first.update(recording=RecordingRef(path="/data/run.h5", recorder_pid=4242), ramp="seed.toml")
    with pytest.raises(SessionBusy, match="another daemon"):  # the lock is held: a second daemon is refused
        SessionKeeper(tmp_path, "rig-a").acquire()
    other = SessionKeeper(tmp_path, "rig-b")
    other.acquire()  # another rig is not
    other.release()
    first.release()  # as the kernel does when the process dies: no end_clean()

    second = SessionKeeper(tmp_path, "rig-a")
    second.acquire()
    end = second.unclean_end(utcnow())
    assert isinstance(end, UncleanEnd) and end.pid == os.getpid() and end.ramp == "seed.toml"
    assert end.recording.path == "/data/run.h5" and "ended uncleanly" in end.summary()
    second.begin(utcnow(), None, end)
    second.end_clean()  # an orderly session that never reset

    third = SessionKeeper(tmp_path, "rig-a")
    third.acquire()
    assert third.previous.state == "clean" and third.unclean_end(utcnow()) == end  # still reported
    third.begin(utcnow(), None, end)
    third.update(unclean_end=None)  # what `daq ctl reset` does
    third.end_clean()
    fourth = SessionKeeper(tmp_path, "rig-a")
    fourth.acquire()
    assert fourth.unclean_end(utcnow()) is None
    fourth.release()


def test_an_unreadable_state_file_is_reported_not_trusted(tmp_path):
    (tmp_path / "rig-a.session.json").write_text('{"state": "runn')
    k = SessionKeeper(tmp_path, "rig-a")
    k.acquire()
    end = k.unclean_end(utcnow())
    assert end is not None and "unreadable" in end.note and "end is unknown" in end.summary()
    k.release()


def test_status_text_says_what_ended_and_never_shows_a_dead_recorder_as_recording():
    t = _dt.datetime(2026, 11, 25, 8, 0, tzinfo=_dt.timezone.utc).isoformat()
    st = {"rig": "brake-2dof", "sim": True, "pid": 7, "uptime_s": 3.0, "bus": "tcp://x",
          "belt": {"measured": 0.0001, "age_s": 0.01, "setpoint": 0.0, "commanded": 0.0, "regulator": "connected"},
          "streams": {}, "sources": {}, "drops": {}, "estimator": None, "recording": None, "ramp": None,
          "motion": {"allowed": False, "refused_because": "..."},
          "regulator": {"state": "WATCHDOG", "latched": True, "watchdog_trips": 1, "read_at": t},
          "last_session": {"pid": 5, "last_alive_at": t, "recording": {"path": "/d/a.h5", "recorder_pid": 6},
                           "recording_outcome": "closed cleanly; opens with plain h5py", "ramp": "long.toml",
                           "note": ""},
          "recording_failure": {"pid": 9, "path": "/d/b.h5", "exit": "killed by SIGKILL", "ended_at": t,
                                "recovery": "recovered in 1 ms"}}
    text = format_status(st)
    assert "LAST SESSION ENDED UNCLEANLY: daemon pid 5" in text and "/d/a.h5" in text and "long.toml" in text
    assert "regulator WATCHDOG LATCHED, 1 watchdog trip(s)" in text and "motion    REFUSED" in text
    assert "recording ENDED UNEXPECTEDLY" in text and "SIGKILL" in text and "recording off" in text
    assert "commanded 0.0000 m/s" in text


class _Motor(MotorDrive):
    """Just enough regulator for the runner: set points are followed at once."""

    def __init__(self) -> None:
        self.v = self.set = 0.0
        self.lock = threading.Lock()

    def enable(self) -> None: ...
    def disable(self) -> None: ...
    def set_accel(self, a: float) -> None: ...
    def reset(self) -> None: ...

    def set_speed(self, v: float) -> None:
        self.v = self.set = v

    def read_speed(self) -> tuple[float, float]:
        return self.v, self.set

    def stop(self) -> None:
        self.set = 0.0

    def estop(self) -> None:
        self.set = 0.0

    def status(self) -> Status:
        return Status("RUNNING", self.v, self.set, 500, 0.3, 0.5)


@pytest.mark.parametrize("how", ["stop", "estop"])
def test_runner_commands_0_after_a_stop_not_the_programme_speed(how):
    r = RampRunner(_Motor(), [0.0, 0.3, 60.0], [0.0, 0.15, 0.15], max_speed=0.3, max_accel=0.5).start()
    wait_for(lambda: r.progress().commanded > 0.05, 10, "the ramp under way")
    getattr(r, how)()
    assert r.join(5)
    p = r.progress()
    assert p.state == ("stopped" if how == "stop" else "estopped") and p.commanded == 0.0
