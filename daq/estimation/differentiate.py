"""Causal differentiation: local polynomial (Savitzky-Golay) fits over the last N samples.

Why a lagged causal fit: a friction estimate needs x, x' and x'' from a noisy
position. A least-squares polynomial of degree d over the last N samples,
evaluated ``lag`` samples before the newest one, is a fixed FIR filter that uses
only the past. At lag = (N-1)/2 (the default) it is the classic centred
Savitzky-Golay filter: linear phase, a pure delay of lag samples, the least
noise, and exact for polynomials up to degree d (odd-degree accuracy for free).
At lag = 0 the delay vanishes but the noise grows: x' of a quadratic fit ~3.8x,
x'' of a quartic fit ~5.5x (x'' of a quadratic is the same at any lag, but delayed).
White position noise sigma becomes x'' noise ~ sigma / (dt^2 N^2.5) times a
constant (sqrt(720) for the centred quadratic), which the tolerances quote.
"""

from __future__ import annotations

import math

import numpy as np

from daq.physics.jit import kernel


def sg_coefficients(n: int, degree: int, deriv: int, lag: int, dt: float) -> np.ndarray:
    """FIR taps h (oldest sample first): sum(h * x[k-n+1:k+1]) estimates x^(deriv) at sample k - lag."""
    if not 0 <= lag <= n - 1:
        raise ValueError(f"lag {lag} outside [0, {n - 1}]")
    if degree >= n or deriv > degree:
        raise ValueError(f"need deriv <= degree < n, got deriv={deriv}, degree={degree}, n={n}")
    tau = (np.arange(n) - (n - 1 - lag)).astype(float)  # sample offsets from the evaluation point
    vander = tau[:, None] ** np.arange(degree + 1)[None, :]
    pinv = np.linalg.pinv(vander)  # (degree+1, n): polynomial coefficients from samples
    return pinv[deriv] * math.factorial(deriv) / dt**deriv


def noise_gain(h: np.ndarray) -> float:
    """Standard deviation of the filter output per unit of white input noise."""
    return float(np.sqrt(np.sum(h * h)))


@kernel
def fir_bank(x: np.ndarray, taps: np.ndarray, src: np.ndarray, out: np.ndarray) -> None:
    """out[f, k] = sum_i taps[f, i] * x[src[f], k + i]; x carries n-1 samples of history first.

    One pass for every filter of every channel: O(block * taps), no Python per sample.
    """
    nf, n = taps.shape
    m = out.shape[1]
    for f in range(nf):
        row = x[src[f]]
        h = taps[f]
        for k in range(m):
            acc = 0.0
            for i in range(n):
                acc += h[i] * row[k + i]
            out[f, k] = acc
