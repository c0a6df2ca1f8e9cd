"""A soak of the whole daemon: ``daq soak --minutes N``: is its memory flat, is every stream at its rate, is
nothing lost, while it runs as the lab runs it.

Why: a 10-minute soak in issue 29 saw the daemon and the web process grow ~1 MB/min, too short to call
a leak; a rig runs for days. This runs ``daq daemon --sim --web`` (its own ports, data and bench under
``--out``) with what a day brings: the live page fetched, two viewers on the page's WebSocket (one
acknowledging frames as a browser does and changing its window every minute, one connected but never
reading), recordings rotated every ``record_every_min`` (hourly by default), and ramps one after the
other (stick-slip, so the estimator's fits and cycles run). Every ``sample_s`` it reads the resident
memory (RSS) of every process of the daemon's family (the daemon, its estimator, recorder and web
children, the simulated bench) and the daemon's status.

The figures: per process the RSS slope in MB/min by least squares over its samples after a warm-up
(buffers fill: the page keeps 120 s of raw samples, HDF5 its chunk caches), with a 95 % bound that
allows for the samples' correlation (the standard error inflated by the residuals' lag-1
autocorrelation, as an AR(1) noise would need); every stream's measured rate (samples counted by the
daemon over the soak) against the rate its instrument publishes on the bus; lost blocks as the
recordings' own ``stop`` events count them, beside the bus queue's, the estimator's and the web
process's. Written as JSON and a PNG (RSS against time per process) in ``out_dir``.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import matplotlib.pyplot as plt
import numpy as np
import psutil
from pydantic import Field
from scipy import stats as sps
from websockets.exceptions import ConnectionClosed, InvalidStatus, InvalidURI
from websockets.sync.client import connect

from daq.io.jsonout import write_json
from daq.io.png import save_png  # sets the Agg backend (before any figure exists)
from daq.io.stream_format import Block
from daq.streaming.bus import Subscriber
from daq.strict import Strict
from sim_backends.bench_client import end_bench, read_ready, stop_daemon

from .control import ControlClient

ROOT = Path(__file__).resolve().parents[2]  # where `python -m daq.cli` finds the packages
START_TIMEOUT_S = 180.0  # the daemon's first start compiles/loads numba caches
STATUS_TIMEOUT_S = 15.0
RAMP_ACTIVE = ("idle", "lead-in", "running")
VIEW_WINDOWS = (10.0, 300.0, 0.0)  # the reading viewer's windows, one a minute (0: the whole run)
# 2 s up to 0.15 m/s, 60 s held (stick-slip on brake-2dof), 2 s down to rest: then the next one
RAMP = ('start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 2.0\nto_m_per_s = 0.15\n'
        '[[segment]]\nkind = "hold"\nduration_s = 60.0\n[[segment]]\nkind = "linear"\nduration_s = 2.0\n'
        'to_m_per_s = 0.0\n')


class SoakCfg(Strict):
    minutes: float = Field(gt=0, le=7 * 24 * 60, description="how long the daemon runs once it is ready")
    out_dir: Path
    rig: str = "brake-2dof"
    record_every_min: float = Field(60.0, gt=0, description="a new recording this often")
    sample_s: float | None = Field(None, gt=0, le=600, description="None: minutes*60/120 within [1, 5] s")
    warmup_min: float | None = Field(None, ge=0, description="each process's first minutes left out of its slope "
                                                             "(None: a fifth of the run, at most 3)")
    ramps: bool = Field(True, description="ramps one after the other (False: the belt at rest)")

    def sample_every(self) -> float:
        return self.sample_s if self.sample_s is not None else min(5.0, max(1.0, self.minutes * 60 / 120))

    def warmup(self) -> float:
        return self.warmup_min if self.warmup_min is not None else min(3.0, self.minutes / 5)


class ProcessMemory(Strict):
    role: str
    pid: int
    samples: int
    from_min: float  # of the soak, when this process was first seen
    to_min: float
    first_mb: float
    last_mb: float
    max_mb: float
    fit_samples: int  # after the warm-up
    slope_mb_per_min: float | None  # least squares over the samples after the warm-up
    bound_mb_per_min: float | None  # half-width of its 95 % interval (autocorrelation allowed for)
    lag1_autocorrelation: float | None


class StreamRate(Strict):
    stream: str
    nominal_hz: float | None  # as its instrument publishes it on the bus
    measured_hz: float
    ratio: float | None
    samples: int


class RecordingResult(Strict):
    path: str
    samples: int | None  # the recorder's own count, from the file's stop event
    lost_blocks: int | None
    closed_cleanly: bool  # a stop event is the last row
    motor_t: tuple[float, float] | None = None  # host time of its first and last motor sample
    # from the previous file's last motor sample to this one's first (negative: they overlap); a rotation starts
    # the next file before the last one closes, so this is never a hole (None: the first file)
    gap_s: float | None = None


class SoakResult(Strict):
    started_at: str
    rig: str
    minutes: float
    measured_minutes: float
    record_every_min: float
    sample_s: float
    warmup_min: float
    ramps_run: int
    processes: list[ProcessMemory]
    streams: list[StreamRate]
    recordings: list[RecordingResult]
    lost: dict[str, int]  # recorder (files), bus_queue, estimator, web
    lost_total: int
    drops: dict[str, int]  # the daemon's drop counters at the end
    viewer: dict[str, int]  # frames read and acknowledged, reconnects, window changes
    stalled_viewer: dict[str, Any]  # connected to the end, frames the server sent it
    daemon_stderr_lines: int
    tracebacks: int
    daemon_exit: int | None  # None: it ran to the end (then stopped by SIGTERM)
    status_timeouts: int = 0  # status requests unanswered within STATUS_TIMEOUT_S
    figure: str
    series: dict[str, list[list[float]]]  # "role pid" -> [[minute, MB], ...]


def slope_with_bound(t_min: np.ndarray, mb: np.ndarray) -> tuple[float | None, float | None, float | None]:
    """Least-squares slope [MB/min], the half-width of its 95 % interval, and the residuals' lag-1 autocorrelation.

    RSS samples a few seconds apart are not independent (the allocator keeps what it got), so the
    textbook standard error is inflated by sqrt((1+r)/(1-r)), r the residuals' lag-1 autocorrelation
    (clipped to [0, 0.95]), and the t quantile taken at the effective number of samples.
    """
    n = t_min.size
    if n < 4 or np.ptp(t_min) <= 0:
        return None, None, None
    slope, icpt = np.polyfit(t_min, mb, 1)
    res = mb - (slope * t_min + icpt)
    sxx = float(np.sum((t_min - t_min.mean()) ** 2))
    se = math.sqrt(float(np.sum(res ** 2)) / (n - 2) / sxx)
    r = float(np.corrcoef(res[:-1], res[1:])[0, 1]) if np.std(res[:-1]) > 0 and np.std(res[1:]) > 0 else 0.0
    r = min(0.95, max(0.0, r)) if math.isfinite(r) else 0.0
    n_eff = max(3.0, n * (1 - r) / (1 + r))
    bound = float(sps.t.ppf(0.975, n_eff - 2)) * se * math.sqrt((1 + r) / (1 - r))
    return float(slope), bound, r


class _Viewer(threading.Thread):
    """A page's WebSocket that reads and acknowledges every frame, as a browser does, changing its window every
    minute (10 s, 5 min, the whole run); it reconnects if the server closes it."""

    def __init__(self, ws_url: str, stop: threading.Event) -> None:
        super().__init__(name="soak-viewer", daemon=True)
        self.ws_url = ws_url
        self.stop_event = stop
        self.counts = {"frames": 0, "reconnects": 0, "window_changes": 0}
        self.error: str | None = None

    def run(self) -> None:
        while not self.stop_event.is_set():
            try:
                with connect(self.ws_url, open_timeout=30) as ws:
                    self._read(ws)
            except (ConnectionClosed, InvalidStatus, InvalidURI, OSError, TimeoutError) as exc:
                self.error = f"{type(exc).__name__}: {exc}"
                if self.stop_event.wait(1.0):
                    return
                self.counts["reconnects"] += 1

    def _read(self, ws) -> None:
        k = 0
        ws.send(json.dumps({"type": "view", "window_s": VIEW_WINDOWS[0], "width": 1200}))
        next_change = time.monotonic() + 60.0
        while not self.stop_event.is_set():
            if time.monotonic() >= next_change:
                k += 1
                ws.send(json.dumps({"type": "view", "window_s": VIEW_WINDOWS[k % len(VIEW_WINDOWS)], "width": 1200}))
                self.counts["window_changes"] += 1
                next_change += 60.0
            try:
                msg = json.loads(ws.recv(timeout=1.0))
            except TimeoutError:
                continue
            if msg.get("type") == "frame":
                self.counts["frames"] += 1
                ws.send(json.dumps({"type": "ack", "seq": msg["seq"]}))


class _Daemon:
    """``daq daemon --sim --web`` under ``work``: its ready line's fields and its stderr (kept and logged)."""

    def __init__(self, rig: str, work: Path, log: Callable[[str], None]) -> None:
        work.mkdir(parents=True, exist_ok=True)
        self.stderr_log = (work / "daemon.log").open("w")
        self.err_lines = 0
        self.tracebacks = 0
        self.proc = subprocess.Popen([sys.executable, "-m", "daq.cli", "daemon", "--rig", rig, "--sim",
                                      "--data-dir", str(work / "data"), "--control", "tcp://127.0.0.1:0",
                                      "--bus", "tcp://127.0.0.1:0", "--workdir", str(work / "dev"),
                                      "--web", "127.0.0.1:0"],
                                     cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        threading.Thread(target=self._read_err, name="soak-daemon-stderr", daemon=True).start()
        self.fields = read_ready(self.proc, START_TIMEOUT_S, f" (its stderr: {work / 'daemon.log'})")
        threading.Thread(target=lambda: [None for _ in self.proc.stdout], daemon=True).start()
        log(f"soak: daemon pid {self.proc.pid} ready: web {self.fields.get('web')}, bench pid "
            f"{self.fields.get('sim_bench_pid')}")

    def _read_err(self) -> None:
        for line in self.proc.stderr:
            self.err_lines += 1
            self.tracebacks += "Traceback" in line
            self.stderr_log.write(line)
            self.stderr_log.flush()

    def stop(self) -> int | None:
        """SIGTERM (ramp down, recording closed), then end the bench, which outlives the daemon by design."""
        stop_daemon(self.proc)
        end_bench(int(self.fields.get("sim_bench_pid", 0) or 0), self.fields.get("sim_control"), ask_s=2.0, wait_s=10.0)
        return self.proc.returncode


def _nominal_rates(bus: str, seconds: float = 5.0) -> dict[str, float | None]:
    """Each stream's rate as its instrument declares it in the blocks it publishes."""
    sub = Subscriber(bus, events=False, name="soak")
    rates: dict[str, float | None] = {}
    t_end = time.monotonic() + seconds
    try:
        while time.monotonic() < t_end:
            msg = sub.recv(0.2)
            if isinstance(msg, Block):
                rates.setdefault(msg.meta.stream, msg.meta.rate_hz)
    finally:
        sub.close()
    return rates


def _family(status: dict[str, Any], daemon_pid: int) -> dict[int, str]:
    """pid -> role of every process of the daemon's family: what status names, and any other descendant."""
    roles = {daemon_pid: "daemon"}
    for role, key in (("estimator", "estimator"), ("recorder", "recording"), ("web", "web"), ("sim bench", "sim_bench")):
        pid = (status.get(key) or {}).get("pid")
        if pid:
            roles[int(pid)] = role
    with contextlib.suppress(psutil.Error):
        for child in psutil.Process(daemon_pid).children(recursive=True):
            roles.setdefault(child.pid, f"child {child.name()}")
    return roles


def _rss_mb(pid: int) -> float | None:
    try:
        return psutil.Process(pid).memory_info().rss / 1e6
    except psutil.Error:
        return None


def _get_json(url: str) -> dict[str, Any]:
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.load(r)


def _recording_result(path: Path) -> RecordingResult:
    """What the recording's own events say: its recorder's sample count and lost blocks, a clean close."""
    try:
        with h5py.File(path, "r") as f:
            kinds = [k.decode() if isinstance(k, bytes) else k for k in f["events"]["kind"]]
            details = [d.decode() if isinstance(d, bytes) else d for d in f["events"]["detail"]]
            t = f["streams/motor/t"] if "streams/motor/t" in f else None
            motor_t = (float(t[0]), float(t[-1])) if t is not None and t.size else None
    except (OSError, KeyError) as exc:
        return RecordingResult(path=f"{path} (unreadable: {type(exc).__name__})", samples=None, lost_blocks=None,
                               closed_cleanly=False)
    stop = next((d for k, d in zip(reversed(kinds), reversed(details), strict=True) if k == "stop"), "")
    m = re.match(r"(\d+) samples, (\d+) lost blocks", stop)
    return RecordingResult(path=str(path), samples=int(m.group(1)) if m else None,
                           lost_blocks=int(m.group(2)) if m else None, closed_cleanly=bool(kinds) and kinds[-1] == "stop",
                           motor_t=motor_t)


def _memory(series: dict[tuple[str, int], list[tuple[float, float]]], warmup: float) -> list[ProcessMemory]:
    out = []
    for (role, pid), pts in sorted(series.items(), key=lambda kv: (kv[0][0], kv[1][0][0])):
        a = np.asarray(pts)
        t, mb = a[:, 0], a[:, 1]
        fit = t >= t[0] + warmup
        slope, bound, r = slope_with_bound(t[fit], mb[fit])
        out.append(ProcessMemory(role=role, pid=pid, samples=len(pts), from_min=float(t[0]), to_min=float(t[-1]),
                                 first_mb=float(mb[0]), last_mb=float(mb[-1]), max_mb=float(mb.max()),
                                 fit_samples=int(fit.sum()), slope_mb_per_min=slope, bound_mb_per_min=bound,
                                 lag1_autocorrelation=r))
    return out


def _figure(processes: list[ProcessMemory], series: dict[tuple[str, int], list[tuple[float, float]]],
            warmup: float, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(10, 5.5))
    for p in processes:
        a = np.asarray(series[(p.role, p.pid)])
        label = f"{p.role} ({p.pid})"
        if p.slope_mb_per_min is not None:
            label += f": {p.slope_mb_per_min:+.3f} ± {p.bound_mb_per_min:.3f} MB/min"
        line, = ax.plot(a[:, 0], a[:, 1], lw=1.2, label=label)
        if p.slope_mb_per_min is not None:
            t = a[:, 0][a[:, 0] >= a[0, 0] + warmup]
            mb = a[:, 1][a[:, 0] >= a[0, 0] + warmup]
            icpt = float(np.mean(mb) - p.slope_mb_per_min * np.mean(t))
            ax.plot(t, p.slope_mb_per_min * t + icpt, ls="--", lw=0.8, color=line.get_color())
    ax.set_xlabel("minutes since the daemon was ready")
    ax.set_ylabel("resident memory (RSS) [MB]")
    ax.set_title(f"daq soak: memory per process (slopes after each process's first {warmup:g} min, 95 % bounds)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    save_png(fig, path)


class _SoakRun:
    """One soak against a running daemon: what it asks, what it measures, and when (the steps of :func:`run_soak`)."""

    def __init__(self, cfg: SoakCfg, d: _Daemon, log: Callable[[str], None], interrupt: threading.Event) -> None:
        self.cfg, self.d, self.log, self.interrupt = cfg, d, log, interrupt
        self.out = cfg.out_dir
        self.stop = threading.Event()
        self.ctl = ControlClient(d.fields["control"], timeout_s=120.0)  # record_start waits for the recorder
        self.quick = ControlClient(d.fields["control"], timeout_s=STATUS_TIMEOUT_S)  # a dead daemon is seen soon
        self.web = d.fields["web"]
        self.ws_url = self.web.replace("http://", "ws://") + "ws"
        self.series: dict[tuple[str, int], list[tuple[float, float]]] = {}
        self.counts: list[tuple[float, dict[str, int]]] = []
        self.recordings: list[Path] = []
        self.ramps = self.status_timeouts = 0
        self.status: dict[str, Any] = {}
        self.web_stats: dict[str, Any] = {}
        self.stalled_stack = contextlib.ExitStack()
        self.viewer = _Viewer(self.ws_url, self.stop)
        self.daemon_exit: int | None = None
        self.nominal: dict[str, float | None] = {}
        self.measured_min = 0.0

    def open_viewers(self) -> None:
        """The page as a browser loads it, a stalled viewer that never reads a frame, and a reading one."""
        for page in ("", "static/app.js"):
            with urllib.request.urlopen(self.web + page, timeout=10) as r:
                r.read()
        stalled = self.stalled_stack.enter_context(connect(self.ws_url, open_timeout=30))
        stalled.send(json.dumps({"type": "view", "window_s": 10, "width": 1500}))
        self.viewer.start()

    def record_start(self, op: str = "record_start") -> None:
        path = self.out / "data" / f"soak-{len(self.recordings) + 1:03d}.h5"
        r = self.ctl.request(op, path=str(path))
        if not r.ok:
            raise RuntimeError(f"{op} refused: {r.error}")
        self.recordings.append(path)

    def loop(self) -> None:
        """Sample every ``cfg.sample_every()`` until the end, an interrupt or the daemon's death; keep a ramp
        running, start a new recording every ``record_every_min``, log every minute."""
        cfg = self.cfg
        t0 = time.monotonic()
        every = cfg.sample_every()
        next_rotation, next_log, t_end = t0 + cfg.record_every_min * 60, t0 + 60.0, t0 + cfg.minutes * 60
        while not self._ended(t0):
            now = time.monotonic()
            try:
                r = self.quick.request("status")
            except TimeoutError:
                self.status_timeouts += 1
                if now >= t_end:
                    break
                continue  # the daemon's exit is seen at the top; a busy one is asked again
            self.status = r.result if r.ok else self.status
            minute = (time.monotonic() - t0) / 60
            self._sample(minute)
            self._keep_a_ramp_running()
            if now >= t_end:
                break
            if now >= next_rotation:
                self.record_start("record_rotate")  # the next file before this one closes: no hole between
                next_rotation += cfg.record_every_min * 60
            if now >= next_log:
                self._log_minute(minute, every)
                next_log += 60.0
            self.interrupt.wait(max(0.0, min(every, t_end - time.monotonic()) - (time.monotonic() - now)))
        self.measured_min = (time.monotonic() - t0) / 60

    def _ended(self, t0: float) -> bool:
        """The daemon died, or the operator interrupted (each said once, in the log)."""
        if self.d.proc.poll() is not None:
            self.daemon_exit = self.d.proc.returncode
            self.log(f"soak: the daemon ended unexpectedly (exit {self.daemon_exit}); see {self.out / 'daemon.log'}")
            return True
        if self.interrupt.is_set():
            self.log(f"soak: interrupted after {(time.monotonic() - t0) / 60:.1f} min: the figures of what ran")
            return True
        return False

    def _sample(self, minute: float) -> None:
        """Every process's RSS, every stream's sample count, the web server's stats."""
        for pid, role in _family(self.status, self.d.proc.pid).items():
            mb = _rss_mb(pid)
            if mb is not None:
                self.series.setdefault((role, pid), []).append((minute, mb))
        self.counts.append((time.monotonic(), {k: int(s.get("samples") or 0)
                                               for k, s in self.status.get("streams", {}).items()}))
        with contextlib.suppress(OSError, ValueError):
            self.web_stats = _get_json(self.web + "api/stats")

    def _keep_a_ramp_running(self) -> None:
        ramp = self.status.get("ramp")
        if self.cfg.ramps and (ramp is None or ramp.get("state") not in RAMP_ACTIVE):
            with contextlib.suppress(TimeoutError):
                self.ramps += self.ctl.request("ramp", file=str(self.out / "ramp.toml")).ok

    def _log_minute(self, minute: float, every: float) -> None:
        rss = "  ".join(f"{role} {pts[-1][1]:.0f}" for (role, _), pts in self.series.items()
                        if pts[-1][0] >= minute - every / 60)
        drops = self.status.get("drops", {})
        self.log(f"soak: {minute:6.1f}/{self.cfg.minutes:g} min  RSS MB: {rss}  recordings {len(self.recordings)}  "
                 f"ramps {self.ramps}  recorder lost {drops.get('recorder_lost_blocks', 0)}  "
                 f"viewer frames {self.viewer.counts['frames']}")

    def wind_down(self) -> None:
        """A daemon still alive: its web stats at the end, then the belt stopped and the recording closed."""
        if self.daemon_exit is None:
            with contextlib.suppress(OSError, ValueError):
                self.web_stats = _get_json(self.web + "api/stats")
            with contextlib.suppress(TimeoutError):
                self.ctl.request("stop")
                self.ctl.request("record_stop")

    def close(self) -> None:
        """The viewers, the clients and the daemon (with its bench); its exit status if it failed."""
        self.stop.set()
        self.stalled_stack.close()
        self.ctl.close()
        self.quick.close()
        code = self.d.stop()
        if self.daemon_exit is None and code not in (0, None):
            self.daemon_exit = code
        self.d.stderr_log.close()


def run_soak(cfg: SoakCfg, log: Callable[[str], None], interrupt: threading.Event | None = None) -> SoakResult:
    """The soak itself (see the module's docstring); progress lines through ``log`` every minute. ``interrupt``
    set (the CLI's SIGTERM/SIGINT) ends it early, with the figures of what ran."""
    out = cfg.out_dir
    out.mkdir(parents=True, exist_ok=True)
    (out / "ramp.toml").write_text(RAMP)
    started_at = datetime.now(UTC).isoformat(timespec="seconds")
    run = _SoakRun(cfg, _Daemon(cfg.rig, out, log), log, interrupt or threading.Event())
    try:
        run.nominal = _nominal_rates(run.d.fields["bus"])
        run.open_viewers()
        run.record_start()
        run.loop()
        run.wind_down()
    finally:
        run.close()
    run.viewer.join(5.0)
    if run.status_timeouts:
        log(f"soak: {run.status_timeouts} status request(s) went unanswered for {STATUS_TIMEOUT_S:g} s")
    result = _result(cfg, started_at, run.measured_min, run.nominal, run.counts, run.series, run.recordings,
                     run.status, run.web_stats, run.viewer, run.d, run.ramps, run.daemon_exit)
    return result.model_copy(update={"status_timeouts": run.status_timeouts})


def _result(cfg: SoakCfg, started_at: str, measured_min: float, nominal: dict[str, float | None],
            counts: list[tuple[float, dict[str, int]]], series: dict[tuple[str, int], list[tuple[float, float]]],
            recordings: list[Path], status: dict[str, Any], web_stats: dict[str, Any], viewer: _Viewer,
            d: _Daemon, ramps: int, daemon_exit: int | None) -> SoakResult:
    (t_a, first), (t_b, last) = counts[0], counts[-1]
    streams = []
    for name in sorted(last):
        n = last[name] - first.get(name, 0)
        hz = n / (t_b - t_a) if t_b > t_a else 0.0
        nom = nominal.get(name)
        streams.append(StreamRate(stream=name, nominal_hz=nom, measured_hz=hz, ratio=hz / nom if nom else None,
                                  samples=n))
    recs = [_recording_result(p) for p in recordings]
    recs[1:] = [b.model_copy(update={"gap_s": b.motor_t[0] - a.motor_t[1]}) if a.motor_t and b.motor_t else b
                for a, b in zip(recs, recs[1:])]
    drops = {k: int(v or 0) for k, v in status.get("drops", {}).items()}
    lost = {"recorder": sum(r.lost_blocks or 0 for r in recs), "bus_queue": drops.get("bus_queue", 0),
            "estimator": drops.get("estimator_lost_blocks", 0), "web": int(web_stats.get("bus_lost_blocks") or 0)}
    pages = web_stats.get("page_list") or []  # read before the viewers closed
    held = [p["frames_sent"] for p in pages if p["frames_sent"] <= 2]  # it acknowledges nothing: 1 frame in flight
    stalled = {"connected_to_the_end": bool(held), "frames_sent": min(held, default=None), "pages_at_the_end": len(pages)}
    warmup = cfg.warmup()
    processes = _memory(series, warmup)
    figure = cfg.out_dir / "soak.png"
    _figure(processes, series, warmup, figure)
    return SoakResult(started_at=started_at, rig=cfg.rig, minutes=cfg.minutes, measured_minutes=measured_min,
                      record_every_min=cfg.record_every_min, sample_s=cfg.sample_every(), warmup_min=warmup,
                      ramps_run=ramps, processes=processes, streams=streams, recordings=recs, lost=lost,
                      lost_total=sum(lost.values()), drops=drops, viewer=dict(viewer.counts), stalled_viewer=stalled,
                      daemon_stderr_lines=d.err_lines, tracebacks=d.tracebacks, daemon_exit=daemon_exit,
                      figure=str(figure),
                      series={f"{role} {pid}": [[round(t, 4), round(mb, 3)] for t, mb in pts]
                              for (role, pid), pts in series.items()})


def write_result(result: SoakResult, path: Path) -> Path:
    return write_json(path, result.model_dump(mode="json"))


def report(result: SoakResult) -> str:
    """The soak's figures as text: memory slopes with bounds, stream rates, lost blocks."""
    lines = [(f"daq soak: {result.rig}, {result.measured_minutes:.1f} min, {len(result.recordings)} recording(s) "
              f"(every {result.record_every_min:g} min), {result.ramps_run} ramp(s), RSS every {result.sample_s:g} s"),
             f"memory (slope after each process's first {result.warmup_min:g} min; 95 % bound):"]
    for p in result.processes:
        slope = ("   n/a" if p.slope_mb_per_min is None
                 else f"{p.slope_mb_per_min:+.4f} ± {p.bound_mb_per_min:.4f} MB/min")
        lines.append(f"  {p.role:12s} pid {p.pid:<7d} {p.first_mb:7.1f} -> {p.last_mb:7.1f} MB (max {p.max_mb:.1f})  "
                     f"{slope}  ({p.fit_samples} samples, {p.from_min:.1f}-{p.to_min:.1f} min)")
    lines.append("streams (measured / nominal):")
    for s in result.streams:
        nom = f"{s.nominal_hz:9.1f} Hz  {100 * s.ratio:6.2f} %" if s.nominal_hz else "  (no nominal rate)"
        lines.append(f"  {s.stream:16s} {s.measured_hz:9.1f} Hz / {nom}  {s.samples:>11,d} samples")
    lines.append("lost blocks: " + "  ".join(f"{k} {v}" for k, v in result.lost.items()) + f"  total {result.lost_total}")
    for r in result.recordings:
        lines.append(f"  {r.path}: {r.samples} samples, {r.lost_blocks} lost blocks, "
                     f"{'closed cleanly' if r.closed_cleanly else 'NOT CLOSED CLEANLY'}"
                     + (f"; from the file before: {r.gap_s:+.3f} s" if r.gap_s is not None else ""))
    lines.append(f"viewer: {result.viewer['frames']} frames read, {result.viewer['reconnects']} reconnects; stalled "
                 f"viewer: connected to the end {result.stalled_viewer['connected_to_the_end']}, "
                 f"{result.stalled_viewer['frames_sent']} frame(s) sent to it")
    lines.append(f"daemon stderr: {result.daemon_stderr_lines} line(s), {result.tracebacks} traceback(s); "
                 f"{'ran to the end' if result.daemon_exit is None else f'EXIT {result.daemon_exit}'}")
    lines.append(f"figure: {result.figure}")
    return "\n".join(lines)
