"""Regime transitions of a brake run (paper 001, section 5), cycle by cycle and per spectrogram column.

Why two tracks: the paper names its segments by the motion (quasi-steady, period doubling, regular
multiple-frequency, irregular) and by the spectrum ("strip of widening spectrum"); the first is decided
per stick-slip cycle (the peaks of x1), the second per column of the paper's spectrogram of x1'. Every
threshold is a field of :class:`TransitionCfg`, with its rationale in the field's description, and
travels with the result (docs/analyses-001.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field
from scipy import signal

from daq.signals import paper_spectrogram
from daq.strict import Closed

from .kinematics import sample_rate
from .spectra import SPEC_FS, SPEC_NOVERLAP, SPEC_NPERSEG, dominant_line, entropy_bandwidth, subharmonic_db


class TransitionCfg(Closed):
    """Thresholds of the transition detectors (documented in docs/analyses-001.md)."""

    model_config = ConfigDict(frozen=True)
    min_prominence: float = Field(0.05, description="a cycle's peak rises >= this fraction of the run's robust "
                                                    "range (P99.5-P0.5) above its surroundings; below: quiet")
    minor_peak: float = Field(0.25, description="peaks smaller than this fraction of the largest within "
                                                "+-neighbourhood_s are wiggles inside a cycle, not cycles")
    neighbourhood_s: float = Field(1.0, gt=0)
    mismatch_tol: float = Field(0.04, description="tau: a cycle repeats with period n when the n-step second "
                                                  "difference of peak rise and of interval is < tau of their "
                                                  "local median (drift-free; quasi-steady run ~0.01, noise "
                                                  "and period-2 alternation of the paper's Fig. 9b >> 0.05)")
    median_cycles: int = Field(7, ge=3, description="median of the mismatch over this many cycles")
    min_cycles: int = Field(6, ge=1, description="regime runs shorter than this merge into a neighbour")
    max_period: int = Field(4, ge=1, le=4)
    quiet_gap_periods: float = Field(3.0, description="no cycle for this many local periods (and for at least "
                                                      "quiet_min_s): quiet")
    quiet_min_s: float = Field(0.5, ge=0, description="shorter gaps are a missed peak, not a quiet stretch")
    widening_factor: float = Field(2.0, description="widening: entropy bandwidth of x1' > this times the "
                                                    "median over quasi-steady columns")
    widening_min_columns: int = Field(2, ge=1)
    subharmonic_db: float = Field(-30.0, description="f/2 (or 3f/2) line above this, dB re the f line, "
                                                     "confirms period doubling (quasi-steady run: -50 dB)")


class TransitionSegment(Closed):
    """One segment on the timeline: a regime (from cycles) or a widening strip (from the spectrum)."""

    track: Literal["regime", "spectrum"]
    kind: str = Field(description="regime: quasi-steady, period-doubling, period-3, period-4, irregular, quiet; "
                                  "spectrum: widening")
    start_s: float
    end_s: float
    n_cycles: int | None = None
    period_s: float | None = Field(None, description="median cycle interval")
    mismatch_p1: float | None = Field(None, description="median period-1 mismatch in the segment")
    mismatch_p2: float | None = None
    subharmonic_db: float | None = Field(None, description="median f/2 line level re f over the columns inside")
    bandwidth_ratio: float | None = Field(None, description="median entropy bandwidth / reference")


class TransitionResult(Closed):
    """Segments of the run, both tracks, sorted by start."""

    cfg: TransitionCfg
    signal: str
    n_cycles: int
    reference_bandwidth_hz: float
    segments: list[TransitionSegment]


@dataclass
class TransitionTrace:
    """Per-cycle and per-column features behind the segments (for the figure)."""

    cycle_t: np.ndarray
    amp: np.ndarray
    period: np.ndarray  # interval to the next cycle (nan for the last)
    mismatch: np.ndarray  # (max_period, n_cycles) median-filtered mismatch per period n
    label: list[str]
    col_t: np.ndarray
    line_hz: np.ndarray
    sub_db: np.ndarray
    bandwidth_hz: np.ndarray
    spec: tuple[np.ndarray, np.ndarray, np.ndarray] = field(default=None)  # type: ignore[assignment]


def find_cycles(t: np.ndarray, x: np.ndarray, cfg: TransitionCfg) -> tuple[np.ndarray, np.ndarray]:
    """Peak times (parabolic sub-sample) and rises (peak minus the preceding trough) of the cycles of x."""
    lo, hi = np.percentile(x, [0.5, 99.5])
    rng = max(hi - lo, 1e-300)
    pk, props = signal.find_peaks(x, prominence=cfg.min_prominence * rng)
    if pk.size == 0:
        return np.empty(0), np.empty(0)
    prom = props["prominences"]
    fs = sample_rate(t)
    half = max(1, int(round(cfg.neighbourhood_s * fs)))
    keep = np.ones(pk.size, bool)
    j0 = np.searchsorted(pk, pk - half)
    j1 = np.searchsorted(pk, pk + half, side="right")
    for i in range(pk.size):
        keep[i] = prom[i] >= cfg.minor_peak * prom[j0[i]:j1[i]].max()
    pk = pk[keep]
    # sub-sample peak time: parabola through the three samples around the peak
    inner = (pk > 0) & (pk < x.size - 1)
    tp = t[pk].astype(float)
    dt = 1.0 / fs
    k = pk[inner]
    a, b, c = x[k - 1], x[k], x[k + 1]
    den = a - 2 * b + c
    tp[inner] += np.where(den != 0, 0.5 * (a - c) / np.where(den != 0, den, 1.0), 0.0) * dt
    # rise: peak minus the lowest sample since the previous peak (or the signal start)
    starts = np.concatenate([[0], pk[:-1]])
    mins = np.array([x[s:e + 1].min() for s, e in zip(starts, pk)])
    return tp, x[pk] - mins


def _rolling_median(a: np.ndarray, n: int) -> np.ndarray:
    """Centred running median of n (shrinking at the ends), nan-aware."""
    out = np.full(a.size, np.nan)
    h = n // 2
    for i in range(a.size):
        w = a[max(0, i - h): i + h + 1]
        w = w[np.isfinite(w)]
        if w.size:
            out[i] = np.median(w)
    return out


def cycle_mismatch(amp: np.ndarray, period: np.ndarray, n: int, median_cycles: int) -> np.ndarray:
    """Period-n mismatch per cycle: n-step second difference of rise and interval, relative, median-filtered.

    r_n(k) = |a[k+n] - (a[k] + a[k+2n]) / 2| / median(a): zero for any signal that repeats every n cycles
    while drifting linearly (the deceleration), the full alternation |a - b| for period 2 seen with n = 1.
    The larger of the rise and interval values counts; it is assigned to the middle cycle k+n.
    """
    out = np.full(amp.size, np.nan)
    if amp.size < 2 * n + 1:
        return out
    scale_a = _rolling_median(np.abs(amp), 4 * n + 1)
    scale_t = _rolling_median(period, 4 * n + 1)
    ra = np.abs(amp[n:-n] - 0.5 * (amp[:-2 * n] + amp[2 * n:])) / scale_a[n:-n]
    rt = np.abs(period[n:-n] - 0.5 * (period[:-2 * n] + period[2 * n:])) / scale_t[n:-n]
    raw = np.fmax(ra, rt)
    out[n:-n] = raw
    return _rolling_median(out, median_cycles)


def _merge_short(labels: list[str], min_len: int) -> list[str]:
    """Relabel runs shorter than min_len (cycles) as their longer neighbour, shortest first."""
    lab = list(labels)
    while True:
        runs = []
        i = 0
        while i < len(lab):
            j = i
            while j + 1 < len(lab) and lab[j + 1] == lab[i]:
                j += 1
            runs.append((i, j))
            i = j + 1
        short = [(j - i + 1, k) for k, (i, j) in enumerate(runs) if j - i + 1 < min_len and len(runs) > 1]
        if not short:
            return lab
        _, k = min(short)
        i, j = runs[k]
        left = runs[k - 1] if k > 0 else None
        right = runs[k + 1] if k + 1 < len(runs) else None
        pick = max([r for r in (left, right) if r is not None], key=lambda r: r[1] - r[0])
        for q in range(i, j + 1):
            lab[q] = lab[pick[0]]


def detect_transitions(t: np.ndarray, x: np.ndarray, xdot: np.ndarray | None = None,
                       cfg: TransitionCfg = TransitionCfg(), signal_name: str = "x1"
                       ) -> tuple[TransitionResult, TransitionTrace]:
    """Segment a run into regimes (cycle by cycle) and widening strips (spectrogram columns).

    Regime of a cycle: the smallest n in 1..max_period with period-n mismatch < tau gives quasi-steady
    (n = 1), period-doubling (n = 2), period-3/4; none: irregular. Stretches without cycles (gaps longer
    than quiet_gap_periods local periods, or no peak above min_prominence) are quiet. Runs shorter than
    min_cycles merge into their longer neighbour; a boundary lies midway between the two cycles.
    Widening: spectrogram columns (the paper's 512/256 at 100 Hz, on x') whose entropy bandwidth
    exceeds widening_factor x the median over columns centred in quasi-steady segments.
    """
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    tc, amp = find_cycles(t, x, cfg)
    period = np.append(np.diff(tc), np.nan)
    mism = np.vstack([cycle_mismatch(amp, period, n, cfg.median_cycles) for n in range(1, cfg.max_period + 1)]) \
        if tc.size else np.zeros((cfg.max_period, 0))
    labels = _cycle_labels(mism, cfg)
    t0, t1 = float(t[0]), float(t[-1])
    segs = _regime_segments(t0, t1, tc, period, mism, labels, cfg)

    # spectral features per column of the paper's spectrogram, on x' (harmonics weigh more, as in Fig. 5)
    v = np.gradient(x, t) if xdot is None else np.asarray(xdot, float)
    f, ct, pxx = paper_spectrogram(t, v, SPEC_FS, SPEC_NPERSEG, SPEC_NOVERLAP)
    line = dominant_line(f, pxx)
    sub = subharmonic_db(f, pxx, line)
    bw = entropy_bandwidth(f, pxx)
    inside_qs = np.zeros(ct.size, bool)
    for s in segs:
        if s.kind == "quasi-steady":
            inside_qs |= (ct >= s.start_s) & (ct <= s.end_s)
    ref = float(np.median(bw[inside_qs])) if inside_qs.any() else float(np.percentile(bw, 25))
    for s in segs:
        m = (ct >= s.start_s) & (ct <= s.end_s)
        if m.any():
            s.subharmonic_db = float(np.median(sub[m]))
            s.bandwidth_ratio = float(np.median(bw[m]) / ref)
    segs += _widening_segments(ct, bw > cfg.widening_factor * ref, bw, sub, ref, t0, t1, cfg)
    segs.sort(key=lambda s: (s.start_s, s.track))
    res = TransitionResult(cfg=cfg, signal=signal_name, n_cycles=int(tc.size), reference_bandwidth_hz=ref,
                           segments=segs)
    trace = TransitionTrace(tc, amp, period, mism, labels, ct, line, sub, bw, (f, ct, pxx))
    return res, trace


def _cycle_labels(mism: np.ndarray, cfg: TransitionCfg) -> list[str]:
    """Regime of every cycle from its mismatch per period n (see detect_transitions); cycles at the ends
    that cannot be judged take the nearest judged label, and short runs merge into a neighbour."""
    names = {1: "quasi-steady", 2: "period-doubling", 3: "period-3", 4: "period-4"}
    labels = []
    for k in range(mism.shape[1]):
        lab = "irregular"
        for n in range(1, cfg.max_period + 1):
            if np.isfinite(mism[n - 1, k]) and mism[n - 1, k] < cfg.mismatch_tol:
                lab = names[n]
                break
        else:
            if not np.isfinite(mism[:, k]).any():
                lab = None  # too close to an end to judge: takes its neighbour's label
        labels.append(lab)
    judged = [i for i, lab in enumerate(labels) if lab is not None]
    if judged:
        for i in range(len(labels)):
            if labels[i] is None:
                labels[i] = labels[min(judged, key=lambda j: abs(j - i))]
    return _merge_short([str(lab) for lab in labels], cfg.min_cycles)


def _regime_segment(kind: str, a: float, b: float, idx: np.ndarray, period: np.ndarray, mism: np.ndarray,
                    cfg: TransitionCfg) -> TransitionSegment | None:
    """A regime segment from a to b over the cycles ``idx``, with their median interval and mismatches
    (None if empty)."""
    if b <= a:
        return None
    seg = TransitionSegment(track="regime", kind=kind, start_s=a, end_s=b, n_cycles=int(idx.size))
    if idx.size:
        per = period[idx]
        per = per[np.isfinite(per)]
        seg.period_s = float(np.median(per)) if per.size else None
        for n, name in ((1, "mismatch_p1"), (2, "mismatch_p2")):
            if n <= cfg.max_period:
                v = mism[n - 1, idx]
                v = v[np.isfinite(v)]
                setattr(seg, name, float(np.median(v)) if v.size else None)
    return seg


def _regime_segments(t0: float, t1: float, tc: np.ndarray, period: np.ndarray, mism: np.ndarray, labels: list[str],
                     cfg: TransitionCfg) -> list[TransitionSegment]:
    """The regime track over [t0, t1]: runs of cycles of equal label, split at quiet gaps (no cycle for
    quiet_gap_periods local periods, and the run's ends beyond the last cycle)."""
    local_T = _rolling_median(period, 9) if tc.size else np.empty(0)
    segs: list[TransitionSegment] = []

    def add_regime(kind: str, a: float, b: float, idx: np.ndarray) -> None:
        seg = _regime_segment(kind, a, b, idx, period, mism, cfg)
        if seg is not None:
            segs.append(seg)

    if tc.size < 3:
        add_regime("quiet", t0, t1, np.arange(tc.size))
        return segs
    gap_after = np.zeros(tc.size, bool)
    gap_after[:-1] = np.diff(tc) > np.maximum(cfg.quiet_gap_periods * np.nan_to_num(local_T[:-1], nan=np.inf),
                                              cfg.quiet_min_s)
    start_i = 0
    cur_start = t0
    first_T = float(np.nanmedian(period[: min(9, period.size)]))
    if tc[0] - t0 > max(cfg.quiet_gap_periods * first_T, cfg.quiet_min_s):
        add_regime("quiet", t0, float(tc[0] - 0.5 * first_T), np.empty(0, int))
        cur_start = float(tc[0] - 0.5 * first_T)
    for i in range(1, tc.size + 1):
        end_run = i == tc.size or labels[i] != labels[start_i] or gap_after[i - 1]
        if not end_run:
            continue
        idx = np.arange(start_i, i)
        if i == tc.size:
            last_T = float(np.nanmedian(period[max(0, i - 9): i - 1])) if i > 1 else 0.0
            end = float(min(t1, tc[i - 1] + last_T))
            add_regime(labels[start_i], cur_start, end, idx)
            if t1 - tc[i - 1] > max(cfg.quiet_gap_periods * last_T, cfg.quiet_min_s):
                add_regime("quiet", end, t1, np.empty(0, int))
            else:
                segs[-1].end_s = t1
        elif gap_after[i - 1]:
            lt = float(local_T[i - 1]) if np.isfinite(local_T[i - 1]) else float(period[i - 2])
            end = float(tc[i - 1] + lt)
            add_regime(labels[start_i], cur_start, end, idx)
            nxt = float(tc[i] - 0.5 * lt)
            add_regime("quiet", end, nxt, np.empty(0, int))
            cur_start = nxt
        else:
            b = float(0.5 * (tc[i - 1] + tc[i]))
            add_regime(labels[start_i], cur_start, b, idx)
            cur_start = b
        start_i = i
    _merge_adjacent(segs)
    return segs


def _widening_segments(ct: np.ndarray, wide: np.ndarray, bw: np.ndarray, sub: np.ndarray, ref: float, t0: float,
                       t1: float, cfg: TransitionCfg) -> list[TransitionSegment]:
    """Spectrum-track segments over runs of at least widening_min_columns wide columns (centres ``ct``)."""
    half = 0.5 * (SPEC_NPERSEG - SPEC_NOVERLAP) / SPEC_FS
    segs = []
    k = 0
    while k < ct.size:
        if not wide[k]:
            k += 1
            continue
        j = k
        while j + 1 < ct.size and wide[j + 1]:
            j += 1
        if j - k + 1 >= cfg.widening_min_columns:
            a = float(max(t0, ct[k] - half))
            b = float(min(t1, ct[j] + half))
            segs.append(TransitionSegment(track="spectrum", kind="widening", start_s=a, end_s=b,
                                          bandwidth_ratio=float(np.median(bw[k:j + 1]) / ref),
                                          subharmonic_db=float(np.median(sub[k:j + 1]))))
        k = j + 1
    return segs


def _merge_adjacent(segs: list[TransitionSegment]) -> None:
    """Join consecutive regime segments of the same kind (e.g. split by a gap that was not quiet)."""
    i = 0
    while i + 1 < len(segs):
        a, b = segs[i], segs[i + 1]
        if a.kind == b.kind and abs(a.end_s - b.start_s) < 1e-9:
            a.end_s = b.end_s
            a.n_cycles = (a.n_cycles or 0) + (b.n_cycles or 0)
            del segs[i + 1]
        else:
            i += 1
