"""The daemon's parts, each on its own and without a daemon: daq/daemon/children.py, motion.py, recording.py,
status.py, handlers.py and daq/streaming/child_process.py (record 38). Fast: fakes for the motor and the daemon,
and at most a ``sleep`` child process."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from daq.daemon.children import RecorderProcess, first_line
from daq.daemon.handlers import ControlHandlers
from daq.daemon.motion import MotionGuard
from daq.daemon.recording import RecordingSlot, run_file_path
from daq.daemon.session_state import MotionRefused, RegulatorReading, UncleanEnd, utcnow
from daq.daemon.status import StreamRates, belt, daemon_status
from daq.errors import InputError
from daq.streaming.child_process import pid_alive, terminate
from drivers.motor_protocol import Status

ROOT = Path(__file__).resolve().parent.parent


# ----------------------------------------------------------------------------- child processes


def _python(code: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", code], **kw)


def test_terminate_ends_a_child_by_sigterm_and_one_that_ignores_it_by_sigkill():
    polite = _python("import time; time.sleep(60)")
    assert terminate(polite, 10) == -15 and not pid_alive(polite.pid)
    deaf = _python("import signal, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('x', flush=True); "
                   "time.sleep(60)", stdout=subprocess.PIPE, text=True)
    deaf.stdout.readline()  # its handler is set
    t0 = time.monotonic()
    assert terminate(deaf, 0.3) == -9 and time.monotonic() - t0 < 5
    assert terminate(deaf, 0.3) == -9  # an ended child: its status, nothing sent
    deaf.stdout.close()


def test_a_child_that_says_nothing_is_killed_and_named():
    silent = _python("import time; time.sleep(60)", stdout=subprocess.PIPE, text=True)
    with pytest.raises(RuntimeError, match="the test child did not start within 0.3 s"):
        first_line(silent, 0.3, "the test child")
    silent.wait(5)
    silent.stdout.close()
    talker = _python("print('ready here')", stdout=subprocess.PIPE, text=True)
    assert first_line(talker, 10, "talker") == "ready here"
    talker.wait(5)
    talker.stdout.close()


def test_the_recorders_lost_blocks_come_from_its_last_progress_line():
    rec = object.__new__(RecorderProcess)  # no process: only the parsing
    rec.progress = "recorder:    12.0 s   1,000 samples written  0.01 M/s  lost blocks 3  malformed 0  rejected 0"
    assert rec.lost_blocks() == 3
    rec.progress = ""
    assert rec.lost_blocks() is None


def test_the_daemon_module_does_not_load_the_simulator():
    code = "import sys, daq.daemon.service; print(sorted(m for m in sys.modules if m.startswith(('sim_backends', 'daq.sim'))))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


# ----------------------------------------------------------------------------- motion


class FakeMotor:
    def __init__(self, state: str = "DISABLED", measured: float = 0.0) -> None:
        self.state, self.measured, self.calls = state, measured, []
        self.unreadable = False

    def status(self) -> Status:
        if self.unreadable:
            raise TimeoutError("no reply to STAT?")
        return Status(self.state, self.measured, 0.0, 500, 1.0, 1.0)

    def read_speed(self) -> tuple[float, float]:
        return self.measured, 0.0

    def reset(self) -> None:
        self.calls.append("reset")
        self.state = "DISABLED"

    def stop(self) -> None:
        self.calls.append("stop")

    def estop(self) -> None:
        self.calls.append("estop")
        self.state = "ESTOP"


class FakeBench:
    def __init__(self, trips: int | None) -> None:
        self.trips = trips

    def watchdog_trips(self) -> int | None:
        return self.trips


def _guard(motor: FakeMotor, bench=None) -> tuple[MotionGuard, list[tuple[str, str, str]]]:
    events: list[tuple[str, str, str]] = []
    g = MotionGuard()
    g.attach(motor, bench, lambda *ev: events.append(ev))
    return g, events


def _unclean() -> UncleanEnd:
    now = utcnow()
    return UncleanEnd(pid=1, started_at=now, last_alive_at=now, found_at=now, found_by_pid=2)


def test_motion_is_refused_after_an_unclean_end_and_while_the_regulator_is_latched():
    motor = FakeMotor()
    g, _ = _guard(motor)
    assert g.refusal(read=True) is None
    g.unclean = _unclean()
    assert "until `daq ctl reset`" in g.refusal()
    g.unclean = None
    motor.state = "WATCHDOG"
    assert g.refusal() is None  # as last read
    assert "latched in WATCHDOG" in g.refusal(read=True)


def test_a_latch_while_running_is_reported_once_with_the_benchs_trip_count(capsys):
    motor = FakeMotor("RUNNING", 0.1)
    g, events = _guard(motor, FakeBench(1))
    g.read_regulator()
    motor.state = "WATCHDOG"
    g.poll()
    g.poll()
    assert [e[0] for e in events] == ["watchdog"] and "1 watchdog trip(s)" in events[0][2]
    assert g.regulator.latched and "motion refused" in capsys.readouterr().err


def test_our_own_estop_is_no_news_and_an_unreadable_regulator_is_an_answer():
    motor = FakeMotor("RUNNING")
    g, events = _guard(motor)
    g.read_regulator()
    g.halted = True
    motor.state = "ESTOP"
    g.poll()
    assert events == [] and g.regulator.latched
    motor.unreadable = True
    g.poll()  # no reading: the state stays as last read
    assert g.regulator.state == "ESTOP"
    assert g.read_regulator().error == "TimeoutError: no reply to STAT?"


class SlowFirstAnswer(FakeMotor):
    """A regulator whose next answer is held on the wire until released (a loaded line): it answers the state it
    had when asked."""

    def __init__(self, state: str) -> None:
        super().__init__(state)
        self.asked, self.release = threading.Event(), threading.Event()

    def status(self) -> Status:
        answer = super().status()
        if not self.asked.is_set():
            self.asked.set()
            self.release.wait(5)
        return answer


def test_a_poll_answered_late_does_not_overwrite_the_e_stops_own_reading():
    """The watch asks (RUNNING), the operator's e-stop latches the regulator and its handler reads it, then the
    watch's answer arrives: status must end latched. Without one read at a time it ended RUNNING."""
    motor = SlowFirstAnswer("RUNNING")
    g, _ = _guard(motor)
    g.halted = True
    watch = threading.Thread(target=g.poll)
    watch.start()
    assert motor.asked.wait(5)
    motor.estop()
    handler = threading.Thread(target=g.read_regulator)
    handler.start()
    time.sleep(0.2)  # the handler waits for the watch's exchange to end (or, unguarded, reads ESTOP now)
    motor.release.set()
    watch.join(5)
    handler.join(5)
    assert g.regulator.state == "ESTOP" and g.regulator.latched


