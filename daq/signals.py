"""Signal helpers shared by the models, the papers' analyses and the figures: one copy each.

Savitzky-Golay smoothing and differentiation (:func:`savgol` in samples, :func:`sg` in seconds),
the white-noise level of a sampled signal (:func:`noise_sigma`), clock jitter seen in a model's residual
(:func:`timing_noise`), block means (:func:`block_mean`), a bounded log of floats resident from the start
(:class:`FloatRing`), the spectral tools as the papers use them (:func:`paper_spectrogram`, :func:`dominant_frequency`), and
a device clock's line on the host clock (:func:`clock_line`, the drivers' live one and the file reader's).
"""

from __future__ import annotations

import math
from fractions import Fraction
from typing import NamedTuple

import numpy as np

# scipy is imported where it is used: the web page's process takes FloatRing from here and nothing of scipy, whose
# import alone made it 69 MB larger (125 MB instead of 57 MB before any data, issue 29's soak)


class FloatRing:
    """The last ``keep`` floats appended, oldest first, in a float64 ring written through when it is made.

    Why not ``deque(maxlen=keep)``: a deque of Python floats holds the same bound in 4 times the memory and
    reaches it only after ``keep`` appends; the estimator's two logs of a million grew 0.51 MB/min through a
    30-minute soak, which a soak cannot tell from a leak (issue 29). Here the memory is resident at once.
    One writer; readers take :meth:`values` (a copy)."""

    def __init__(self, keep: int) -> None:
        self._ring = np.full(keep, np.nan)  # every page touched now
        self._n = 0

    def append(self, x: float) -> None:
        self._ring[self._n % self._ring.size] = x
        self._n += 1

    def __len__(self) -> int:
        return min(self._n, self._ring.size)

    @property
    def capacity(self) -> int:
        return self._ring.size

    def clear(self) -> None:
        """Forget the values; the memory stays (resident memory does not move)."""
        self._n = 0

    def values(self) -> np.ndarray:
        """The floats kept, oldest first."""
        if self._n <= self._ring.size:
            return self._ring[:self._n].copy()
        return np.roll(self._ring, -(self._n % self._ring.size))

    def __iter__(self):
        return iter(self.values().tolist())


def savgol(x: np.ndarray, half: int, deriv: int = 0, dt: float = 1.0, degree: int = 3, axis: int = -1) -> np.ndarray:
    """Centred Savitzky-Golay smoothing or derivative over +-half samples (zero phase, mode 'interp' at the
    ends); a window longer than the data is cut to the longest odd length that fits."""
    from scipy.signal import savgol_filter

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


