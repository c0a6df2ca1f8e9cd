"""What several test files share: bad-input assertions (one line naming file and field), ramp files, a lab's
slider, the command line as a subprocess, waits on a condition, and a real ``daq daemon --sim`` (with its web page)
driven from a test.

``daq`` here is the command line called in this process (``main(argv)``, its exit code); ``daq_process`` runs
it as the user does, in a subprocess (each pays ~1.5 s of imports: keep those to the paths a user takes).
"""

from __future__ import annotations

import contextlib
import json
import re
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import scipy.io
from websockets.sync.client import connect

from daq.cli.main import main as daq
from daq.config import load_rig, rig_path
from daq.daemon.control import ControlClient
from daq.errors import InputError
from daq.io.interchange import write_recording
from daq.sim.effectset import parse_effect
from daq.sim.run import simulate
from sim_backends.bench_client import end_bench, read_ready, stop_daemon, wait_gone  # noqa: F401 - tests use wait_gone
from sim_backends.bench_client import request as sim_request

ROOT = Path(__file__).resolve().parent.parent  # the repository: the working folder of every subprocess

M, K, G = 0.05, 200.0, 9.81  # the spring-slider of docs/examples/spring-slider.md: mass, spring, gravity


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def expect_error(exc: InputError, source: str, field: str, *fragments: str) -> None:
    """The error is one line 'SOURCE: FIELD: message' with the given source and field."""
    text = str(exc)
    assert "\n" not in text
    assert (exc.source, exc.field) == (source, field), text
    assert text == f"{source}: {field}: {exc.message}"
    assert exc.message
    for frag in fragments:
        assert frag in exc.message, (frag, text)


def ramp_text(hold_s: float, stop: bool = True) -> str:
    """A ramp file for the daemon tests: 0.5 s up to 0.15 m/s, a hold, and (``stop``) 0.5 s down to rest."""
    text = ('start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 0.5\nto_m_per_s = 0.15\n'
            f'[[segment]]\nkind = "hold"\nduration_s = {hold_s}\n')
    return text + ('[[segment]]\nkind = "linear"\nduration_s = 0.5\nto_m_per_s = 0.0\n' if stop else "")


def slider_rig(tmp_path: Path) -> Path:
    """The spring-slider of docs/examples/spring-slider.md as a user's belt-ndof rig file."""
    text = rig_path("belt-ndof").read_text()
    text = text.replace("mass_kg = 0.5", f"mass_kg = {M}").replace("normal_force_N = 4.905", f"normal_force_N = {M * G}")
    assert 'driven = "belt"' in text
    text = text.replace('driven = "belt"', 'driven = "spring"', 1)  # the driver pulls the spring; the track is fixed
    path = tmp_path / "slider-rig.toml"
    path.write_text(text)
    return path


def slider_compare(tmp_path: Path, t: np.ndarray, f_over_mg: np.ndarray, drive: str) -> dict:
    """A lab's slider record through the user's path: a .mat of t and F/mg (500 Hz; noise 5e-4, steps 1e-3 of
    F/mg) -> the rig file edited -> `import --map` (x1 from F/mg, vb = ``drive``, arithmetic of t) -> `model init`
    -> `compare`; returns compare's JSON."""
    scipy.io.savemat(tmp_path / "slider.mat", {"t": t, "F_over_mg": f_over_mg})
    rig = slider_rig(tmp_path)
    rig.write_text(rig.read_text().replace("noise_std = 2e-5\nlsb = 1e-5", f"noise_std = {5e-4 * M * G / K:.3g}\n"
                                           f"lsb = {1e-3 * M * G / K:.3g}", 1).replace("rate_Hz = 250.0", "rate_Hz = 500.0"))
    h5, model = tmp_path / "slider.h5", tmp_path / "model.toml"
    assert daq(["import", str(tmp_path / "slider.mat"), "--rig", str(rig), "--map", f"x1=F_over_mg*{M}*{G}/{K}",
                "--map", f"vb={drive}", "-o", str(h5)]) == 0
    assert daq(["model", "init", str(rig), "-o", str(model)]) == 0
    assert daq(["compare", str(h5), "--model", str(model), "--no-history", "--report", str(tmp_path / "cmp")]) == 0
    return json.loads((tmp_path / "cmp" / "compare.json").read_text())


