"""Spectral tools used as the papers use them."""

from __future__ import annotations

import numpy as np
from scipy import signal


def resample_to(t: np.ndarray, x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Resample a uniformly sampled signal to rate fs (anti-aliased polyphase when decimating)."""
    fs_in = 1.0 / np.median(np.diff(t))
    if abs(fs_in - fs) / fs < 1e-9:
        return t, x
    from fractions import Fraction

    fr = Fraction(fs / fs_in).limit_denominator(1000)
    y = signal.resample_poly(x - x.mean(), fr.numerator, fr.denominator) + x.mean()
    ty = t[0] + np.arange(y.size) / fs
    return ty, y


def paper_spectrogram(t: np.ndarray, x: np.ndarray, fs: float = 100.0, nperseg: int = 512,
                      noverlap: int = 256) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paper 001's MATLAB ``spectrogram(signal, 512, 256, [], 1E2)``: Hamming window 512, overlap 256,
    nfft = max(256, 2^nextpow2(512)) = 512, at 100 Hz. Returns (f [Hz], t [s], PSD)."""
    ts, xs = resample_to(t, x, fs)
    nperseg = min(nperseg, xs.size)
    noverlap = min(noverlap, nperseg - 1)
    f, tt, pxx = signal.spectrogram(xs, fs=fs, window="hamming", nperseg=nperseg, noverlap=noverlap,
                                    nfft=max(256, 1 << (nperseg - 1).bit_length()), detrend=False,
                                    scaling="density", mode="psd")
    return f, tt + ts[0], pxx


def dominant_frequency(t: np.ndarray, x: np.ndarray, fmin: float = 0.5) -> float:
    """Frequency of the largest spectral peak above fmin (Welch, Hann)."""
    fs = 1.0 / np.median(np.diff(t))
    nper = min(x.size, int(fs * 8))
    f, p = signal.welch(x - x.mean(), fs=fs, nperseg=nper)
    m = f >= fmin
    return float(f[m][np.argmax(p[m])])
