"""The device clock on the host clock (daq/signals.py, clock_line): the line under the quickest arrivals, its drift bounded."""

from __future__ import annotations

import numpy as np
import pytest

from daq.signals import MAX_DRIFT, clock_line, quickest_per_bin
from drivers.base import ClockSync

RATE = 1000.0


def _arrivals(seconds, drift, delay, seed=0):
    """Device times of a 1 kHz instrument that runs ``drift`` fast, and host arrival times: host = 5 + device/(1 +
    drift) + a jittery positive delay (0.2-2 ms) + ``delay(device)``."""
    rng = np.random.default_rng(seed)
    d = 100.0 + np.arange(int(seconds * RATE)) / RATE
    h = 5.0 + (d - 100.0) / (1.0 + drift) + 2e-4 + rng.exponential(3e-4, d.size) + delay(d - 100.0)
    return d, h


def test_without_delays_the_line_is_the_clock():
    d = np.linspace(0.0, 60.0, 6001)
    line = clock_line(d, 2.0 + 1.0002 * d)
    assert line.slope == pytest.approx(1.0002, abs=1e-12) and line.offset == pytest.approx(2.0, abs=1e-9)


@pytest.mark.parametrize("drift", [0.0, 300e-6, -300e-6])
def test_a_slow_spell_of_delays_does_not_bend_the_line(drift):
    """A host that reads 150 ms late for six seconds in the middle of a minute, then catches up: the line stays
    on the quickest arrivals before and after the spell (a fit through the lowest 5 % of delays followed it)."""
    spell = lambda t: np.interp(t, [20.0, 26.0, 26.5], [0.0, 0.15, 0.0])  # noqa: E731
    d, h = _arrivals(60.0, drift, spell)
    line = clock_line(d, h)
    assert line.slope == pytest.approx(1.0 / (1.0 + drift), abs=5e-6)
    truth = 5.0 + (d - 100.0) / (1.0 + drift)
    assert np.max(np.abs(line.host(d) - truth - 2e-4)) < 1e-3  # the smallest delay, within a millisecond


def test_a_delay_that_grows_all_run_long_is_not_taken_for_a_clock():
    """The case no arrival fit can resolve: the delay grows by 0.25 % of the run from start to end (a loaded host,
    stop 40's CI). The slope stays within the clocks' tolerance, so the record's time is stretched at most that."""
    d, h = _arrivals(12.0, 0.0, lambda t: 0.0025 * t)
    line = clock_line(d, h)
    assert line.free_slope == pytest.approx(1.0025, abs=2e-4)  # what the arrivals alone say
    assert line.slope == pytest.approx(1.0 + MAX_DRIFT)
    assert np.all(line.host(d) <= h + 1e-12)  # still a line under every arrival


def test_quickest_per_bin_keeps_one_pair_per_bin_in_order():
    d = np.array([0.0, 0.1, 0.2, 0.3, 0.6, 0.55])
    h = d + np.array([5.0, 1.0, 3.0, 2.0, 4.0, 0.5])
    qd, qh = quickest_per_bin(d, h, bin_s=0.25)
    assert qd.tolist() == [0.1, 0.3, 0.55] and (qh - qd).tolist() == pytest.approx([1.0, 2.0, 0.5])


def test_the_live_estimator_and_the_file_reader_fit_the_same_line():
    d, h = _arrivals(30.0, 120e-6, lambda t: 0.05 * (np.sin(t) > 0.9))
    sync = ClockSync()
    for a, b in zip(d, h):
        sync.update(a, b)
    offset, drift = sync.estimate()
    line = clock_line(d, h)
    assert drift == pytest.approx(120e-6, abs=5e-6)
    assert offset + d[-1] / (1.0 + drift) == pytest.approx(line.host(d[-1]), abs=1e-4)