def make_recordings(folder: Path, spec: list[tuple[str, float, int]], effects: dict[int, str] | None = None) -> Path:
    """Simulated recordings (the project's simulator) of each (rig, seconds, seed), at 100 Hz."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, (rig, seconds, seed) in enumerate(spec):
        eff = (effects or {}).get(i)
        rec = simulate(load_rig(rig), effects=[parse_effect(eff)] if eff else [], rate=100.0, seed=seed,
                       duration=seconds)
        write_recording(rec, folder / f"{rig}-{i:02d}.h5")
    return folder


# ----------------------------------------------------------------------------- processes, waits, ports


def daq_process(*args: str, timeout: float = 120.0, cwd: Path | None = None, env: dict | None = None
                ) -> subprocess.CompletedProcess:
    """``daq ARGS...`` in a subprocess (``python -m daq.cli``), as the user runs it; output captured as text."""
    return subprocess.run([sys.executable, "-m", "daq.cli", *args], cwd=cwd or ROOT, capture_output=True, text=True,
                          timeout=timeout, env=env, check=False)


def wait_for(pred, timeout: float, what: str):
    """Poll ``pred`` every 50 ms until it returns something true (returned), or fail naming ``what``."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        got = pred()
        if got:
            return got
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (the OS's pick: no two test workers get the same one)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def event_kinds(f) -> list[str]:
    """The ``kind`` column of a recording's event table (an open h5py.File), as str."""
    return [k.decode() if isinstance(k, bytes) else k for k in f["events"]["kind"]]


# ----------------------------------------------------------------------------- a real daemon on a simulated bench

SHORT = ramp_text(1.5)
LONG = ramp_text(120.0, stop=False)
TOO_FAST = 'start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 0.1\nto_m_per_s = 0.4\n'
START_S = 180.0  # first start compiles/loads numba caches; a loaded CI machine is slow


class DaemonProc:
    """``daq daemon --rig brake-2dof --sim`` as a subprocess; parses its ready line (``err``: its stderr lines)."""

    def __init__(self, tmp: Path, *extra: str) -> None:
        self.tmp = tmp
        self.data = tmp / "data"
        self.proc = subprocess.Popen([sys.executable, "-m", "daq.cli", "daemon", "--rig", "brake-2dof", "--sim",
                                      "--data-dir", str(self.data), "--control", "tcp://127.0.0.1:0",
                                      "--bus", "tcp://127.0.0.1:0", "--workdir", str(tmp / "dev"), *extra],
                                     cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.err: list[str] = []
        threading.Thread(target=self._read_err, daemon=True).start()
        fields = read_ready(self.proc, START_S)
        self.endpoint = fields["control"]
        self.sim_control = fields["sim_control"]
        self.sim_pid = int(fields["sim_bench_pid"])
        self.rest: list[str] = []
        threading.Thread(target=lambda: self.rest.extend(self.proc.stdout), daemon=True).start()

    def _read_err(self) -> None:
        for line in self.proc.stderr:
            self.err.append(line)
            sys.stderr.write(line)  # still shown by pytest on failure

    def ctl(self, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
        """``daq ctl --endpoint THIS ARGS...`` in a subprocess, as the operator types it."""
        return daq_process("ctl", "--endpoint", self.endpoint, *args, timeout=timeout)

    def run_long_ramp(self, record: Path | None = None) -> None:
        """Start recording to ``record`` (if given) and the long ramp, and wait until the belt is at speed."""
        ramp = self.tmp / "long.toml"
        ramp.write_text(LONG)
        if record is not None:
            assert self.ctl("record", "start", "--path", str(record)).returncode == 0
        assert self.ctl("ramp", str(ramp), "--no-wait").returncode == 0
        wait_for(lambda: self.sim()["belt_speed"] > 0.149, 30, "the belt at speed")

    def status(self) -> dict:
        """The daemon's status over its control socket, from this process: what ``daq ctl status --json`` prints,
        without a subprocess's start-up, so that a poll reads it every few ms (the CLI's own output is tested with
        ``ctl``)."""
        with ControlClient(self.endpoint, timeout_s=30.0) as c:
            r = c.request("status")
        assert r.ok, r.error
        return r.result

    def sim(self) -> dict:
        return sim_request(self.sim_control, "status")

    def close(self) -> None:
        stop_daemon(self.proc)
        end_bench(self.sim_pid, self.sim_control, ask_s=2.0, wait_s=10.0)  # (unless a later daemon on it already did)


class WebRig:
    """A daemon with CURVE keys and its web page (``--keys DIR --web 127.0.0.1:0``), its operator link, a page that
    asks for frames and never reads one, and a CURVE operator client for status."""

    def __init__(self, tmp: Path) -> None:
        keys = tmp / "keys"
        r = daq_process("ctl", "keygen", str(keys), "--operator", "alice", timeout=60)
        assert r.returncode == 0, r.stderr
        self.d = DaemonProc(tmp, "--keys", str(keys), "--web", "127.0.0.1:0")
        line = wait_for(lambda: next((x for x in self.d.err if "operator link" in x), None), 10, "the operator link")
        self.url, self.token = re.search(r"(http://\S+/)#token=(\S+)", line).groups()
        # a page that asks for frames and never reads one: it must cost nobody anything
        self._stack = contextlib.ExitStack()
        self.stalled = self._stack.enter_context(connect(self.url.replace("http://", "ws://") + "ws"))
        self.stalled.send(json.dumps({"type": "view", "window_s": 10, "width": 1500}))
        alice = keys / "clients" / "alice"
        self.client = ControlClient(self.d.endpoint, client_secret_file=alice / "client.key_secret",
                                    server_public_file=alice / "server.key", timeout_s=30.0)

    def status(self) -> dict:
        r = self.client.request("status")
        assert r.ok, r.error
        return r.result

    def page_stats(self) -> dict:
        with urllib.request.urlopen(self.url + "api/stats", timeout=10) as r:
            return json.load(r)

    def close(self) -> None:
        self._stack.close()
        self.client.close()
        self.d.close()


def expect_read_error(read, path, field: str, *fragments: str) -> InputError:
    """``read(path)`` fails with one InputError naming ``path`` (as given) and ``field`` (see expect_error)."""
    try:
        read(path)
    except InputError as exc:
        expect_error(exc, str(path), field, *fragments)
        return exc
    raise AssertionError(f"{getattr(read, '__name__', read)}({path!r}) raised no InputError")


def brake_on_serial_stream():
    """The brake rig wired the alternative way: x1 and phi on the binary serial stream, the CAN bus off."""
    from daq.config import parse_rig

    data = load_rig("brake-2dof").model_dump(mode="json", exclude_none=True)
    data["instruments"]["can"]["enabled"] = False
    data["instruments"]["laser_serial"]["enabled"] = True
    return parse_rig(data, "test")


def logged_tracebacks(path: Path) -> list[dict]:
    """The exceptions `daq` commands ended in, as daq.cli.main logged them to ``path`` (TRACEBACK_LOG), one dict each
    (command, argv, type, traceback); a line cut short by a killed process is skipped."""
    out = []
    if not path.exists():
        return out
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return out
