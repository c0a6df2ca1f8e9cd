"""The windows a record is cut into for multiple shooting, and the windows' weights in a fit.

Windows are short (about one stick-slip cycle and a half, WINDOW_CYCLES) so phase drift cannot build up,
non-overlapping, spread over the whole record and started where the contact sticks if it does; every third is
held out (scored, never fitted), and a window whose drive changes much faster than the record's typical window
is flagged as a transient (scored in the all-window error, neither fitted nor deciding). In a fit, no window's
cost counts for more than WINDOW_CAP times the median window's (window_weights). The fit itself is
daq/models/fit/shooting.py. Decision records: docs/decisions/0002-output-error-by-multiple-shooting.md,
docs/decisions/0030-real-records-cycles-windows-floor.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .cycle_features import load_cycles
from .data import DRIVE_SMOOTH_S, Measured

WINDOW_CYCLES = 1.5  # window length in stick-slip periods
MIN_WINDOW_SAMPLES = 12
MIN_CYCLES = 10  # fewer load cycles than this in a record: its windows are cut by the spectral line alone
MIN_WINDOWS = 12  # fewer windows starting in stick than this: windows start anywhere the drive moves
HOLE_DRIVE_CHANGE = 0.01  # a hole in the drive's data where it leaves a straight line by this share of its top speed
TRANSIENT_SLOPE = 10.0  # a window whose drive command changes this many times faster than the median is a transient


@dataclass
class Windows:
    starts: np.ndarray  # sample index of each window's start
    length: int  # samples per window, start included
    held_out: np.ndarray  # bool per window: scored but not fitted
    transient: np.ndarray | None = None  # bool per window: the drive accelerates from rest or stops (flagged)

    def select(self, held_out: bool | None) -> np.ndarray:
        """Fit (False) or held-out (True) windows, transients left out; None: every window, transients too."""
        if held_out is None:
            return np.arange(self.starts.size)
        keep = self.held_out == held_out
        if self.transient is not None:
            keep &= ~self.transient
        return np.flatnonzero(keep)

    def scored(self) -> np.ndarray:
        """Every window a score reads: the fit windows, then the held-out ones (flagged transients left out)."""
        return np.concatenate([self.select(False), self.select(True)])


def dominant_period(m: Measured, fmin: float = 0.5) -> float:
    """Period of the strongest oscillation of the primary signal (detrended) [s]."""
    x = m.outputs[m.primary]
    x = x - np.polynomial.polynomial.polyval(np.arange(x.size), np.polynomial.polynomial.polyfit(
        np.arange(x.size), x, 3))
    n = 1 << int(math.ceil(math.log2(max(x.size, 16))))
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size), n))
    f = np.fft.rfftfreq(n, 1.0 / m.rate)
    ok = f >= fmin
    if not ok.any():
        return 1.0
    fpk = f[ok][np.argmax(spec[ok])]
    return 1.0 / fpk if fpk > 0 else 1.0


def cycle_period(m: Measured) -> float:
    """The stick-slip period windows are cut by [s]: the strongest spectral line, unless the record's load cycles
    (cycle_features.load_cycles, at least MIN_CYCLES of them) say otherwise by more than a factor 1.5; then their
    median period. Why: on a real record the strongest line need not be the cycle. The lab's spring-slider at
    1.1 mm/s wanders slowly (line at 0.67 Hz; cycles every 24 ms): windows of 2.2 s held ~90 cycles and the seed
    model's error was 9.0x its floor, 1.7x with windows of 1.5 cycles; at 42 um/s a 50 Hz line (cycles every
    0.6 s) made windows of 30 ms that saw almost no slip. Only cycles that fill at least half the record count:
    on the brake's ramp-B record with velocity strengthening hidden, 24 cycles of 0.12 s fill 3 s of 52 (the
    stick-slip dies out), and windows cut by them made the diagnosis name temperature before the hidden effect;
    the lab's records are 99 % cycles."""
    spectral = dominant_period(m)
    cycles = load_cycles(m.t, m.outputs[m.primary], m.sigma[m.primary])["period_s"]
    if cycles.size < MIN_CYCLES or np.sum(cycles) < 0.5 * (m.t[-1] - m.t[0]):
        return spectral  # too few, or cycles that fill less than half the record: not its rhythm
    median = float(np.median(cycles))
    return spectral if median / 1.5 <= spectral <= 1.5 * median else median