def test_the_watch_ends_when_told():
    g, _ = _guard(FakeMotor())
    stop = threading.Event()
    th = threading.Thread(target=g.watch, args=(stop,))
    th.start()
    stop.set()
    th.join(2)
    assert not th.is_alive()


# ----------------------------------------------------------------------------- the recording slot


def test_a_run_files_path_is_checked_before_a_recorder_starts(tmp_path):
    path = run_file_path(None, tmp_path / "data", "rig-a")
    assert path.parent == tmp_path / "data" and path.name.startswith("rig-a-") and path.suffix == ".h5"
    (tmp_path / "x.h5").write_bytes(b"")
    with pytest.raises(InputError, match="never overwritten"):
        run_file_path(str(tmp_path / "x.h5"), tmp_path, "rig-a")
    with pytest.raises(InputError, match=r"\.h5 or \.hdf5"):
        run_file_path(str(tmp_path / "x.txt"), tmp_path, "rig-a")


def test_the_slot_holds_one_recorder_and_forgets_nothing_it_did_not_stop():
    events, gone = [], []
    slot = RecordingSlot(threading.RLock(), lambda *ev: events.append(ev), lambda: gone.append(1))
    with pytest.raises(RuntimeError, match="not recording"):
        slot.take()
    rec = SimpleNamespace(path=Path("/r.h5"), pid=7, alive=True, stopping=True)
    slot.recorder = rec
    with pytest.raises(RuntimeError, match="already recording to /r.h5"):
        slot.refuse_if_busy()
    assert slot.ref().recorder_pid == 7
    slot._on_exit(rec)  # the daemon stopped it: no failure, no event
    assert slot.failure is None and events == [] and gone == []
    assert slot.take() is rec and slot.recorder is None



