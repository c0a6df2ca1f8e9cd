"""Stick-slip cycles read from a load signal alone, as a friction lab scores a record: stick time, force drop,
slip duration and period, their distributions, for the record and for a model's free run side by side.

Why from the load signal (the spring's extension, the brake's block position: the rig's primary output) and not
from a relative velocity: a spring-slider lab records the force only, and the model's free run must be read by
the same rule as the record, or the comparison measures the rule. Why distributions and not the pointwise
error: over a record the free run drifts in phase, so pointwise it is wrong by a whole drop while its cycles
may be right (issue 31); and a real contact's sticks differ from one another, which a median and quartiles show.

A cycle runs from one slip's start to the next's. Peaks and valleys of the load alternate with a hysteresis of
``PROMINENCE_SIGMAS`` noise levels (:func:`turning_points`), on the signal after a 5-sample median (an impulsive
spike is no peak); a slip starts at the last sample within ``ONSET_SIGMAS`` noise levels of its peak and ends at
the valley. Per cycle: ``drop`` = peak - valley, ``slip_s`` its duration, ``stick_s`` from the valley to the next
slip's start, ``creep_s`` the part of that spent at the peak load (within ``ONSET_SIGMAS``: a contact that
creeps before it slips holds its load while it moves; a linear rise spends 2 sigma / its loading rate there
anyway, the same on both sides of a comparison), ``period_s`` slip start to slip start, and the loading rates
``load_rate_early`` / ``load_rate_late``: the load's slope (least squares) over the first and the last third of the
stick. Why the two rates: a stuck slider is loaded at the drive's speed (the spring's extension, or the slider
carried by the belt, grows at V), so early / V near 1 says the rig file's mechanics hold while the contact holds,
and late / V well below the early one says the slider moves before it slips: creep, which a contact law that
holds until its static level cannot make (the lab's 42 um/s record: ~1 early, ~0.1 late). Why a slip's start and
not its peak: the lab's 42 um/s record plateaus at its peak for ~0.2 s before it drops (the peak of a noisy
plateau falls anywhere on it, and "slips" of 0.2 s were read). The live detector
(daq/estimation/cycles.py) reads cycles from the estimator's v_rel instead; this one needs only the record.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import medfilt

PROMINENCE_SIGMAS = 6.0  # a drop smaller than this many noise levels is not told from noise on a 2 kHz record
ONSET_SIGMAS = 2.0  # the load has left its peak when it is this many noise levels below it
FEATURES = ("stick_s", "creep_s", "drop", "slip_s", "period_s", "load_rate_early", "load_rate_late")
PHASES = {1: "slip", 2: "loading", 3: "at the peak load"}  # cycle_phases' codes (0: outside any cycle)
INDEX_KEYS = ("i_start", "i_valley", "i_reached", "i_next")  # a cycle's bounds (load_cycles)
MIN_THIRD = 3  # samples a third of a stick needs for its loading rate (else NaN)


def load_cycles(t: np.ndarray, x: np.ndarray, sigma: float) -> dict[str, np.ndarray]:
    """Per cycle of the load signal ``x`` (noise level ``sigma``, same unit): stick_s, creep_s, drop, slip_s,
    period_s, load_rate_early and load_rate_late [unit/s], the slip's start time ``t`` and the peak load ``peak``,
    and the sample indices that bound its phases (``i_start``, ``i_valley``, ``i_reached``, ``i_next``: slip start,
    slip end, peak load reached, next slip start); empty arrays when fewer than three peaks stand out. A cycle runs
    from one slip's start to the next's."""
    x = np.asarray(x, dtype=float)
    xs = medfilt(x, 5) if x.size >= 5 else x
    peaks, valleys = turning_points(xs, PROMINENCE_SIGMAS * max(sigma, 1e-300))
    if peaks.size < 3:
        empty = {k: np.zeros(0) for k in (*FEATURES, "t", "peak")}
        return {**empty, **{k: np.zeros(0, dtype=int) for k in INDEX_KEYS}}
    near = ONSET_SIGMAS * sigma
    # the slip starts where the load leaves its peak for good: the last sample within ``near`` of it before the valley
    starts = np.array([p + int(np.flatnonzero(xs[p:v + 1] >= xs[p] - near)[-1]) for p, v in zip(peaks[:-1], valleys)])
    # the load reaches its peak (within ``near``) first: from there to the slip, the contact holds its peak load
    reached = np.array([v + int(np.flatnonzero(xs[v:s + 1] >= xs[p] - near)[0])
                        for v, s, p in zip(valleys[:-1], starts[1:], peaks[1:-1])])
    s0, s1, v0 = starts[:-1], starts[1:], valleys[:-1]
    early, late = loading_rates(t, xs, v0, s1)
    return {"t": t[s0], "peak": xs[peaks[:-2]], "drop": xs[peaks[:-2]] - xs[v0], "slip_s": t[v0] - t[s0],
            "stick_s": t[s1] - t[v0], "creep_s": t[s1] - t[reached], "period_s": t[s1] - t[s0],
            "load_rate_early": early, "load_rate_late": late,
            "i_start": s0, "i_valley": v0, "i_reached": reached, "i_next": s1}



def loading_rates(t: np.ndarray, x: np.ndarray, v0: np.ndarray, s1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The load's least-squares slope over the first and the last third of each stick (valley ``v0`` to the next
    slip's start ``s1``); NaN where a third has fewer than MIN_THIRD samples."""
    early, late = np.full(v0.size, np.nan), np.full(v0.size, np.nan)
    for c, (a, b) in enumerate(zip(v0, s1)):
        third = (b - a + 1) // 3
        if third >= MIN_THIRD:
            early[c] = np.polyfit(t[a:a + third] - t[a], x[a:a + third], 1)[0]
            late[c] = np.polyfit(t[b - third + 1:b + 1] - t[b], x[b - third + 1:b + 1], 1)[0]
    return early, late


