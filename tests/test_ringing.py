"""How a ringing's frequency moves with its amplitude (daq.signals.ringing_by_amplitude): one frequency for a linear
oscillator whatever its amplitude, the law back for one that softens, and the lab's 4.3 mm/s record (issue 31):
above the rig file's natural frequency, most at small amplitude."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.io as sio

from daq.signals import frequency_against_amplitude, noise_sigma, ringing_by_amplitude

RATE = 2000.0
NOISE = 1e-6  # m, the lab gauge's level
RECORD = Path(__file__).parent / "data" / "real-slider" / "k2254Nm_v4300.mat"


def _ringing(freq_of_amp, seconds: float = 3.8, seed: int = 0) -> np.ndarray:
    """A ringing whose amplitude wanders between 3 and 19 um, at the frequency ``freq_of_amp(amplitude)``, with
    white noise and a slow drift."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE)) / RATE
    amp = 11e-6 + 8e-6 * np.sin(2 * np.pi * 0.7 * t + 0.3)
    phase = 2 * np.pi * np.cumsum(freq_of_amp(amp)) / RATE
    return 1e-4 + 2e-6 * t + amp * np.sin(phase) + NOISE * rng.standard_normal(t.size)


def test_a_linear_oscillator_rings_at_one_frequency_whatever_its_amplitude():
    x = _ringing(lambda a: np.full_like(a, 57.0))
    r = frequency_against_amplitude(*ringing_by_amplitude(x, RATE, 55.0, NOISE))
    assert r["windows"] > 200
    assert abs(r["line_Hz_small"] - 57.0) < 0.3 and abs(r["line_Hz_large"] - 57.0) < 0.3, r
    assert r["p"] > 0.01 or abs(r["rho"]) < 0.15, r  # no dependence beyond chance


def test_a_softening_oscillator_gives_its_law_back():
    law = lambda a: 62.0 - 0.5e6 * a  # noqa: E731 - 60.5 Hz at 3 um, 52.5 Hz at 19 um
    x = _ringing(law, seed=1)
    r = frequency_against_amplitude(*ringing_by_amplitude(x, RATE, 57.0, NOISE))
    assert r["rho"] < -0.8 and r["p"] < 1e-6, r
    # the quartiles' medians sit on the law at amplitudes inside each quarter
    assert law(r["amplitude_q25"]) - 0.5 <= r["line_Hz_small"] <= law(3e-6) + 0.5, r
    assert law(19e-6) - 0.5 <= r["line_Hz_large"] <= law(r["amplitude_q75"]) + 0.5, r


def test_too_few_windows_say_nothing():
    r = frequency_against_amplitude(*ringing_by_amplitude(_ringing(lambda a: 57.0 + 0 * a, seconds=0.05), RATE,
                                                          57.0, NOISE))
    assert r["windows"] < 8 and np.isnan(r["rho"]) and np.isnan(r["line_Hz_small"])


def test_the_lab_record_at_4_3_mm_s_rings_above_the_rig_most_at_small_amplitude():
    """The rig file's mechanics (k 2254 N/m, m 30.7 g) ring at 43.1 Hz. The record: ~57 Hz in its smallest quarter of
    windows, lower in its largest, so while it slides something stiffens the slider beyond the spring, most at small
    amplitude (decision 30)."""
    d = sio.loadmat(RECORD)
    x = d["Fnorm"].ravel() * 0.0307 * 9.81 / 2254.0
    natural = np.sqrt(2254.0 / 0.0307) / (2 * np.pi)
    r = frequency_against_amplitude(*ringing_by_amplitude(x, RATE, 56.9, noise_sigma(x)))
    assert r["windows"] > 250
    assert r["line_Hz_small"] > 1.25 * natural and r["line_Hz_small"] > r["line_Hz_large"] + 1.5, r
    assert r["rho"] < -0.15 and r["p"] < 1e-3, r