def test_a_rotation_whose_new_recorder_ends_as_it_starts_keeps_the_old_one(monkeypatch):
    """RecordingSlot.rotate puts the new recorder in the slot only once it runs: one that ended before it saw our
    data (a child that said 'ready' and died) leaves the old one recording, and the operator gets the error."""
    slot = RecordingSlot(threading.RLock(), lambda *ev: None, lambda: None)
    with pytest.raises(RuntimeError, match="not recording: nothing to rotate"):
        slot.rotate(Path("/b.h5"), ["tcp://127.0.0.1:1"], "rig-a", 0.25, 5.0)
    old = SimpleNamespace(path=Path("/a.h5"), pid=7, alive=True, stopping=False)
    slot.recorder = old
    started = []

    def dead_at_start(path, *args):
        started.append(path)
        return SimpleNamespace(path=path, pid=8, alive=False, closed_line="", progress="recorder: 0 samples")
    monkeypatch.setattr("daq.daemon.recording.RecorderProcess", dead_at_start)
    with pytest.raises(RuntimeError, match="ended as it started .*still recording to /a.h5"):
        slot.rotate(Path("/b.h5"), ["tcp://127.0.0.1:1"], "rig-a", 0.25, 5.0)
    assert started == [Path("/b.h5")] and slot.recorder is old


# ----------------------------------------------------------------------------- status and handlers


class FakeAcq:
    endpoint = "tcp://127.0.0.1:1"

    def __init__(self) -> None:
        self.events: list[tuple[str, str, str]] = []
        self.samples = 0

    def counters(self):
        return {"motor": SimpleNamespace(samples=self.samples)}

    def status(self):
        return {"streams": {"motor": {"samples": self.samples}}, "dropped": 0, "misaligned_reads": 0,
                "sources": {"motor": {"lost_frames": 1, "checksum_errors": 2}},
                "motor": {"measured": 0.0, "setpoint": 0.0, "state": "DISABLED", "host_time": time.monotonic()}}

    def publish_event(self, kind: str, source: str, detail: str) -> None:
        self.events.append((kind, source, detail))


def _fake_daemon(motor: FakeMotor) -> SimpleNamespace:
    acq = FakeAcq()
    d = SimpleNamespace(acq=acq, rig=SimpleNamespace(rig="rig-a"), simulated=False, t_start=time.monotonic(),
                        started_at=utcnow(), rates=StreamRates(acq.counters), runner=None, estimator=None,
                        monitor=None, web=None, bench=None, session=None, lock=threading.RLock(),
                        drivers=SimpleNamespace(motor=motor), motion=_guard(motor)[0],
                        recording=RecordingSlot(threading.RLock(), acq.publish_event, lambda: None))
    d.halt = lambda how, detail: (setattr(d.motion, "halted", True), getattr(motor, how)(),
                                  acq.publish_event(how, "operator", detail))
    return d


