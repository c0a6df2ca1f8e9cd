"""The estimator on the bus: subscribe to a rig's streams, publish friction estimates and law fits.

Why a separate adapter: the algorithm (core.FrictionEstimator) knows nothing about
sockets; this class only routes blocks, aligns streams, keeps the latency books, and
keeps the law fit off the hot path (in a worker process by default, so a fit never
holds the interpreter lock while blocks wait).

Published (on its own Publisher):
  stream ``estimator``: t = the time each estimate refers to (input time minus the
    differentiator's delay), channels F_est [N], N_est [N], mu_est, v_rel [m/s],
    slip (1 = slip, 0 = stick/creep), growing (1 while |v_rel| grows), latency [s]
    (publish time minus the input block's sent_host_time), plus rig extras;
  stream ``friction_fit``: one sample per fit (t = window end): n_points, rms, each
    free parameter and its standard error (``<name>_se``);
  stream ``cycles``: one sample per stick–slip cycle (t = break-away time): break-away
    force and mu, stick and slip time, slip distance, peak slip velocity (cycles.py),
    published about 10 ms after the slip ends;
  events: ``estimator_started`` (delay, window, rate as JSON), ``friction_fit``
    (the RunningLawFit as JSON), ``estimator_gap`` (input gap: the window restarts).

Decision record: docs/decisions/0005-daemon-process-layout.md.
"""

from __future__ import annotations

import json
import multiprocessing
import time
from concurrent.futures import BrokenExecutor, Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from typing import Literal

import numpy as np
import zmq
from pydantic import BaseModel, ConfigDict, Field

from daq.background import BackgroundLoop
from daq.config import RigConfig
from daq.io.stream_format import Block, BusEvent, StreamMeta
from daq.signals import FloatRing
from daq.streaming.bus import Publisher, Subscriber
from daq.strict import Closed

from .align import HoldBuffer, Pending
from .core import EstimateBlock, EstimatorCfg, FrictionEstimator
from .cycles import CYCLE_STREAM, CYCLE_UNITS, CycleDetector
from .fit import FitData, RunningLawFit, fit_law
from .rigmodels import RigModel, rig_model

OUT_UNITS = {"F_est": "N", "N_est": "N", "mu_est": "-", "v_rel": "m/s", "slip": "-", "growing": "-",
             "latency": "s"}


class OnlineCfg(Closed):
    """Where the estimator listens and speaks, and how it schedules work."""

    model_config = ConfigDict(frozen=True)
    sub_endpoint: str = Field(description="the rig's sample bus (a Publisher's endpoint)")
    pub_endpoint: str = Field("tcp://127.0.0.1:0", description="where the estimator publishes (port 0 = any)")
    streams: tuple[str, ...] | None = Field(None, description="streams to subscribe to; None = all")
    out_stream: str = "estimator"
    fit_stream: str = "friction_fit"  # not "estimator_...": ZeroMQ subscriptions match by prefix
    cycle_stream: str = CYCLE_STREAM
    source: str = "estimator"
    rate_hz: float | None = Field(None, gt=0.0, description="position stream rate; None = its StreamMeta")
    max_wait_s: float = Field(0.05, ge=0.0, description="how long a position sample waits for slower streams")
    fit: Literal["process", "thread", "inline", "off"] = "process"
    rcvhwm: int = Field(100_000, ge=1)
    sndhwm: int = Field(100_000, ge=1)


class OnlineStats(BaseModel):
    """Counters an operator (or a test) reads to see that the estimator keeps up."""

    blocks_in: int = 0
    samples_in: int = 0
    blocks_out: int = 0
    samples_out: int = 0
    lost_blocks: int = 0
    gaps: int = 0
    unaligned_dropped: int = 0
    fits_published: int = 0
    fits_failed: int = 0
    cycles: int = 0