def timing_noise(residual: np.ndarray, speed: np.ndarray, bins: int = 8, min_rise: float = 2.0,
                 smooth_share: float = 0.25) -> float:
    """Clock jitter [s] from a fitted model's residual: its sample-to-sample part grows with the signal's speed.

    A sample taken at t_i + e_i but stamped t_i reads x(t_i) + x'(t_i) e_i: white noise whose level is
    proportional to the speed. A physical effect the model lacks leaves a residual that is smooth from one
    sample to the next (the brake's 100 Hz aging record without aging in the model: 5 um in every speed band,
    its instrument noise), so the part w_i = r_i - (r_{i-1} + r_{i+1})/2 of the residual ``residual`` (windows
    x samples, model - measured) holds the noise: var(w_i) = 1.5 s0^2 + s_t^2 u_i with
    u_i = v_i^2 + (v_{i-1}^2 + v_{i+1}^2)/4, ``speed`` the model's own rate of the same output.
    Only where the model's motion is smoothest (its acceleration, over the three samples, in the lowest
    ``smooth_share``: on a stick-slip record the sticks, where the block rides the belt): a slip the model
    misplaces by a fraction of a sample also leaves a residual that grows with speed (the 100 Hz accel-sign
    record without accel-sign in the model: 0.38 ms read from every sample, 0.06 ms from the smoothest
    quarter, none after the gate). 0 unless the two fastest of ``bins`` quantile bands of u have a robust
    variance (MAD) ``min_rise`` times the two slowest' (no jitter the data show); else the smaller of two
    non-negative least squares of (s0^2, s_t^2), over the bands' robust variances and over every sample
    (5-sigma outliers trimmed): a model error inflates each in its own way (the aging missing, the bands:
    0.24 ms; accel-sign missing, the samples: 0.32 ms). Measured on the brake's 100 Hz records with 0.2 ms of
    jitter, nothing / aging / accel-sign hidden: 0.192 / 0.193 / 0.194 ms; without jitter: 0 on all three.
    """
    from scipy.optimize import nnls

    r = np.atleast_2d(np.asarray(residual, dtype=float))
    v = np.atleast_2d(np.asarray(speed, dtype=float))
    v2 = v ** 2
    if r.shape[-1] < 3:
        return 0.0
    w = (r[:, 1:-1] - 0.5 * (r[:, :-2] + r[:, 2:])).ravel()
    u = (v2[:, 1:-1] + 0.25 * (v2[:, :-2] + v2[:, 2:])).ravel()
    ok = np.isfinite(w) & np.isfinite(u)
    if smooth_share < 1.0:
        a = np.abs(np.gradient(v, axis=-1))
        a3 = np.maximum(np.maximum(a[:, 1:-1], a[:, :-2]), a[:, 2:]).ravel()
        ok &= a3 <= np.quantile(a3[np.isfinite(a3)], smooth_share)
    w, u = w[ok], u[ok]
    if w.size < 20 * bins:
        return 0.0
    edges = np.quantile(u, np.linspace(0.0, 1.0, bins + 1))
    band = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, bins - 1)
    var, mean_u = np.zeros(bins), np.zeros(bins)
    for b in range(bins):
        sel = band == b
        var[b] = (1.4826 * np.median(np.abs(w[sel]))) ** 2 if sel.any() else np.nan
        mean_u[b] = float(np.mean(u[sel])) if sel.any() else np.nan
    good = np.isfinite(var)
    if good.sum() < 4 or np.mean(var[good][-2:]) < min_rise * np.mean(var[good][:2]):
        return 0.0
    banded, _ = nnls(np.stack([np.full(good.sum(), 1.5), mean_u[good]], axis=1), var[good])
    keep = np.ones(w.size, dtype=bool)  # the same line through every sample, 5-sigma outliers trimmed
    for _ in range(3):
        trimmed, _ = nnls(np.stack([np.full(keep.sum(), 1.5), u[keep]], axis=1), w[keep] ** 2)
        keep = np.abs(w) < 5.0 * np.sqrt(1.5 * trimmed[0] + trimmed[1] * u)
    return float(math.sqrt(min(banded[1], trimmed[1])))


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
    from scipy import signal

    fr = Fraction(fs / fs_in).limit_denominator(1000)
    y = signal.resample_poly(x - x.mean(), fr.numerator, fr.denominator) + x.mean()
    ty = t[0] + np.arange(y.size) / fs
    return ty, y