def test_status_has_every_part_and_the_rates_come_from_the_counters():
    d = _fake_daemon(FakeMotor())
    d.acq.samples = 100
    d.rates.update()
    st = daemon_status(d)
    assert list(st)[:6] == ["rig", "sim", "pid", "uptime_s", "bus", "belt"]
    assert st["streams"]["motor"]["rate_hz"] > 0 and st["drops"]["lost_frames"] == 1
    assert st["motion"] == {"allowed": True, "refused_because": None}
    assert st["recording"] is st["ramp"] is st["estimator"] is st["session"] is None
    assert "sim_bench" not in st and "web" not in st
    assert belt(d, {})["commanded"] is None
    d.motion.halted = True
    assert belt(d, {})["commanded"] == 0.0


def test_the_handlers_stop_note_and_refuse_a_reset_while_the_belt_moves():
    motor = FakeMotor("ESTOP", measured=0.2)
    d = _fake_daemon(motor)
    h = ControlHandlers(d)
    assert set(h.table()) == {"status", "ramp", "stop", "estop", "reset", "record_start", "record_stop",
                              "record_rotate", "note"}
    assert h.handle_note({"text": "hello"}) == {"noted": "hello"}
    assert h.handle_stop({}) == {"stopping": True} and motor.calls == ["stop"]
    with pytest.raises(MotionRefused, match="the belt is moving"):
        h.handle_reset({})
    motor.measured = 0.0
    d.motion.unclean = _unclean()
    r = h.handle_reset({})
    assert r["regulator_before"] == "ESTOP" and r["regulator"] == "DISABLED" and r["acknowledged"]
    assert motor.calls == ["stop", "reset"] and d.motion.unclean is None
    assert [e[0] for e in d.acq.events] == ["note", "stop", "reset"]
    with pytest.raises(RuntimeError, match="not recording"):
        h.handle_record_stop({})


def test_a_regulator_reading_is_kept_for_status():
    g, _ = _guard(FakeMotor("RUNNING", 0.05), FakeBench(None))
    r = g.read_regulator()
    assert isinstance(r, RegulatorReading) and r.state == "RUNNING" and not r.latched and r.measured == 0.05


# ----------------------------------------------------------------------------- the simulated bench's handle


class FakeBenchProcess:
    def __init__(self, workdir: Path, status) -> None:
        self.pid, self.control, self.workdir = 4242, "tcp://127.0.0.1:9", workdir
        self.endpoints = {"motor": {"port": str(workdir / "motor")}}
        self._status = status
        self.stopped = False

    def status(self):
        return self._status()

    def alive(self) -> bool:
        return not self.stopped

    def stop(self) -> None:
        self.stopped = True


def test_the_sim_bench_handle_stores_its_wiring_and_tells_its_trips(tmp_path):
    from daq.config import load_rig
    from daq.daemon.sim_bench import AttachedSimBench, SimBench, SimBenchCfg

    cfg = SimBenchCfg(rig="brake-2dof", effects=["stick-time"], time_scale=2.0, seed=3)
    rig = load_rig("brake-2dof")
    bench = SimBench(FakeBenchProcess(tmp_path, lambda: {"watchdog_trips": 2}), rig, cfg)
    assert bench.rig_arg == str(tmp_path / "brake-2dof.toml") and Path(bench.rig_arg).exists()
    assert not bench.attached and bench.watchdog_trips() == 2 and bench.alive()
    ref = bench.ref()
    assert (ref.pid, ref.rig, ref.effects, ref.time_scale, ref.seed) == (4242, "brake-2dof", ["stick-time"], 2.0, 3)
    bench.keepalive()  # a bench we started has us as its owner: nothing to ask

    def silent():
        raise TimeoutError("no reply")
    assert SimBench(FakeBenchProcess(tmp_path, silent), rig, cfg).watchdog_trips() is None
    bench.stop()
    assert not bench.alive()
    # another simulation than the last session's: a new bench, whatever runs
    assert AttachedSimBench.find(ref, "brake-2dof", None, ["stick-time"], 1.0, 3) is None
    assert AttachedSimBench.find(None, "brake-2dof", None, [], 1.0, 0) is None