class OnlineEstimator:
    """Subscribes to a rig's streams, estimates friction per block, publishes estimates and fits."""

    def __init__(self, cfg: RigConfig, online: OnlineCfg, est: EstimatorCfg = EstimatorCfg(),
                 e: np.ndarray | None = None, ctx: zmq.Context | None = None) -> None:
        self.rig = cfg
        self.online = online
        self.est_cfg = est
        self.model: RigModel = rig_model(cfg, e)
        self.sub = Subscriber(online.sub_endpoint, streams=list(online.streams) if online.streams else None,
                              events=True, rcvhwm=online.rcvhwm, name=online.source, ctx=ctx)
        self.pub = Publisher(online.pub_endpoint, sndhwm=online.sndhwm, ctx=ctx)
        self.endpoint = self.pub.endpoint
        self.stats = OnlineStats()
        self.fe: FrictionEstimator | None = None
        self._master: str | None = None  # stream carrying the position channel
        self._master_cols: list[int] = []
        self._from_master: list[int] = []  # rows of the estimator's inputs the master carries
        self._holds: dict[str, HoldBuffer] = {}  # slower stream -> its buffer
        self._hold_rows: dict[str, list[int]] = {}
        self._pending: Pending | None = None
        self._out_meta: StreamMeta | None = None
        self._fit_meta: StreamMeta | None = None
        self.cycles = CycleDetector()
        self._cycle_meta = StreamMeta(stream=online.cycle_stream, channels=tuple(CYCLE_UNITS),
                                      units=tuple(CYCLE_UNITS.values()), rig=cfg.rig, source=online.source)
        self._executor = self._make_executor(online.fit)
        self._fit_future: Future | None = None
        self.last_fit: RunningLawFit | None = None
        # per published block: the oldest sample's latency and the work it took (for benchmarks, monitoring)
        self.latency_log = FloatRing(1_000_000)
        self.work_log = FloatRing(1_000_000)
        self._loop = BackgroundLoop(lambda: self.poll(0.02), "online-estimator")

    # ------------------------------------------------------------------ lifecycle
    @staticmethod
    def _make_executor(kind: str) -> Executor | None:
        """Where fits run: a worker process keeps scipy off the interpreter lock the hot path needs."""
        if kind == "process":
            return ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))
        if kind == "thread":
            return ThreadPoolExecutor(max_workers=1)
        return None

    def warm_up(self) -> None:
        """Compile the kernels and start the fit worker before data flows (first use costs ~1 s)."""
        fe = FrictionEstimator(self.model, 1000.0, self.est_cfg)
        n = fe.n_taps + 8
        fe.process(np.arange(n) * 1e-3, np.zeros((len(fe.inputs), n)) + 1e-3)
        if self._executor is not None:  # start the worker and compile the law there
            v = np.linspace(2.0, 20.0, 40) * self.model.v_stick
            data = FitData(0.0, 1.0, v, fe.law.mu(v), np.ones_like(v))
            try:
                self._submit(fe.law, data, 10).result()
            except BrokenExecutor as exc:  # the worker died while starting (unguarded __main__ under spawn)
                self._fall_back_to_thread(exc)

    def start(self) -> "OnlineEstimator":
        """Poll in a background thread (the sockets are used by that thread only) until stop()."""
        self._loop.start()
        return self

    def stop(self) -> None:
        """Ask the loop thread to finish and wait for it."""
        self._loop.stop(timeout=10.0)

    def close(self) -> None:
        """Stop, then release the sockets and the fit worker."""
        self.stop()
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
        self.sub.close()
        self.pub.close()

    # ------------------------------------------------------------------ one step
    def poll(self, timeout: float = 0.02) -> int:
        """Receive what has arrived (waiting up to ``timeout`` for the first), estimate, publish; returns estimates."""
        msg = self.sub.recv(timeout)
        for _ in range(1000):  # drain what is queued, bounded so fits and publishing still happen
            if msg is None:
                break
            if isinstance(msg, Block):
                self._on_block(msg)
            else:
                self._on_event(msg)
            msg = self.sub.recv(0.0)
        n = self._estimate_ready()
        self._service_fit()
        return n

    def _on_event(self, ev: BusEvent) -> None:
        """Count the drops our Subscriber reports (the time gap itself restarts the window)."""
        if ev.kind == "lost_blocks" and ev.source == self.online.source:
            self.stats.lost_blocks += ev.count or 0

    def _on_block(self, b: Block) -> None:
        """Route a block: position samples wait in Pending, slower streams fill their HoldBuffer."""
        name = b.meta.stream
        if self._master is None and self.model.position in b.meta.channels:
            self._attach_master(b)
        if name == self._master:
            self.stats.blocks_in += 1
            self.stats.samples_in += b.header.n
            x = b.data[:, self._master_cols].T.astype(float)
            self._pending.append(b.t, x, b.header.sent_host_time, time.monotonic())
            return
        if name not in self._holds:
            rows = [i for i, c in enumerate(self.model.inputs) if c in b.meta.channels]
            if self._master is not None:
                rows = [i for i in rows if i not in self._from_master]
            taken = {r for rs in self._hold_rows.values() for r in rs}
            rows = [i for i in rows if i not in taken]
            if not rows:
                return
            period = 1.0 / b.meta.rate_hz if b.meta.rate_hz else 0.0
            self._holds[name] = HoldBuffer([b.meta.channels.index(self.model.inputs[i]) for i in rows], period)
            self._hold_rows[name] = rows
        self._holds[name].append(b.t, b.data)

    def _attach_master(self, b: Block) -> None:
        """The stream with the position channel sets the time base and the rate."""
        meta = b.meta
        self._master = meta.stream
        self._from_master = [i for i, c in enumerate(self.model.inputs) if c in meta.channels]
        self._master_cols = [meta.channels.index(self.model.inputs[i]) for i in self._from_master]
        for name in list(self._holds):  # a slower stream seen first may duplicate master channels
            self._hold_rows[name] = [r for r in self._hold_rows[name] if r not in self._from_master]
        rate = self.online.rate_hz or meta.rate_hz
        if rate is None:
            rate = 1.0 / float(np.median(np.diff(b.t))) if b.t.size > 1 else 1000.0
        self.fe = FrictionEstimator(self.model, rate, self.est_cfg)
        self._pending = Pending(len(self._from_master))
        extras = self.model.extra_names
        chans = (*OUT_UNITS, *extras)
        units = (*OUT_UNITS.values(), *("N" if x.startswith("F") else "m/s" for x in extras))
        self._out_meta = StreamMeta(stream=self.online.out_stream, channels=chans, units=units, rig=self.rig.rig,
                                    source=self.online.source, rate_hz=rate)
        free = self.fe.law.free
        self._fit_meta = StreamMeta(stream=self.online.fit_stream,
                                    channels=("n_points", "rms", *free, *(f"{k}_se" for k in free)),
                                    units=("-", "-", *("-",) * (2 * len(free))), rig=self.rig.rig,
                                    source=self.online.source)
        info = {"rig": self.rig.rig, "rate_hz": rate, "n_taps": self.fe.n_taps, "lag": self.fe.lag,
                "delay_s": self.fe.delay_s, "inputs": list(self.model.inputs), "master": meta.stream,
                "fit_free": list(free)}
        self.pub.event("estimator_started", self.online.source, json.dumps(info))

    # ------------------------------------------------------------------ estimation
    def _needed_holds(self) -> list[str]:
        """Slower streams that carry at least one input the position stream lacks."""
        return [s for s, rows in self._hold_rows.items() if rows]

    def _estimate_ready(self) -> int:
        """Estimate the pending samples whose slower inputs are known (or waited for long enough)."""
        if self.fe is None or self._pending is None or self._pending.t.size == 0:
            return 0
        holds = self._needed_holds()
        missing = set(range(len(self.model.inputs))) - set(self._from_master)
        missing -= {r for s in holds for r in self._hold_rows[s]}
        now = time.monotonic()
        if missing:  # a needed stream has not spoken yet: wait, then drop what is too old
            n_old = self._pending.ready(-np.inf, now, self.online.max_wait_s)
            if n_old:
                self._pending.take(n_old)
                if self.stats.unaligned_dropped == 0:
                    names = ", ".join(self.model.inputs[i] for i in sorted(missing))
                    self.pub.event("estimator_waiting", self.online.source, f"no stream carries {names} yet")
                self.stats.unaligned_dropped += n_old
            return 0
        covered = min((self._holds[s].covered_until for s in holds), default=np.inf)
        n = self._pending.ready(covered, now, self.online.max_wait_s)
        if n == 0:
            return 0
        t, xm, sent = self._pending.take(n)
        x = np.empty((len(self.model.inputs), n))
        x[self._from_master] = xm
        for s in holds:
            x[self._hold_rows[s]] = self._holds[s].hold(t)
        first = self.fe.n_seen
        resets = self.fe.resets
        w0 = time.perf_counter()
        est = self.fe.process(t, x)
        if self.fe.resets != resets:
            self.stats.gaps += self.fe.resets - resets
            self.pub.event("estimator_gap", self.online.source, "input time gap: differentiator window restarted")
        if est.size:
            self._publish(est, sent[est.newest - first])
            self.work_log.append(time.perf_counter() - w0)
            self._detect_cycles(est, gap=self.fe.resets != resets)
        return est.size

    def _detect_cycles(self, est: EstimateBlock, gap: bool) -> None:
        """Stick–slip cycles completed in these estimates, as one block of the cycles stream (after the estimates)."""
        if gap:  # what happened in the gap is unknown: start afresh after the last jump in time
            self.cycles.reset()
            jumps = np.flatnonzero(np.diff(est.t) > 1.5 * self.fe.dt)
            est = est if jumps.size == 0 else _tail(est, int(jumps[-1]) + 1)
        done = self.cycles.feed(est.t, est.F, est.N, est.v_rel, est.slip)
        if done:
            self.pub.publish(self._cycle_meta, np.array([c.t for c in done]), np.array([c.row() for c in done]))
            self.stats.cycles += len(done)

    def _publish(self, est: EstimateBlock, sent: np.ndarray) -> None:
        """One output block per processed batch; latency = now minus the carrying input block's send time."""
        cols = [est.F, est.N, est.mu, est.v_rel, est.slip, est.growing, sent]
        cols += [est.extra[k] for k in self.model.extra_names]
        data = np.stack(cols, axis=1).astype(float)
        data[:, 6] = time.monotonic() - sent  # latency: input block sent -> this estimate sent
        self.latency_log.append(float(data[:, 6].max()))
        self.pub.publish(self._out_meta, est.t, data)
        self.stats.blocks_out += 1
        self.stats.samples_out += est.size
        if self._executor is not None or self.online.fit == "inline":
            if self.fe.fit_due(float(est.t[-1])):
                self._schedule_fit()

    # ------------------------------------------------------------------ running fit
    def _schedule_fit(self) -> None:
        """Start a fit of the current window unless one is still running (never queue fits up)."""
        if self._fit_future is not None and not self._fit_future.done():
            return  # the previous fit is still running: skip this round rather than queue
        data = self.fe.fit_window.select(self.est_cfg.fit_max_points)
        if data is None:
            return
        if self._executor is None:
            self._publish_fit(fit_law(self.fe.law, data, self.est_cfg.fit_min_points))
            return
        self._fit_future = self._submit(self.fe.law, data, self.est_cfg.fit_min_points)

    def _submit(self, law, data: FitData, min_points: int) -> Future:
        """Hand a fit to the worker; if the worker process cannot run, fall back to a thread."""
        try:
            return self._executor.submit(fit_law, law, data, min_points)
        except (BrokenExecutor, RuntimeError) as exc:  # e.g. spawn from an unguarded __main__ script
            self._fall_back_to_thread(exc)
            return self._executor.submit(fit_law, law, data, min_points)

    def _fall_back_to_thread(self, exc: BaseException) -> None:
        """Keep fitting (in a thread) when the worker process cannot start, and say so on the bus."""
        self._executor.shutdown(wait=False, cancel_futures=True)
        self._executor = ThreadPoolExecutor(max_workers=1)
        self.pub.event("estimator_notice", self.online.source,
                       f"fit worker process unavailable ({type(exc).__name__}); fitting in a thread")

    def _service_fit(self) -> None:
        """Publish a finished fit; called every poll, never blocks."""
        f = self._fit_future
        if f is not None and f.done():
            self._fit_future = None
            try:
                self._publish_fit(f.result())
            except Exception as exc:  # a failed fit must not stop the estimates
                self.stats.fits_failed += 1
                self.pub.event("friction_fit_failed", self.online.source, str(exc)[:200])

    def _publish_fit(self, r: RunningLawFit) -> None:
        """Every fit as an event (JSON); successful ones also as a sample of the fit stream."""
        self.pub.event("friction_fit", self.online.source, r.model_dump_json())
        if not r.success:
            self.stats.fits_failed += 1
            return
        free = self.fe.law.free
        row = [r.n_points, r.rms, *(r.params[k] for k in free), *(r.stderr.get(k, np.nan) for k in free)]
        self.pub.publish(self._fit_meta, np.array([r.t_end]), np.array([row], dtype=float))
        self.stats.fits_published += 1
        self.last_fit = r


def _tail(est: EstimateBlock, i: int) -> EstimateBlock:
    """The estimates from index ``i`` on."""
    return EstimateBlock(est.index[i:], est.t[i:], est.F[i:], est.N[i:], est.mu[i:], est.v_rel[i:], est.a[i:],
                         est.slip[i:], est.growing[i:], est.newest[i:], {k: v[i:] for k, v in est.extra.items()})
