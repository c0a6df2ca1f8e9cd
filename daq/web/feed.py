"""The web process's side of the bus: one subscriber for every page, and each page's frames built from it.

Why one subscriber and per-page cursors: the web process is a bus client like the recorder
(its own SUB socket with a bounded high-water mark; the PUB drops for it rather than wait,
so no page can slow acquisition). Every block goes into the stream's
:class:`~daq.web.history.StreamHistory`; every event into one bounded ring (drop-oldest).
A page never has a queue of its own that could grow: its :class:`ClientSession` keeps
cursors (the last column sent per stream, the last event sent) and each frame is built
from the histories when the page can take one, so a page that falls behind gets one
larger frame, and one that stops reading gets nothing more (at most ``max_unacked``
frames are in flight to it) while the others go on.

Decision record: docs/decisions/0020-live-web-page.md.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np

from daq.background import BackgroundLoop
from daq.estimation.cycles import CYCLE_STREAM
from daq.io.stream_format import Block, BusEvent
from daq.signals import FloatRing
from daq.streaming.bus import Subscriber

from .history import StreamHistory
from .messages import EventRow, Frame, Scatter, StreamFrame, View

EVENT_RING = 2000  # events kept for pages (drop-oldest)
EVENT_DETAIL_BYTES = 2000  # of an event's detail, UTF-8, kept for pages
EVENT_NAME_BYTES = 64  # of its kind and its source
EVENTS_ON_CONNECT = 300  # a new page gets the newest this many
MAX_EVENTS_PER_FRAME = 500
SCATTER_S = 5.0  # friction against relative velocity over the last seconds
SCATTER_POINTS = 1500
SCATTER_EVERY_S = 0.25
ESTIMATOR_STREAM = "estimator"
CYCLES_KEPT = 20_000  # stick-slip cycles kept for pages (a 160 s ramp has ~1000)
WHOLE_RUN_REFRESH = 2.0  # a whole-run view is rebuilt once its column width is this far off
PAGE_ROUND_TRIP = "(frame built -> drawn)"  # a latency book entry of its own: the page's share


class LatencyBook:
    """Display latency per stream: a sample's host time to the page's acknowledgement that it is drawn.

    Each stream keeps its last ``keep`` latencies in a FloatRing made when the stream is first seen, so its
    memory is resident at once (1.6 MB a stream). Why not a deque of floats: it held the same bound in 4 times
    the memory and reached it only after ``keep`` acknowledgements (over an hour for a page acknowledging 47
    frames a second), growing 0.5 MB/min until then, which a soak cannot tell from a leak (issue 29).
    """

    def __init__(self, keep: int = 200_000) -> None:
        self.by_stream: dict[str, FloatRing] = {}
        self.keep = keep
        self.lock = threading.Lock()

    def add(self, stream: str, seconds: float) -> None:
        with self.lock:
            ring = self.by_stream.get(stream)
            if ring is None:
                ring = self.by_stream[stream] = FloatRing(self.keep)
            ring.append(seconds)

    def summary(self) -> dict[str, dict[str, float]]:
        """p50/p99/max in ms and the count, per stream."""
        with self.lock:
            snap = {k: v.values() for k, v in self.by_stream.items()}
        out = {}
        for k, a in snap.items():
            if a.size:
                out[k] = {"n": int(a.size), "p50_ms": float(np.percentile(a, 50) * 1e3),
                          "p99_ms": float(np.percentile(a, 99) * 1e3), "max_ms": float(a.max() * 1e3)}
        return out

    def clear(self) -> None:
        """Forget the figures; the rings stay (resident memory does not move)."""
        with self.lock:
            for ring in self.by_stream.values():
                ring.clear()


class CycleRing:
    """The last ``keep`` stick-slip cycles: run time and values, in a float64 ring taken whole at the first cycle.

    Why not a deque of dicts: ~580 bytes a cycle instead of 64, and at the brake rig's 7 cycles/s it filled
    its 20 000 only after 45 minutes, growing 0.26 MB/min until then (issue 29's soak); a page's new cycles
    were found by scanning all of them.
    """

    def __init__(self, keep: int) -> None:
        self.keep = keep
        self.channels: tuple[str, ...] = ()
        self.rows: np.ndarray | None = None  # (keep, 1 + channels): t, then each channel
        self.seq = 0  # cycles ever added; cycle n (from 1) sits in row (n - 1) % keep

    def add(self, t_run: np.ndarray, data: np.ndarray, channels: tuple[str, ...]) -> None:
        if self.rows is None or channels != self.channels:
            self.channels = channels
            self.rows = np.full((self.keep, 1 + len(channels)), np.nan)
        for t, row in zip(t_run, data, strict=True):
            self.rows[self.seq % self.keep, 0] = t
            self.rows[self.seq % self.keep, 1:] = row
            self.seq += 1

    def since(self, n: int) -> list[dict[str, float]]:
        """Every cycle kept numbered above ``n``, oldest first, each with its number ``"n"``."""
        if self.rows is None:
            return []
        out = []
        for i in range(max(n, self.seq - self.keep), self.seq):
            row = self.rows[i % self.keep]
            out.append({"n": i + 1, "t": float(row[0]), **{c: float(v) for c, v in zip(self.channels, row[1:])}})
        return out


class EventRing:
    """The last ``keep`` events for pages, in fixed-size rows of one array written through when it is made.

    Why not a deque of EventRow: a row took 1.1 kB (a ``friction_fit`` event's 405-character detail, the model and
    its set of fields) only when its event came, so 2000 of them filled over 33 minutes at the estimator's one
    event a second, growing the page's process 0.07 MB/min, which a soak cannot tell from a leak (issue 29).
    Here the 4.3 MB are resident at once. A detail is kept to its first ``EVENT_DETAIL_BYTES`` of UTF-8 (2000
    characters of ASCII, as before), a kind and a source to ``EVENT_NAME_BYTES``.
    """

    DTYPE = np.dtype([("t", "f8"), ("count", "i8"), ("has_count", "?"), ("kind", f"S{EVENT_NAME_BYTES}"),
                      ("source", f"S{EVENT_NAME_BYTES}"), ("detail", f"S{EVENT_DETAIL_BYTES}")])

    def __init__(self, keep: int) -> None:
        self.keep = keep
        self.rows = np.zeros(keep, self.DTYPE)
        self.rows.view(np.uint8).fill(0)  # every page touched now (np.zeros' pages become resident only when written)
        self.seq = 0  # events ever added; event n (from 1) sits in row (n - 1) % keep

    def add(self, t: float, kind: str, source: str, detail: str, count: int | None) -> None:
        self.rows[self.seq % self.keep] = (t, 0 if count is None else count, count is not None,
                                           kind.encode()[:EVENT_NAME_BYTES], source.encode()[:EVENT_NAME_BYTES],
                                           detail.encode()[:EVENT_DETAIL_BYTES])
        self.seq += 1

    def since(self, n: int, most: int) -> tuple[list[EventRow], int]:
        """At most ``most`` events numbered above ``n``, oldest first, and how many above ``n`` are no longer kept."""
        if self.seq <= n:
            return [], 0
        first = max(1, self.seq - self.keep + 1)
        start = max(n + 1, first)
        out = []
        for i in range(start, min(self.seq, start + most - 1) + 1):
            r = self.rows[(i - 1) % self.keep]
            out.append(EventRow(seq=i, t=float(r["t"]), kind=r["kind"].decode(errors="ignore"),
                                source=r["source"].decode(errors="ignore"),
                                detail=r["detail"].decode(errors="ignore"),
                                count=int(r["count"]) if r["has_count"] else None))
        return out, max(0, first - n - 1)


class BusFeed:
    """Subscribes to the daemon's bus (and the estimator's), keeps histories and events for the pages."""

    def __init__(self, endpoints: list[str], rcvhwm: int, origin: float | None = None) -> None:
        self.origin = time.monotonic() if origin is None else origin
        self.origin_wall = time.time() - (time.monotonic() - self.origin)
        self.sub = Subscriber(endpoints[0], events=True, rcvhwm=rcvhwm, name="web")
        for ep in endpoints[1:]:
            self.sub.sock.connect(ep)
        self.lock = threading.Lock()
        self.streams: dict[str, StreamHistory] = {}
        self.events = EventRing(EVENT_RING)
        self.cycles = CycleRing(CYCLES_KEPT)
        self.status: dict[str, Any] | None = None
        self.status_seq = 0
        self.latency = LatencyBook()
        self._loop = BackgroundLoop(self._receive, "web-bus")

    def start(self) -> "BusFeed":
        self._loop.start()
        return self

    def close(self) -> None:
        self._loop.stop(timeout=2)
        self.sub.close()

    def now(self) -> float:
        """Run time now [s]."""
        return time.monotonic() - self.origin

    # ------------------------------------------------------------------ the bus thread
    def _receive(self) -> None:
        """Take what has arrived (waiting up to 0.1 s for the first message)."""
        msg = self.sub.recv(0.1)
        while msg is not None:
            self._take(msg)
            msg = self.sub.recv(0)

    def _take(self, msg: Block | BusEvent) -> None:
        if isinstance(msg, Block):
            if not msg.header.n:
                return
            if msg.meta.stream == CYCLE_STREAM:  # rows of a table, not samples of a signal: a list for the page
                self._add_cycles(msg)
                return
            with self.lock:
                h = self.streams.get(msg.meta.stream)
                if h is None or h.meta.channels != msg.meta.channels:
                    h = self.streams[msg.meta.stream] = StreamHistory(msg.meta)
                h.add(msg.t - self.origin, msg.data)
        else:
            self.add_event(msg)

    def _add_cycles(self, b: Block) -> None:
        with self.lock:
            self.cycles.add(b.t - self.origin, np.asarray(b.data, dtype=np.float64), tuple(b.meta.channels))

    def add_event(self, ev: BusEvent) -> None:
        with self.lock:
            self.events.add(ev.host_time - self.origin, ev.kind, ev.source, ev.detail, ev.count)

    def set_status(self, status: dict[str, Any]) -> None:
        with self.lock:
            self.status = status
            self.status_seq += 1


class ClientSession:
    """One page: its view, its cursors into the feed, and the frames it has not yet acknowledged."""

    def __init__(self, feed: BusFeed, max_unacked: int) -> None:
        self.feed = feed
        self.max_unacked = max_unacked
        self.view: View | None = None
        self.dt = 0.01
        self.window_s = 10.0
        self.seq = 0
        self.k_sent: dict[str, int] = {}
        self.t_sent: dict[str, float] = {}  # newest sample time already sent, per stream
        self.event_cursor = max(0, feed.events.seq - EVENTS_ON_CONNECT)
        self.status_seq = 0
        self.cycle_cursor = 0  # a new page gets every cycle kept
        self.scatter_at = -math.inf
        self.unacked: dict[int, dict[str, float]] = {}  # seq -> stream -> host time of its oldest new sample
        self.frames_sent = 0

    def set_view(self, view: View) -> None:
        """A new window or width: every stream is sent afresh."""
        self.view = view
        self.k_sent.clear()
        self._choose_dt(self.feed.now())

    def _whole_run_s(self, now: float) -> float:
        with self.feed.lock:  # the bus thread adds streams
            firsts = [h.first_t for h in self.feed.streams.values() if h.first_t is not None]
        return max(now - min(firsts, default=now), 1.0)

    def _choose_dt(self, now: float) -> None:
        v = self.view
        assert v is not None
        self.window_s = v.window_s if v.window_s > 0 else self._whole_run_s(now)
        self.dt = self.window_s / v.width

    @property
    def can_send(self) -> bool:
        return self.view is not None and len(self.unacked) < self.max_unacked

    def ack(self, seq: int) -> None:
        """Frame ``seq`` (and every one before it) is drawn: record each stream's display latency."""
        now = time.monotonic()
        for s in [s for s in self.unacked if s <= seq]:
            for stream, t in self.unacked.pop(s).items():
                self.feed.latency.add(stream, now - t)

    def frame(self) -> Frame | None:
        """Everything new for this page (None if nothing is); call only when :attr:`can_send`."""
        feed = self.feed
        now = feed.now()
        v = self.view
        assert v is not None
        if v.window_s == 0 and self._whole_run_s(now) / v.width > WHOLE_RUN_REFRESH * self.dt:
            self.k_sent.clear()
            self._choose_dt(now)
        streams: dict[str, StreamFrame] = {}
        oldest_new: dict[str, float] = {}
        with feed.lock:
            for name, h in feed.streams.items():
                reset = name not in self.k_sent
                k_from = math.floor((now - self.window_s) / self.dt) if reset else self.k_sent[name]
                cols = h.columns(k_from, self.dt)
                if cols.n == 0 and not reset:
                    continue
                streams[name] = StreamFrame(channels=list(h.meta.channels), units=list(h.meta.units), dt=cols.dt,
                                            reset=reset, k=cols.k.tolist(), lo=cols.lo.tolist(), hi=cols.hi.tolist())
                self.k_sent[name] = int(cols.k[-1]) if cols.n else k_from
                if name in self.t_sent:  # the first frame of a stream holds history, not news: not timed
                    first_new = h.first_after(self.t_sent[name])
                    if first_new is not None:
                        oldest_new[name] = first_new + feed.origin
                self.t_sent[name] = h.last_t
            events, dropped = self._new_events()
            status = None
            if feed.status_seq != self.status_seq and feed.status is not None:
                status, self.status_seq = feed.status, feed.status_seq
            scatter = self._scatter(now)
            cycles = feed.cycles.since(self.cycle_cursor) if feed.cycles.seq > self.cycle_cursor else []
            self.cycle_cursor = feed.cycles.seq
        if not streams and not events and status is None and scatter is None and not cycles:
            return None
        self.seq += 1
        self.unacked[self.seq] = {**oldest_new, PAGE_ROUND_TRIP: time.monotonic()}
        self.frames_sent += 1
        return Frame(seq=self.seq, now=now, origin_wall=feed.origin_wall, window_s=self.window_s, streams=streams,
                     events=events, events_dropped=dropped, status=status, scatter=scatter, cycles=cycles or None)

    def _new_events(self) -> tuple[list[EventRow], int]:
        new, dropped = self.feed.events.since(self.event_cursor, MAX_EVENTS_PER_FRAME)
        if new:
            self.event_cursor = new[-1].seq
        return new, dropped

    def _scatter(self, now: float) -> Scatter | None:
        h = self.feed.streams.get(ESTIMATOR_STREAM)
        if h is None or now - self.scatter_at < SCATTER_EVERY_S:
            return None
        ch = h.meta.channels
        if "v_rel" not in ch or "mu_est" not in ch:
            return None
        self.scatter_at = now
        _, d = h.tail(SCATTER_S, SCATTER_POINTS)
        return Scatter(seconds=SCATTER_S, v_rel=d[:, ch.index("v_rel")].tolist(), mu=d[:, ch.index("mu_est")].tolist())
