"""Paper 001's spectrogram settings and the features read off each of its columns.

Why fixed settings: the paper shows MATLAB ``spectrogram(signal, 512, 256, [], 1E2)`` (Figs. 4, 5, 10),
and our spectrograms must be comparable with its figures; they are computed by
:func:`daq.signals.paper_spectrogram` with the constants below. Per column we read the dominant line (the
stick-slip frequency), the level of an f/2 or 3f/2 line (confirms period doubling) and an entropy
bandwidth (spectral widening); the transition detectors and the figures use them.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from daq.strict import Closed

SPEC_FS = 100.0  # the paper's spectrogram: MATLAB spectrogram(signal, 512, 256, [], 1E2)
SPEC_NPERSEG = 512
SPEC_NOVERLAP = 256
BAND_HZ = (0.5, 45.0)  # spectral features: above the constant-shift line, below Nyquist of 100 Hz


class SpectrogramResult(Closed):
    """The paper's spectrogram settings and the dominant spectral line of x1 per column."""

    fs_hz: float = SPEC_FS
    nperseg: int = SPEC_NPERSEG
    noverlap: int = SPEC_NOVERLAP
    times_s: list[float]
    line_hz: list[float] = Field(description="dominant line of x1 in 0.5-45 Hz, per column")
    line_hz_velocity: list[float] = Field(description="dominant line of x1' in 0.5-45 Hz, per column")
    modes_hz: list[float] = Field(description="linearised eigenfrequencies about the equilibrium (our equations)")


def dominant_line(f: np.ndarray, pxx: np.ndarray, band: tuple[float, float] = BAND_HZ) -> np.ndarray:
    """Frequency of the strongest bin per column in the band, refined by a parabola through log power."""
    m = (f >= band[0]) & (f <= band[1])
    fb, pb = f[m], np.log(pxx[m] + 1e-300)
    k = np.argmax(pb, axis=0)
    out = fb[k].astype(float)
    df = fb[1] - fb[0]
    inner = (k > 0) & (k < fb.size - 1)
    j = np.arange(pb.shape[1])[inner]
    kk = k[inner]
    a, b, c = pb[kk - 1, j], pb[kk, j], pb[kk + 1, j]
    den = a - 2 * b + c
    off = np.where(den != 0, 0.5 * (a - c) / np.where(den != 0, den, 1.0), 0.0)
    out[inner] += np.clip(off, -0.5, 0.5) * df
    return out


def subharmonic_db(f: np.ndarray, pxx: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Level of the strongest bin within 2 bins of f/2 or 3f/2, in dB re the f line, per column."""
    df = f[1] - f[0]
    out = np.full(line.size, -np.inf)
    for j, f1 in enumerate(line):
        p1 = pxx[np.argmin(np.abs(f - f1)), j]
        best = 0.0
        for fc in (0.5 * f1, 1.5 * f1):
            m = np.abs(f - fc) <= 2 * df
            if m.any() and fc >= BAND_HZ[0]:
                best = max(best, float(pxx[m, j].max()))
        out[j] = 10 * np.log10(max(best, 1e-300) / max(p1, 1e-300))
    return out


def entropy_bandwidth(f: np.ndarray, pxx: np.ndarray, band: tuple[float, float] = BAND_HZ) -> np.ndarray:
    """Bin width times exp(spectral entropy) in the band: ~ the main lobe for one line, the band for noise.

    Why entropy: it counts effectively occupied bins smoothly (a harmonic crossing a percentile level
    makes occupied-bandwidth measures jump); k equal lines give k main lobes, a sweep gives its range.
    """
    m = (f >= band[0]) & (f <= band[1])
    p = pxx[m]
    p = p / np.maximum(p.sum(axis=0, keepdims=True), 1e-300)
    h = -np.sum(np.where(p > 0, p * np.log(np.where(p > 0, p, 1.0)), 0.0), axis=0)
    return (f[1] - f[0]) * np.exp(h)
