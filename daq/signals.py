"""Signal helpers shared by the models, the papers' analyses and the figures: one copy each.

Savitzky-Golay smoothing and differentiation (:func:`savgol` in samples, :func:`sg` in seconds),
the white-noise level of a sampled signal (:func:`noise_sigma`), block means (:func:`block_mean`),
and the spectral tools as the papers use them (:func:`paper_spectrogram`, :func:`dominant_frequency`).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
from scipy import signal
from scipy.signal import savgol_filter


def savgol(x: np.ndarray, half: int, deriv: int = 0, dt: float = 1.0, degree: int = 3, axis: int = -1) -> np.ndarray:
    """Centred Savitzky-Golay smoothing or derivative over +-half samples (zero phase, mode 'interp' at the
    ends); a window longer than the data is cut to the longest odd length that fits."""
    size = np.shape(x)[axis]
    n = min(2 * half + 1, size - (1 - size % 2))
    return savgol_filter(x, n, min(degree, n - 1), deriv=deriv, delta=dt, mode="interp", axis=axis)


def sg(x: np.ndarray, rate: float, half_s: float, deriv: int = 0, degree: int = 3, min_half: int = 3) -> np.ndarray:
    """:func:`savgol` over +-half_s seconds of a signal sampled at ``rate`` (at least +-min_half samples)."""
    return savgol(x, max(min_half, int(round(half_s * rate))), deriv, 1.0 / rate, degree)


def noise_sigma(x: np.ndarray) -> float:
    """White-noise level from third differences (MAD, robust to the sparse stick-slip kinks).

    For white noise of level s, third differences have variance 20 s^2. An upper bound when
    the signal itself has energy near the sampling rate (slow sampling). NaN below 11 samples.
    """
    d3 = np.diff(x, 3)
    if d3.size < 8:
        return float("nan")
    mad = np.median(np.abs(d3 - np.median(d3)))
    return float(1.4826 * mad / math.sqrt(20.0))


def block_mean(x: np.ndarray, q: int) -> np.ndarray:
    """Means of consecutive blocks of ``q`` samples (a trailing partial block is dropped): white noise falls by
    sqrt(q); a smooth signal is read at the block's centre to within x'' (q dt)^2 / 24."""
    x = np.asarray(x)
    n = x.size // q
    return x[:n * q].reshape(n, q).mean(axis=1)


def resample_to(t: np.ndarray, x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Resample a uniformly sampled signal to rate fs (anti-aliased polyphase when decimating)."""
    fs_in = 1.0 / np.median(np.diff(t))
    if abs(fs_in - fs) / fs < 1e-9:
        return t, x

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
