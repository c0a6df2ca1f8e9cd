"""Stick-slip cycles read from a load signal alone, as a friction lab scores a record: stick time, force drop,
slip duration and period, their distributions, for the record and for a model's free run side by side.

Why from the load signal (the spring's extension, the brake's block position: the rig's primary output) and not
from a relative velocity: a spring-slider lab records the force only, and the model's free run must be read by
the same rule as the record, or the comparison measures the rule. Why distributions and not the pointwise
error: over a record the free run drifts in phase, so pointwise it is wrong by a whole drop while its cycles
may be right (issue 31); and a real contact's sticks differ from one another, which a median and quartiles show.

A cycle is read between two load peaks: the peak is where the contact lets go (the static threshold), the
lowest load before the next peak is where the slip ends; peaks and valleys alternate with a hysteresis of
``PROMINENCE_SIGMAS`` noise levels (:func:`turning_points`), on the signal after a 5-sample median (an
impulsive spike is no peak). Per cycle: ``drop`` = peak - following minimum, ``slip_s`` = its duration,
``stick_s`` = the rise from that minimum to the next peak, ``period_s`` = peak to next peak. The live detector
(daq/estimation/cycles.py) reads cycles from the estimator's v_rel instead; this one needs only the record.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import medfilt

PROMINENCE_SIGMAS = 6.0  # a drop smaller than this many noise levels is not told from noise on a 2 kHz record
FEATURES = ("stick_s", "drop", "slip_s", "period_s")


def load_cycles(t: np.ndarray, x: np.ndarray, sigma: float) -> dict[str, np.ndarray]:
    """Per cycle of the load signal ``x`` (noise level ``sigma``, same unit): stick_s, drop, slip_s, period_s and
    the peak time ``t``; empty arrays when fewer than two peaks stand out."""
    x = np.asarray(x, dtype=float)
    xs = medfilt(x, 5) if x.size >= 5 else x
    peaks, valleys = turning_points(xs, PROMINENCE_SIGMAS * max(sigma, 1e-300))
    if peaks.size < 2:
        return {k: np.zeros(0) for k in (*FEATURES, "t")}
    p0, p1 = peaks[:-1], peaks[1:]
    return {"t": t[p0], "drop": xs[p0] - xs[valleys], "slip_s": t[valleys] - t[p0], "stick_s": t[p1] - t[valleys],
            "period_s": t[p1] - t[p0]}


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
        q = np.quantile(cycles[k], [0.25, 0.5, 0.75]) if n else np.full(3, np.nan)
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
