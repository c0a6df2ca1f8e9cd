"""What the web page can ask for: each stream's recent samples and a whole-run envelope, decimated per pixel.

Why decimate on the server: a 10 s window of the brake rig's 1 kHz streams is ~10 000
points per channel, a whole run millions; a browser plot wants one column per pixel.
Each column carries the **min and max** of its samples (an envelope), so a one-sample
spike is still drawn at any zoom, which plain subsampling would lose.

Columns sit on a fixed grid, column ``k`` covering ``[k dt, (k+1) dt)`` of the run time
(seconds since the web process started), so the column that is still filling can be
sent again and replaced on the page, and a new frame only carries columns from the last
one sent on. Columns are sparse (only those with samples, so a 10 Hz stream on a 10 ms
grid is still a connected line); a real gap (no sample for five sample periods, or half
a second) gets an empty column so the page draws a break.

Two stores per stream: the raw blocks of the last ``raw_s`` seconds (windows up to that
length are decimated from the samples themselves) and an :class:`EnvelopeArchive` of
the whole run at a coarser width that doubles whenever it fills (longer windows are
decimated from it; its memory is bounded whatever the run's length). The archive is read
``ARCHIVE_SLICE`` buckets at a time, in place, so what a frame allocates does not grow
with the run either (issue 29's soak: copies of the whole archive, made for every
whole-run and 5-minute view, grew the process's heap ~1.5 MB per view cycle).

Decision record: docs/decisions/0020-live-web-page.md.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from daq.io.stream_format import StreamMeta

RAW_S = 120.0  # seconds of raw samples kept per stream (windows up to this long use them)
ARCHIVE_W0 = 0.05  # initial width of a whole-run envelope bucket [s]
ARCHIVE_CAP = 32_768  # buckets before the archive halves its resolution
ARCHIVE_SLICE = 4096  # buckets the archive is read in at once (a frame's and a halving's temporaries: this many,
# never the whole archive)
GAP_PERIODS = 5.0  # no sample for this many periods is a gap ...
GAP_MIN_S = 0.5  # ... and never less than this
GAP_IRREGULAR_S = 10.0  # a stream without a nominal rate has a gap after this long a silence


@dataclass
class Columns:
    """Envelope columns of one stream: column ``k[i]`` spans ``[k dt, (k+1) dt)``; lo/hi (n_channels, n)."""

    dt: float
    k: np.ndarray  # int64 column indices, increasing
    lo: np.ndarray  # float64 (n_channels, n); NaN = gap
    hi: np.ndarray

    @property
    def n(self) -> int:
        return int(self.k.size)


def envelope(t: np.ndarray, data: np.ndarray, dt: float, gap_s: float) -> Columns:
    """Min/max of ``data`` (n, n_channels) per column of width ``dt``, over time ``t`` (non-decreasing).

    NaN samples are ignored (fmin/fmax). Where two consecutive columns with samples are more
    than ``gap_s`` apart, an all-NaN column is inserted right after the first, so a plot breaks there.
    """
    nc = data.shape[1] if data.ndim == 2 else 1
    if t.size == 0:
        return Columns(dt, np.zeros(0, np.int64), np.zeros((nc, 0)), np.zeros((nc, 0)))
    k = np.floor(t / dt).astype(np.int64)
    starts = np.flatnonzero(np.concatenate(([True], k[1:] != k[:-1])))
    d = data.reshape(t.size, nc).astype(np.float64, copy=False)
    lo = np.fmin.reduceat(d, starts, axis=0).T
    hi = np.fmax.reduceat(d, starts, axis=0).T
    return _with_gaps(Columns(dt, k[starts], lo, hi), gap_s)


def _with_gaps(c: Columns, gap_s: float) -> Columns:
    """Insert an empty column after each column followed by a silence longer than ``gap_s``."""
    if c.n < 2:
        return c
    jump = np.flatnonzero(np.diff(c.k) * c.dt > gap_s + c.dt)
    if jump.size == 0:
        return c
    k = np.insert(c.k, jump + 1, c.k[jump] + 1)
    nan = np.full((c.lo.shape[0], jump.size), np.nan)
    return Columns(c.dt, k, np.insert(c.lo, jump + 1, nan, axis=1), np.insert(c.hi, jump + 1, nan, axis=1))


def rebucket(c: Columns, dt: float, gap_s: float) -> Columns:
    """Coarser columns (``dt`` >= ``c.dt``) from finer ones: a bucket joins the column its start falls in."""
    if c.n == 0:
        return Columns(dt, c.k, c.lo, c.hi)
    kd = np.floor(c.k * (c.dt / dt) + 1e-9).astype(np.int64)
    starts = np.flatnonzero(np.concatenate(([True], kd[1:] != kd[:-1])))
    lo = np.fmin.reduceat(c.lo, starts, axis=1)
    hi = np.fmax.reduceat(c.hi, starts, axis=1)
    return _with_gaps(Columns(dt, kd[starts], lo, hi), gap_s)


class EnvelopeArchive:
    """A whole run's min/max envelope at a width that doubles whenever ``cap`` buckets are filled."""

    def __init__(self, n_channels: int, w0: float = ARCHIVE_W0, cap: int = ARCHIVE_CAP) -> None:
        self.w = w0
        self.cap = cap
        self.n = 0
        # written through now (np.full, not np.zeros, whose pages become resident only as buckets fill): at 20
        # buckets/s the archive took 27 min to fill, growing the web process ~0.4 MB/min (issue 29's soak)
        self.k = np.full(cap, 0, np.int64)
        self.lo = np.full((n_channels, cap), np.nan)
        self.hi = np.full((n_channels, cap), np.nan)

    def add(self, t: np.ndarray, data: np.ndarray) -> None:
        """Fold samples in (times after everything added before)."""
        self._append(envelope(t, data, self.w, math.inf))

    def _append(self, c: Columns) -> None:
        """Append columns of width ``self.w``, merging the first into the last bucket if it continues it."""
        merge = int(bool(self.n and c.n and c.k[0] == self.k[self.n - 1]))
        if self.n + c.n - merge > self.cap:
            self._halve()
            return self._append(rebucket(c, self.w, math.inf))
        self._put(c)

    def _put(self, c: Columns) -> None:
        """Write columns of width ``self.w`` after the last bucket (merging into it if the first continues it).
        Room is the caller's to check."""
        i = 0
        if self.n and c.n and c.k[0] == self.k[self.n - 1]:  # the last bucket is still filling
            j = self.n - 1
            self.lo[:, j] = np.fmin(self.lo[:, j], c.lo[:, 0])
            self.hi[:, j] = np.fmax(self.hi[:, j], c.hi[:, 0])
            i = 1
        m = c.n - i
        self.k[self.n:self.n + m] = c.k[i:]
        self.lo[:, self.n:self.n + m] = c.lo[:, i:]
        self.hi[:, self.n:self.n + m] = c.hi[:, i:]
        self.n += m

    def _slices(self, i0: int = 0) -> list[Columns]:
        """The buckets from ``i0`` on as views, ``ARCHIVE_SLICE`` at a time (no copy of the archive)."""
        return [Columns(self.w, self.k[a:b], self.lo[:, a:b], self.hi[:, a:b])
                for a in range(i0, self.n, ARCHIVE_SLICE) for b in (min(a + ARCHIVE_SLICE, self.n),)]

    def _halve(self) -> None:
        """Double the bucket width: pairs of buckets become one (the envelope is kept exactly). In place, a slice
        at a time: a slice's merged buckets land at or before its start, so no bucket is overwritten unread."""
        slices = list(self._slices())  # views at the old width
        self.n, self.w = 0, 2 * self.w
        for c in slices:
            self._put(rebucket(c, self.w, math.inf))  # rebucket's arrays are new, never views of the archive

    def columns(self) -> Columns:
        return Columns(self.w, self.k[:self.n].copy(), self.lo[:, :self.n].copy(), self.hi[:, :self.n].copy())

    def columns_from(self, t_from: float, dt: float, gap_s: float) -> Columns:
        """Columns of width ``max(dt, w)`` from run time ``t_from`` on, read a slice at a time: what this allocates
        is a slice's and the answer's, whatever the archive holds."""
        dt = max(dt, self.w)
        i0 = int(np.searchsorted(self.k[:self.n], math.floor(t_from / self.w)))
        parts = [rebucket(c, dt, math.inf) for c in self._slices(i0)]
        if len(parts) <= 1:
            return _with_gaps(parts[0], gap_s) if parts else envelope(np.zeros(0), np.zeros((0, self.lo.shape[0])), dt,
                                                                      gap_s)
        # a column may straddle two slices: rebucket at the same width merges it (and inserts the gaps)
        joined = Columns(dt, np.concatenate([p.k for p in parts]), np.concatenate([p.lo for p in parts], axis=1),
                         np.concatenate([p.hi for p in parts], axis=1))
        return rebucket(joined, dt, gap_s)