def paper_spectrogram(t: np.ndarray, x: np.ndarray, fs: float = 100.0, nperseg: int = 512,
                      noverlap: int = 256) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paper 001's MATLAB ``spectrogram(signal, 512, 256, [], 1E2)``: Hamming window 512, overlap 256,
    nfft = max(256, 2^nextpow2(512)) = 512, at 100 Hz. Returns (f [Hz], t [s], PSD)."""
    from scipy import signal

    ts, xs = resample_to(t, x, fs)
    nperseg = min(nperseg, xs.size)
    noverlap = min(noverlap, nperseg - 1)
    f, tt, pxx = signal.spectrogram(xs, fs=fs, window="hamming", nperseg=nperseg, noverlap=noverlap,
                                    nfft=max(256, 1 << (nperseg - 1).bit_length()), detrend=False,
                                    scaling="density", mode="psd")
    return f, tt + ts[0], pxx


def dominant_frequency(t: np.ndarray, x: np.ndarray, fmin: float = 0.5) -> float:
    """Frequency of the largest spectral peak above fmin (Welch, Hann)."""
    from scipy import signal

    fs = 1.0 / np.median(np.diff(t))
    nper = min(x.size, int(fs * 8))
    f, p = signal.welch(x - x.mean(), fs=fs, nperseg=nper)
    m = f >= fmin
    return float(f[m][np.argmax(p[m])])



MAX_RUN = 3  # impulsive noise comes as single samples or bursts of up to this many
RUN_GUARD = 0.4  # runs of two or more are sought only where 99 % of the record's run departures stay below this
# share of the threshold (the motion is resolved: noise alone keeps 99 % of them under 3 noise levels)


def _gap_weights(k: int) -> tuple[np.ndarray, np.ndarray]:
    """The cubic through the two samples on each side of a run of k: node offsets (-2, -1, k, k+1) from the run's
    first sample and, per sample of the run, the Lagrange weights of the four nodes: (4,), (k, 4)."""
    nodes = np.array([-2, -1, k, k + 1])
    w = np.empty((k, 4))
    for j in range(k):
        for m in range(4):
            others = np.delete(nodes, m).astype(float)
            w[j, m] = np.prod((j - others) / (nodes[m] - others))
    return nodes, w


def _single_departures(x: np.ndarray) -> np.ndarray:
    """Each interior sample's departure from the cubic through its two neighbours on each side (ends: 0)."""
    d = np.zeros(x.size)
    if x.size >= 5:
        d[2:-2] = np.abs(x[2:-2] - (-x[:-4] + 4.0 * x[1:-3] + 4.0 * x[3:-1] - x[4:]) / 6.0)
    return d


def impulsive_runs(x: np.ndarray, level: float, max_run: int = MAX_RUN) -> tuple[np.ndarray, np.ndarray]:
    """Runs of 1..max_run samples standing more than ``level`` off the cubic through the two samples on each side
    of the run, replaced by that cubic. Returns (repaired copy, sorted indices of the replaced samples).

    Why runs, not single samples: a burst of two spikes of A pulls the single-sample cubic of each of its samples
    2A/3 towards it (each one's neighbour is the other), so neither stands out, and the clean samples beside it
    stand A/2 off (their cubic reads the burst): a single-sample rule repaired the good neighbours and left the
    burst. A run is a candidate when *every* sample of it stands off (its smallest departure counts); of the
    candidates that overlap, the repair taken is the one after which the run and its nodes are smoothest (the
    largest single-sample departure there is least), one at a time while anything stands off: a single spike is
    a run of one, a burst of two a run of two (a run of one beside it leaves its partner standing off), a burst
    of +A, -A is not read as a spike of 5A/3 beside a clean sample (the largest departure of all), and a run
    whose nodes hold another spike leaves that one standing off among its nodes.

    Why the guard (RUN_GUARD): the wider the gap, the worse a cubic bridges the motion itself. At 100 Hz on the
    brake (12 samples per stick-slip period) runs of three stood up to 12.7 noise levels off on a clean record
    (single samples 4.7; 99 % of them under 9.0): runs of k are sought only when the record's own departures for
    k say the motion is resolved, which at 250 Hz and faster they do (99 % under 3 noise levels, as noise alone;
    the largest then stays under 6). The 99th percentile away from whatever stands off, not the largest:
    bursts do not count against themselves (six in 3000 samples had switched runs off on a clean sine).
    """
    y = np.array(x, dtype=float)
    n = y.size
    if level <= 0 or n < max_run + 8:
        return y, np.zeros(0, dtype=int)
    plans = {k: _gap_weights(k) for k in range(1, max_run + 1)}
    devs = {}
    near = np.zeros(n, dtype=bool)  # within 3 samples of a run that stands off at any k: what the guard leaves out
    for k, (nodes, w) in plans.items():
        starts = np.arange(2, n - k - 1)
        pred = w @ y[starts[None, :] + nodes[:, None]]  # (k, n_starts)
        devs[k] = np.min(np.abs(y[starts[None, :] + np.arange(k)[:, None]] - pred), axis=0)
        for i in np.flatnonzero(devs[k] > level) + 2:
            near[max(i - 3, 0):i + k + 3] = True
    runs = []  # (start, length) of every candidate
    for k in plans:
        quiet = devs[k][~near[2:n - k - 1]]
        if k > 1 and quiet.size and np.percentile(quiet, 99.0) > RUN_GUARD * level:
            break  # this gap (and any wider) cannot bridge the motion to the noise level
        runs += [(int(i) + 2, k) for i in np.flatnonzero(devs[k] > level)]
    taken = np.zeros(n, dtype=bool)
    for cluster in _clusters(sorted(runs)):
        lo = max(cluster[0][0] - 6, 0)
        hi = min(max(i + k for i, k in cluster) + 6, n)
        for _ in range(len(cluster)):  # a neighbourhood may hold several bursts: one repair at a time
            seg = y[lo:hi]
            d = _single_departures(seg)
            if float(np.max(d)) <= level:
                break
            best, best_rough = None, np.inf
            for i, k in cluster:
                nodes, w = plans[k]
                fill = w @ y[i + nodes]
                if np.min(np.abs(y[i:i + k] - fill)) <= level:
                    continue  # (no longer) standing off: an earlier repair took it, or its nodes
                trial = seg.copy()
                trial[i - lo:i - lo + k] = fill
                a, b = max(i - 2 - lo, 0), min(i + k + 2 - lo, hi - lo)  # the run and its nodes
                rough = float(np.max(_single_departures(trial)[a:b]))
                if rough < best_rough:
                    best, best_rough = (i, k, trial), rough
            if best is None or best_rough > level:  # nothing here is a run of up to max_run: left as it is
                break
            i, k, trial = best
            y[lo:hi] = trial
            taken[i:i + k] = True
    return y, np.flatnonzero(taken)