def make_windows(m: Measured, v_stick: float, window_s: float | None = None, max_windows: int = 160,
                 held_out_every: int = 3) -> Windows:
    """Non-overlapping windows spread over the whole record, starting where the contact sticks if it does.

    Why start in stick: there the block moves with the belt, so the unknown start
    velocities are well estimated from the data even at 100 Hz sampling.
    """
    if window_s is None:
        window_s = WINDOW_CYCLES * cycle_period(m)
    L = max(MIN_WINDOW_SAMPLES, int(round(window_s * m.rate)) + 1)
    L = min(L, m.n // 4)
    edge = max(3, int(0.01 * m.rate))  # smoothing filters are less accurate at the very ends
    stuck = np.abs(m.v_rel) < v_stick if m.v_rel is not None else np.zeros(m.n, bool)
    # only where the belt moves: a recording that starts before the drive (or runs on after it stops)
    # says nothing about friction, and there the command and the belt disagree about when motion starts
    moving = np.abs(m.drive_measured) > 0.05 * np.max(np.abs(m.drive_measured))
    moving &= np.abs(m.drive_command) > 0.05 * np.max(np.abs(m.drive_command))
    starts = _window_starts(m.n, L, edge, stuck, moving, in_stick=stuck.mean() > 0.05)
    if len(starts) < MIN_WINDOWS:  # sticks too rare to start enough windows in them: start them anywhere
        starts = max(starts, _window_starts(m.n, L, edge, stuck, moving, in_stick=False), key=len)
    if not starts:
        starts = [edge]
    s = np.asarray(starts, dtype=int)
    if s.size > max_windows:  # evenly spaced subset: the cost stays bounded on long records
        s = s[np.unique(np.linspace(0, s.size - 1, max_windows).round().astype(int))]
    held = (np.arange(s.size) % held_out_every) == held_out_every - 1
    if s.size < 3:
        held[:] = False
    return Windows(s, L, held, transient_windows(m, s, L))


def _window_starts(n: int, L: int, edge: int, stuck: np.ndarray, moving: np.ndarray, in_stick: bool) -> list[int]:
    """Window starts, one window length apart at least; with ``in_stick`` each at the first stuck sample after
    that (a search that finds none within a window length skips it)."""
    starts: list[int] = []
    i = edge
    while i + L + edge <= n:
        if in_stick:
            j = i
            limit = min(n - L - edge, i + L)
            while j < limit and not (stuck[j] and stuck[max(j - 2, 0)] and moving[j] and moving[min(j + L, n - 1)]):
                j += 1
            if j >= limit:
                i = limit + 1
                continue
            i = j
        if not in_stick and not (moving[i] and moving[min(i + L, n - 1)]):
            i += 1
            continue
        starts.append(i)
        i += L
    return starts


def transient_windows(m: Measured, starts: np.ndarray, length: int) -> np.ndarray:
    """Windows in which the drive command changes much faster than over the record's typical window
    (the lead-in from rest, an abrupt stop): the model's drive there is least certain (a regulator ramps
    within its own limits) and one such window can carry more error than all the others together. They
    are flagged, scored in the all-window error and in the report, but neither fit nor decide.
    Both the command (noise-free; a step in it is what a drive lags behind) and the measured speed
    (smoothed over +-0.25 s; it shows the drive's own ramp after a step that came before the window).
    """
    slope = np.maximum(np.abs(np.gradient(m.drive_command, 1.0 / m.rate)),
                       np.abs(np.gradient(m.drive_measured, 1.0 / m.rate)))
    idx = starts[:, None] + np.arange(length)[None, :]
    per_window = slope[idx].max(axis=1)
    typical = float(np.median(per_window))
    scale = max(typical, 1e-3 * float(np.max(np.abs(m.drive_command))))  # a constant drive: tiny median
    out = per_window > TRANSIENT_SLOPE * scale
    if out.sum() > 0.25 * out.size:  # a record that is mostly transients: nothing is flagged
        out[:] = False
    return out | over_filled_spans(m, starts, length)


def over_filled_spans(m: Measured, starts: np.ndarray, length: int) -> np.ndarray:
    """Windows that overlap a stretch the loader filled in across a hole of a stream (daq/io/loading.py,
    ``filled_spans``), widened by the drive's smoothing (DRIVE_SMOOTH_S: a window's start state reads that far):
    every hole in a predicted signal, and a hole in another channel (the drive) where the drive bends.

    Why: there a channel is a straight line, not a measurement. Seen in the closed-loop demo on a loaded machine:
    the motor poller stalled 0.5 s while the belt ran up to speed, the measured drive was a straight line across
    the run-up, and that one held-out window held 74 % of the excess error of every model (measured drive or lag):
    diagnose named the measured drive at 2.5x the noise floor and the test failed. With it flagged, the lag was
    named at 1.12x the floor, tau 0.145 s (truth 0.15). A hole in the drive at constant speed or on a steady ramp
    (the line is right to the tachometer's noise) is left alone: under load the poller leaves a 50-150 ms hole
    every few seconds (six in that 24 s run). They are flagged as a drive transient is (scored in the all-window error, neither fitted nor deciding).
    """
    spans = m.recording.meta.get("filled_spans") if m.recording is not None else None
    out = np.zeros(starts.size, dtype=bool)
    if not spans:
        return out
    first, last = m.t[starts], m.t[np.minimum(starts + length - 1, m.n - 1)]
    top = max(float(np.max(np.abs(m.drive_command))), 1e-12)
    for channel, stretches in spans.items():
        for a, b in stretches:
            if channel not in m.outputs and _straight_across(m, a, b, HOLE_DRIVE_CHANGE * top):
                continue
            out |= (first <= b + DRIVE_SMOOTH_S) & (last >= a - DRIVE_SMOOTH_S)
    return out


def _straight_across(m: Measured, a: float, b: float, tol: float) -> bool:
    """Whether the drive (measured and commanded) runs on one straight line, within ``tol``, through the
    DRIVE_SMOOTH_S before and after the hole [a, b]: then the line drawn across it is what the drive did (a
    constant speed, a steady ramp); otherwise it bent somewhere in the hole (a run-up reaching its set point)."""
    side = ((m.t >= a - DRIVE_SMOOTH_S) & (m.t < a)) | ((m.t > b) & (m.t <= b + DRIVE_SMOOTH_S))
    if side.sum() < 4:
        return False
    for d in (m.drive_measured, m.drive_command):
        line = np.polynomial.polynomial.polyfit(m.t[side], d[side], 1)
        if np.max(np.abs(d[side] - np.polynomial.polynomial.polyval(m.t[side], line))) > tol:
            return False
    return True


WINDOW_CAP = 3.0  # in a fit, no window's cost counts for more than this many times the median window's


def window_weights(costs: np.ndarray, windows: np.ndarray, n_windows: int, cap: float = WINDOW_CAP) -> np.ndarray:
    """Per-window weights that cap each window's share of a fit's cost at ``cap`` x the median window's.

    Why: a few windows (a transient from the record's initial state, a window whose start values sit
    in a poor local minimum) can carry more cost than all the others together; a least-squares fit then
    bends the model's parameters to them and gets worse everywhere else (seen: two windows of 19 at
    170x and 80x the median moved beta to its bound and doubled the held-out error). A window's weight
    is min(1, cap x median / cost): a capped loss at the level of windows, the windows' own start values
    still fitted as before. Windows not in ``windows`` keep weight 1.
    """
    w = np.ones(n_windows)
    if costs.size >= 3:
        m = float(np.median(costs))
        if m > 0:
            w[windows] = np.minimum(1.0, cap * m / np.maximum(costs, 1e-300))
    return w