class StreamHistory:
    """One stream on the page: its metadata, raw blocks of the last ``raw_s`` seconds, the whole-run archive.

    Times are run times (seconds since the web process's origin). Not thread-safe: the caller locks.
    """

    def __init__(self, meta: StreamMeta, raw_s: float = RAW_S) -> None:
        self.meta = meta
        self.raw_s = raw_s
        self.blocks: deque[tuple[np.ndarray, np.ndarray]] = deque()
        self.archive = EnvelopeArchive(len(meta.channels))
        self.first_t: float | None = None
        self.last_t: float | None = None
        self.samples = 0
        # without a nominal rate (one sample per law fit, say) only a long silence is a gap
        self.gap_s = max(GAP_MIN_S, GAP_PERIODS / meta.rate_hz) if meta.rate_hz else GAP_IRREGULAR_S

    def add(self, t: np.ndarray, data: np.ndarray) -> None:
        """A block's samples (run time, (n, n_channels)); blocks arrive in time order per stream."""
        if t.size == 0:
            return
        # a copy, never a view: a bus block's data is a view on its ZeroMQ message, whose receive buffer (shared by
        # the messages received with it) a kept view holds alive. 120 s of views held ~250 MB of buffers for ~12 MB
        # of samples, and more once a large message had grown the buffers (issue 29's soak: +100 MB at minute 24)
        data = np.array(data, dtype=np.float64).reshape(t.size, len(self.meta.channels))
        self.blocks.append((t, data))
        self.archive.add(t, data)
        if self.first_t is None:
            self.first_t = float(t[0])
        self.last_t = float(t[-1])
        self.samples += t.size
        horizon = self.last_t - self.raw_s
        while len(self.blocks) > 1 and self.blocks[0][0][-1] < horizon:
            self.blocks.popleft()

    @property
    def raw_from(self) -> float:
        """The earliest run time the raw blocks still hold."""
        return float(self.blocks[0][0][0]) if self.blocks else math.inf

    def raw_since(self, t_from: float) -> tuple[np.ndarray, np.ndarray]:
        """Raw samples with t >= t_from (walking back from the newest block)."""
        picked: list[tuple[np.ndarray, np.ndarray]] = []
        for t, d in reversed(self.blocks):
            picked.append((t, d))
            if t[0] < t_from:
                break
        if not picked:
            return np.zeros(0), np.zeros((0, len(self.meta.channels)))
        picked.reverse()
        t = np.concatenate([p[0] for p in picked]) if len(picked) > 1 else picked[0][0]
        d = np.concatenate([p[1] for p in picked]) if len(picked) > 1 else picked[0][1]
        keep = t >= t_from
        return t[keep], d[keep]

    def first_after(self, t: float) -> float | None:
        """The time of the first sample later than ``t`` (None if there is none)."""
        found = None
        for bt, _ in reversed(self.blocks):
            if bt[-1] <= t:
                break
            i = int(np.searchsorted(bt, t, side="right"))
            found = float(bt[i])
            if i > 0:
                break
        return found

    def columns(self, k_from: int, dt: float) -> Columns:
        """Envelope columns from column ``k_from`` on at width ``dt``: from the raw samples if they reach back
        that far, else from the archive (then at least the archive's width)."""
        t_from = k_from * dt
        if t_from >= self.raw_from or self.raw_from == self.first_t:  # the raw blocks cover it (or all there is)
            t, d = self.raw_since(t_from)
            return envelope(t, d, dt, self.gap_s)
        return self.archive.columns_from(t_from, dt, self.gap_s)

    def latest(self) -> dict[str, float] | None:
        """The newest sample of every channel (for the page's numbers), or None before the first."""
        if not self.blocks:
            return None
        t, d = self.blocks[-1]
        return {"t": float(t[-1]), **{c: float(v) for c, v in zip(self.meta.channels, d[-1])}}

    def tail(self, seconds: float, max_points: int) -> tuple[np.ndarray, np.ndarray]:
        """The last ``seconds`` of raw samples, thinned evenly to at most ``max_points`` (a scatter plot's)."""
        if self.last_t is None:
            return np.zeros(0), np.zeros((0, len(self.meta.channels)))
        t, d = self.raw_since(self.last_t - seconds)
        if t.size > max_points:
            idx = np.linspace(0, t.size - 1, max_points).astype(np.int64)
            t, d = t[idx], d[idx]
        return t, d