def _clusters(runs: list[tuple[int, int]]) -> list[list[tuple[int, int]]]:
    """Candidate runs (start, length), sorted, grouped where their spans with their nodes (2 each side) overlap."""
    out: list[list[tuple[int, int]]] = []
    end = -10
    for i, k in runs:
        if out and i - 2 <= end:
            out[-1].append((i, k))
            end = max(end, i + k + 2)
        else:
            out.append([(i, k)])
            end = i + k + 2
    return out


RING_PERIODS = 1.5  # each window of ringing_by_amplitude spans this many periods of the line it starts from


def ringing_by_amplitude(x: np.ndarray, rate: float, f_line: float, noise: float, periods: float = RING_PERIODS,
                         max_windows: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude and frequency of a ringing signal ``x``, window by window: a damped sine on a straight line fitted to
    each window of ``periods`` periods of ``f_line`` (windows overlapping by half, after a 5-sample median that takes
    out impulsive noise), kept where the fit leaves no more than twice the ``noise`` level. Returns (amplitude,
    frequency) of the kept windows; at most ``max_windows`` of them, spread over the record (a long record is read at
    that many places: ~2 s on 2 kHz).

    Why: a spring and a mass ring at one frequency whatever the amplitude, and a friction that depends on the speed
    alone changes their damping, not (to first order) their frequency; a line off the rig's natural frequency is then
    a spring or a mass other than the rig file's, or a stiffness the contact adds. How the frequency moves with the
    amplitude is the first reading between them: the small-amplitude end is the stiffness that holds the slider while
    it slides. The lab's 4.3 mm/s record: 58.4 Hz in windows under 5 um, 54.0 Hz over 15 um (Spearman -0.29 on
    281 windows), where the rig file's mechanics ring at 43.1 Hz."""
    from scipy.optimize import least_squares
    from scipy.signal import medfilt

    n = round(periods * rate / f_line)
    if n < 16 or x.size < 2 * n or not np.isfinite(f_line) or f_line <= 0:
        return np.empty(0), np.empty(0)
    y_all = medfilt(np.asarray(x, dtype=float), 5)
    tt = np.arange(n) / rate
    w_lo, w_hi = 0.5 * f_line, 2.0 * f_line
    amps, freqs = [], []
    for i0 in range(0, y_all.size - n + 1, max(n // 2, (y_all.size - n) // max(max_windows - 1, 1) + 1)):
        y = y_all[i0:i0 + n]
        mid, span = float(np.mean(y)), float(np.ptp(y)) + 1e-300

        def resid(p: np.ndarray, y: np.ndarray = y) -> np.ndarray:
            a, b, f, decay, c, s = p
            w = 2.0 * np.pi * f
            return c + s * tt + np.exp(-decay * tt) * (a * np.cos(w * tt) + b * np.sin(w * tt)) - y

        best = None
        for f0 in (0.9 * f_line, f_line, 1.1 * f_line):
            sol = least_squares(resid, [y[0] - mid, 0.0, f0, 0.0, mid, 0.0], x_scale=[span, span, f_line, f_line, span,
                                span * rate], bounds=([-4 * span, -4 * span, w_lo, -f_line, mid - 4 * span, -np.inf],
                                                      [4 * span, 4 * span, w_hi, f_line, mid + 4 * span, np.inf]))
            if best is None or sol.cost < best.cost:
                best = sol
        if np.sqrt(np.mean(best.fun ** 2)) <= 2.0 * noise:
            amps.append(float(np.hypot(best.x[0], best.x[1])))
            freqs.append(float(best.x[2]))
    return np.asarray(amps), np.asarray(freqs)


def frequency_against_amplitude(amps: np.ndarray, freqs: np.ndarray) -> dict:
    """How a ringing's frequency moves with its amplitude (:func:`ringing_by_amplitude`): the median frequency of the
    windows in the lowest and in the highest quarter of the amplitudes, the amplitudes' quartiles, and Spearman's rank
    correlation of frequency with amplitude (rho and its two-sided p), over ``windows`` windows; NaN with fewer than
    8 windows."""
    from scipy.stats import spearmanr

    out = {"windows": int(amps.size), "amplitude_q25": float("nan"), "amplitude_q75": float("nan"),
           "line_Hz_small": float("nan"), "line_Hz_large": float("nan"), "rho": float("nan"), "p": float("nan")}
    if amps.size < 8:
        return out
    q25, q75 = np.percentile(amps, [25, 75])
    res = spearmanr(amps, freqs)
    out.update(amplitude_q25=float(q25), amplitude_q75=float(q75), line_Hz_small=float(np.median(freqs[amps <= q25])),
               line_Hz_large=float(np.median(freqs[amps >= q75])), rho=float(res.statistic), p=float(res.pvalue))
    return out


# --- a device clock on the host clock: the one straight line the drivers (live) and the file reader (offline) fit
#
# An instrument stamps each sample with its own clock; the host sees it arrive later, by a delay that is never
# negative, jitters, and now and then grows for seconds (a loaded host reads late, a simulated rig computes late).
# The line host = offset + slope * device is fitted under every arrival (Moon, Skelly and Towsley's linear
# programme for clock skew, on the lowest arrival of each bin): of all lines below every point, the one nearest
# to them on average. That line is supported by the quickest arrivals before and after a slow spell, where a
# least-squares fit through the delays, or through their lowest few per cent, follows the spell.
#
# Why the slope is bounded (``MAX_DRIFT``): no arrival-time fit can tell a delay that grows through a whole run
# from a clock that runs slow. A run recorded on a loaded machine had its delay grow by 0.25 % of the run's
# length; a fit that believed it stretched the record's time by 0.25 % (the closed-loop demo then refused the two
# runs as sampled at different rates; stop 40's CI). A device clock is a crystal (+-100 ppm, aged and warm) and the
# host's monotonic clock may be slewed by NTP (up to 500 ppm); a slope further from one than that is a delay, not a
# clock. Decision record: docs/decisions/0043-device-clocks-and-late-physics.md.

MAX_DRIFT = 5e-4  # the most a device clock and the host's may differ in rate [-]: crystal plus NTP slew
BIN_S = 0.25  # the quickest arrival of each bin of device time carries the line [s]


class ClockLine(NamedTuple):
    """host = offset + slope * device; ``free_slope``: the slope before the bound (far from one: not a clock)."""

    offset: float
    slope: float
    free_slope: float

    def host(self, device_t: np.ndarray | float) -> np.ndarray | float:
        return self.offset + self.slope * device_t


def quickest_per_bin(device_t: np.ndarray, host_t: np.ndarray, bin_s: float = BIN_S) -> tuple[np.ndarray, np.ndarray]:
    """The (device, host) pair of smallest delay in each bin of device time, in device-time order."""
    d = np.asarray(device_t, dtype=np.float64)
    h = np.asarray(host_t, dtype=np.float64)
    order = np.argsort(d, kind="stable")
    d, h = d[order], h[order]
    k = np.floor((d - d[0]) / bin_s).astype(np.int64)
    by_delay = np.lexsort((h - d, k))  # bin by bin, quickest first
    kk = k[by_delay]
    pick = by_delay[np.r_[True, kk[1:] != kk[:-1]]]
    return d[pick], h[pick]


def _lower_hull(x: np.ndarray, y: np.ndarray) -> list[int]:
    """Indices of the lower convex hull of points sorted by x (Andrew's monotone chain), on Python floats: numpy's
    scalar indexing made it 9 ms for 2 400 bins, ten minutes of a live clock refitted four times a second."""
    xs, ys = x.tolist(), y.tolist()
    hull: list[int] = []
    for i, (xi, yi) in enumerate(zip(xs, ys)):
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            if (xs[b] - xs[a]) * (yi - ys[a]) - (ys[b] - ys[a]) * (xi - xs[a]) <= 0:
                hull.pop()
            else:
                break
        if hull and xi == xs[hull[-1]]:
            continue  # same x, higher or equal y: not on the lower hull
        hull.append(i)
    return hull


def clock_line(device_t: np.ndarray, host_t: np.ndarray, max_drift: float = MAX_DRIFT,
               bin_s: float | None = BIN_S) -> ClockLine:
    """The line under every bin's quickest arrival, nearest to them on average, its slope within 1 +- max_drift.

    The unbounded optimum is the lower hull's edge over the bins' mean device time; the objective is convex in
    the slope, so the bounded optimum is that slope clipped, with the offset that puts the line under every
    point. Times are taken relative to the first pair, so that an hour of microseconds keeps its precision.
    ``bin_s=None``: the pairs are already the quickest of their bins, in device-time order (the live estimator's).
    """
    if bin_s is None:
        d, h = np.asarray(device_t, dtype=np.float64), np.asarray(host_t, dtype=np.float64)
        order = np.argsort(d, kind="stable")
        d, h = d[order], h[order]
    else:
        d, h = quickest_per_bin(device_t, host_t, bin_s)
    d0, h0 = float(d[0]), float(h[0])
    x, y = d - d0, h - h0
    hull = _lower_hull(x, y)
    free = 1.0
    if len(hull) >= 2:
        xs = x[hull]
        j = int(np.clip(np.searchsorted(xs, x.mean(), side="right") - 1, 0, len(hull) - 2))
        a, b = hull[j], hull[j + 1]
        free = float((y[b] - y[a]) / (x[b] - x[a]))
    slope = float(np.clip(free, 1.0 - max_drift, 1.0 + max_drift))
    offset = h0 + float(np.min(y - slope * x)) - slope * d0
    return ClockLine(offset, slope, free)