def cycle_phases(n: int, cycles: dict[str, np.ndarray]) -> np.ndarray:
    """Per sample of the signal ``cycles`` was read from (``n`` samples), its phase code (PHASES): slip (slip start
    to valley), loading (valley to the peak load reached), at the peak load (to the next slip's start); 0 outside
    every cycle. Where a model's error lives in the cycle, read from the record alone."""
    code = np.zeros(n, dtype=np.int8)
    for a, v, r, b in zip(*(cycles[k] for k in INDEX_KEYS)):
        code[a:v] = 1
        code[v:r] = 2
        code[r:b] = 3
    return code


def turning_points(x: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Alternating peaks and the lowest point after each (a zig-zag with hysteresis): a peak is confirmed when the
    signal has fallen ``threshold`` below it, the valley when it has risen ``threshold`` above that. Returns peak
    indices and, for every peak but the last, the valley before the next one. Why not prominence alone: two maxima
    a sample apart with a dip of a fifth of a noise level between them both stood out (scipy's find_peaks on a
    noisy sawtooth: 204 peaks for 200 cycles)."""
    peaks, valleys = [], []
    hi_i, lo_i, falling = 0, 0, False
    for i in range(1, x.size):
        if not falling:
            if x[i] > x[hi_i]:
                hi_i = i
            elif x[hi_i] - x[i] >= threshold:
                peaks.append(hi_i)
                falling, lo_i = True, i
        else:
            if x[i] < x[lo_i]:
                lo_i = i
            elif x[i] - x[lo_i] >= threshold:
                valleys.append(lo_i)
                falling, hi_i = False, i
    peaks_a = np.asarray(peaks, dtype=int)
    return peaks_a, np.asarray(valleys[:max(peaks_a.size - 1, 0)], dtype=int)


def summary(cycles: dict[str, np.ndarray]) -> dict[str, float | int]:
    """What a lab quotes: the number of cycles, median and quartiles of each feature, the mean period."""
    n = int(cycles["period_s"].size)
    out: dict[str, float | int] = {"cycles": n}
    for k in FEATURES:
        x = cycles[k][np.isfinite(cycles[k])]
        q = np.quantile(x, [0.25, 0.5, 0.75]) if x.size else np.full(3, np.nan)
        out[f"{k}_q25"], out[f"{k}_median"], out[f"{k}_q75"] = (float(v) for v in q)
    out["period_s_mean"] = float(np.mean(cycles["period_s"])) if n else float("nan")
    return out


# the three figures issue 31 judges a model's free run by (within 10 % of the record's)
JUDGED = ("stick_s_median", "drop_median", "period_s_mean")


def side_by_side(record: dict[str, np.ndarray], model: dict[str, np.ndarray]) -> dict:
    """Both summaries and, for the judged figures, model / record - 1 (NaN where either has no cycles)."""
    a, b = summary(record), summary(model)
    rel = {k: (b[k] / a[k] - 1.0) if a[k] and np.isfinite(a[k]) and np.isfinite(b[k]) else float("nan")
           for k in JUDGED}
    return {"record": a, "model": b, "relative_difference": rel}
