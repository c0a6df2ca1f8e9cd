"""Paper 001 (brake-2dof) analyses of a deceleration run: what the paper shows, measured on a recording.

Why one module: the spectrograms (Figs. 4, 5, 10), the phase and configuration planes (Figs. 6, 7, 11),
the effective friction coefficient of eq. (10) with a fit of law (7), and the segmentation of the run
into the regimes of section 5 all start from the same kinematics, estimated once from x1, phi and vb.
The numerical core is pure functions over numpy arrays; ``analyse_run`` ties them together (arrays in,
a pydantic result and the figure data out) and the figure functions sit at the end of this file.

Choices (the paper leaves them open; each is documented where it is made and tested):

* Kinematics: a centred Savitzky-Golay fit (degree 4, ``window_s`` = 20 ms) when the window holds at
  least 11 samples (>= 500 Hz); below that a quintic interpolating spline, because a local polynomial
  would span a whole slip phase (~60 ms) and smear it. Measured on simulated runs: mu error rms in slip
  0.019 (1 kHz, SG 20 ms) and 0.030 (100 Hz, spline).
* Friction: the rig's own compiled equations with friction off (daq.estimation.rigmodels.BrakeModel,
  no second copy of eqs. 5-6): F = m (a_without_friction - x1''), N from eq. (6) with the measured x1,
  y1 = r phi and y1', mu = F/N, and eq. (10)'s left-hand side mu_eff = F/(m g).
* Fit of law (7): mu0 and gamma by least squares on slip samples with |V_rel| >= 6/alpha (there
  tanh(alpha V) = 1 and beta/cosh(alpha V) < 0.4 %, so alpha and beta do not enter) and farther than
  the *measured* bias distance from every stick-slip transition. alpha and beta are held at the rig
  config's values: they shape |V_rel| < 25 mm/s only, i.e. the creep phase and the transitions, and
  there the differentiated velocity's error (~1e-3 m/s rms, ringing after each re-stick) is as large
  as V_rel itself; a creep-phase fit of (alpha, beta) on simulated data missed the truth by a factor
  >2 with a claimed uncertainty of 0.3 % (recorded in docs/analyses-001.md), so we do not claim them.
* Transitions: per stick-slip cycle (peaks of x1) and per spectrogram column; thresholds in
  :class:`TransitionCfg`, rationale in its field descriptions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Literal

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch
from pydantic import BaseModel, ConfigDict, Field
from scipy import signal
from scipy.interpolate import make_interp_spline
from scipy.optimize import least_squares

from daq.config import RigConfig
from daq.errors import InputError
from daq.estimation.regime import classify, switch_distance, switch_positions
from daq.estimation.rigmodels import BrakeModel
from daq.io.interchange import atomic_path
from daq.physics import brake2dof
from daq.physics.effects import E
from daq.physics.friction import mu_brake
from daq.signals import paper_spectrogram
from daq.sim.effectset import effect_vector
from daq.sim.rigs import make_sim

# paper 001, section 5 (Fig. 8): segment boundaries of the V0 = 0.25 m/s, Tmax = 160 s run "indicated
# conditionally based on visual estimates", and what the text says happens in each
PAPER_160_SEGMENTS = [
    (0.0, 98.0, "quasi-steady"),
    (98.0, 110.0, "period doubling -> irregular (narrow strip of widening spectrum)"),
    (110.0, 130.0, "regular multiple-frequency"),
    (130.0, 135.0, "narrow strip of widening spectrum"),
    (135.0, 140.0, "regular multiple-frequency"),
    (140.0, 150.0, "wide strip of dense spectrum (localised spikes)"),
]
PAPER_160_BOUNDARIES = [98.0, 110.0, 130.0, 135.0, 140.0, 150.0]

SPEC_FS = 100.0  # the paper's spectrogram: MATLAB spectrogram(signal, 512, 256, [], 1E2)
SPEC_NPERSEG = 512
SPEC_NOVERLAP = 256
BAND_HZ = (0.5, 45.0)  # spectral features: above the constant-shift line, below Nyquist of 100 Hz

SG_DEGREE = 4
SG_MIN_SAMPLES = 2 * SG_DEGREE + 3  # fewer samples per window: quintic interpolating spline instead
VB_WINDOW_S = 0.2  # the belt speed is a slow ramp: a local line over 0.2 s is unbiased and quiet


# ----------------------------------------------------------------------------- kinematics


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
        return (signal.savgol_filter(x, n, SG_DEGREE), signal.savgol_filter(x, n, SG_DEGREE, deriv=1, delta=dt),
                signal.savgol_filter(x, n, SG_DEGREE, deriv=2, delta=dt))
    spl = make_interp_spline(t, x, k=5)
    return spl(t), spl(t, 1), spl(t, 2)


def smooth_line(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """Local straight-line fit over window_s (centred moving regression) for slowly varying channels."""
    n = int(round(window_s * sample_rate(t))) | 1
    n = min(max(n, 3), x.size - (1 - x.size % 2))
    return signal.savgol_filter(x, n, 1) if n >= 3 else x.copy()


# ----------------------------------------------------------------------------- friction (eqs. 6, 7, 10)


@dataclass
class FrictionSeries:
    """Per-sample inverse dynamics of a brake-2dof recording (arrays of one length)."""

    t: np.ndarray
    x1: np.ndarray
    x1d: np.ndarray
    y1: np.ndarray
    y1d: np.ndarray
    vb: np.ndarray
    v_rel: np.ndarray  # x1' - vb [m/s]
    F: np.ndarray  # friction force on the block [N], eq. (5a) convention (+ opposes +x1 motion rel. to belt)
    N: np.ndarray  # normal load, eq. (6) [N]
    mu: np.ndarray  # F / N: law (7)'s coefficient
    mu_eff: np.ndarray  # F / (m g): eq. (10)'s left-hand side
    slip: np.ndarray  # 1 = slip, 0 = stick/creep (|V_rel| against v_stick with hysteresis)
    dist_s: np.ndarray  # time to the nearest stick-slip transition [s]
    n_switches: int
    mg: float


def brake_params(cfg: RigConfig) -> np.ndarray:
    """The rig's compiled parameter vector (as the simulator builds it)."""

    return make_sim(cfg, effect_vector(cfg)[0]).p.copy()


def friction_series(cfg: RigConfig, t: np.ndarray, x1: np.ndarray, phi: np.ndarray, vb: np.ndarray,
                    window_s: float = 0.02, hysteresis: float = 0.3) -> FrictionSeries:
    """Friction force, normal load, mu and mu_eff from measured x1, phi, vb via the rig's own equations."""

    model = BrakeModel(cfg)
    r = float(model.p[brake2dof.P.r])
    xs, xd, xdd = derivatives(t, x1, window_s)
    ps, pd, _ = derivatives(t, phi, window_s)
    vbs = smooth_line(t, vb, VB_WINDOW_S)
    est = model.infer({"x1": xs, "x1'": xd, "x1''": xdd, "phi": ps, "phi'": pd, "vb": vbs,
                       "vb'": np.gradient(vbs, t)})
    slip = classify(est.v_rel, model.v_stick, hysteresis, -1)
    idx = np.arange(t.size)
    sw = switch_positions(slip, idx, -1)
    rate = sample_rate(t)
    dist = switch_distance(idx, sw) / rate
    mg = float(model.p[brake2dof.P.m] * model.p[brake2dof.P.g])
    return FrictionSeries(t, xs, xd, r * ps, r * pd, vbs, est.v_rel, est.F, est.N, est.mu, est.F / mg, slip, dist,
                          int(sw.size), mg)


def kappas(p: np.ndarray) -> tuple[float, float]:
    """kappa1, kappa2 of eq. (10), read back from brake2dof.mu_effective (mu_eff = (1+k1) mu / (1+k2 mu))."""
    a = float(brake2dof.mu_effective(1e-9, p)) / 1e-9  # 1 + kappa1
    b = float(brake2dof.mu_effective(1.0, p))  # (1 + k1) / (1 + k2)
    return a - 1.0, a / b - 1.0


class ParamEstimate(BaseModel):
    """A fitted parameter with its standard error (Jacobian of the least-squares problem)."""

    model_config = ConfigDict(extra="forbid")
    value: float
    std: float


class LawFit(BaseModel):
    """Least-squares fit of law (7) (directly, or through eq. (10)) on the chosen samples."""

    model_config = ConfigDict(extra="forbid")
    target: str = Field(description="what was fitted: 'mu = F/N' (law 7) or 'mu_eff = F/(m g)' (eq. 10 of law 7)")
    params: dict[str, ParamEstimate]
    held: dict[str, float] = Field(description="law parameters held at the rig config's values")
    n_points: int
    rms: float = Field(description="residual rms, in the target's units")
    success: bool


def _fit(model: Callable[[np.ndarray, float, float], np.ndarray], v: np.ndarray, y: np.ndarray, x0: list[float],
         target: str, held: dict[str, float], source: str = "(recording)") -> LawFit:
    """(mu0, gamma) of ``model(v, mu0, gamma)`` by plain least squares; standard errors from J^T J."""
    if v.size < 10:
        raise InputError(source, "x1", f"only {v.size} settled slip samples (|V_rel| >= 6/alpha) to fit the "
                                       "friction law: no stick-slip with fast enough slips in this run")

    def resid(th: np.ndarray) -> np.ndarray:
        return model(v, th[0], th[1]) - y

    sol = least_squares(resid, np.array(x0, dtype=float), bounds=([0.0, 0.0], [5.0, 100.0]), x_scale="jac")
    r = sol.fun
    s2 = float(r @ r) / max(1, v.size - 2)
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * s2
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return LawFit(target=target, params={"mu0": ParamEstimate(value=float(sol.x[0]), std=float(std[0])),
                                         "gamma": ParamEstimate(value=float(sol.x[1]), std=float(std[1]))},
                  held=held, n_points=int(v.size), rms=float(np.sqrt(np.mean(r * r))), success=bool(sol.success))


class BiasBin(BaseModel):
    """Residual of mu against the preliminary fit, for slip samples at a given distance from a transition."""

    model_config = ConfigDict(extra="forbid")
    d_from_s: float
    d_to_s: float
    n: int
    median: float
    rms: float


class FrictionResult(BaseModel):
    """Eq. (10) effective friction and the fit of law (7), with the measured transition bias."""

    model_config = ConfigDict(extra="forbid")
    diff_window_s: float
    differentiator: str
    v_stick_m_per_s: float
    v_min_m_per_s: float = Field(description="slip samples used have |V_rel| >= 6/alpha")
    n_transitions: int
    bias_profile: list[BiasBin]
    bias_tolerance: float
    exclusion_s: float = Field(description="chosen: slip samples closer than this to a transition are not fitted")
    fit: LawFit = Field(description="law (7) fitted to mu = F/N with N from eq. (6): the primary result")
    fit_eq10: LawFit = Field(description="law (7) through eq. (10) fitted to F/(m g): quasi-static, biased")
    kappa1: float
    kappa2: float
    mu_eff_range: tuple[float, float] = Field(description="1st and 99th percentile of F/(m g)")


BIAS_TOL = 0.005  # |median residual| in mu allowed in a distance bin (1 % of mu0 ~ 0.5)
BIAS_RMS_FACTOR = 1.5  # and its rms at most this times the far-field residual rms


def choose_exclusion(profile: list[BiasBin], far_rms: float, fallback: float, min_n: int = 50) -> float:
    """Smallest bin edge from which every bin's |median| <= BIAS_TOL and rms <= BIAS_RMS_FACTOR far_rms.

    A bin's median carries sampling noise ~1.25 rms/sqrt(n): three of those are allowed on top of
    BIAS_TOL, and bins with fewer than min_n samples are not judged (a handful of far samples from
    the start-up must not push the exclusion out to where nothing is left to fit).
    """
    good = [b.n < min_n or (abs(b.median) <= BIAS_TOL + 3.75 * b.rms / math.sqrt(b.n)
                            and b.rms <= BIAS_RMS_FACTOR * far_rms) for b in profile]
    for i in range(len(profile)):
        if all(good[i:]):
            return profile[i].d_from_s
    return fallback


def identify_friction(fs: FrictionSeries, p: np.ndarray, window_s: float, alpha: float, beta: float,
                      v_stick: float, source: str = "(recording)") -> FrictionResult:
    """Fit law (7)'s mu0, gamma on slip samples away from transitions; the distance is measured, not assumed.

    1. A preliminary fit uses a conservative exclusion d0 = max(window, 3 samples).
    2. The residual of every slip sample against it, binned by distance to the nearest transition,
       is the bias profile (the twice-differentiated displacement is biased where the motion kinks).
    3. The exclusion is the smallest distance beyond which every bin is unbiased (choose_exclusion).
    4. The final fit uses the slip samples beyond it; the same samples fit eq. (10) of law (7) to F/(m g).
    """
    rate = sample_rate(fs.t)
    v_min = 6.0 / alpha
    base = (fs.slip == 1) & (np.abs(fs.v_rel) >= v_min) & np.isfinite(fs.mu) & np.isfinite(fs.v_rel)
    held = {"alpha": float(alpha), "beta": float(beta)}

    def law(v, mu0, gamma):
        return mu_brake(v, mu0, gamma, alpha, beta)

    def law_eff(v, mu0, gamma):
        return brake2dof.mu_effective(mu_brake(v, mu0, gamma, alpha, beta), p)

    d0 = max(window_s, 3.0 / rate)
    sel0 = base & (fs.dist_s >= d0)
    x0 = [float(np.median(np.abs(fs.mu[sel0]))) if sel0.any() else 0.5, 1.0]  # data-driven start, not the config
    pre = _fit(law, fs.v_rel[sel0], fs.mu[sel0], x0, "mu = F/N", held, source)
    resid = fs.mu - law(fs.v_rel, pre.params["mu0"].value, pre.params["gamma"].value)
    step = max(1.0 / rate, window_s / 4.0)
    edges = list(np.arange(0.0, 3.0 * d0 + 0.5 * step, step)) + [np.inf]
    profile = []
    for a, b in zip(edges[:-1], edges[1:]):
        m = base & (fs.dist_s >= a) & (fs.dist_s < b)
        rr = resid[m]
        profile.append(BiasBin(d_from_s=float(a), d_to_s=float(b) if np.isfinite(b) else float("inf"), n=int(m.sum()),
                               median=float(np.median(rr)) if rr.size else 0.0,
                               rms=float(np.sqrt(np.mean(rr * rr))) if rr.size else 0.0))
    d_star = choose_exclusion(profile, pre.rms, d0)
    sel = base & (fs.dist_s >= d_star)
    fit = _fit(law, fs.v_rel[sel], fs.mu[sel], [pre.params["mu0"].value, pre.params["gamma"].value], "mu = F/N",
               held, source)
    fit10 = _fit(law_eff, fs.v_rel[sel], fs.mu_eff[sel], [fit.params["mu0"].value, fit.params["gamma"].value],
                 "mu_eff = F/(m g)", held, source)
    k1, k2 = kappas(p)
    lo, hi = np.nanpercentile(fs.mu_eff, [1, 99])
    return FrictionResult(diff_window_s=window_s, differentiator=differentiator_name(fs.t, window_s),
                          v_stick_m_per_s=v_stick, v_min_m_per_s=v_min, n_transitions=fs.n_switches,
                          bias_profile=profile, bias_tolerance=BIAS_TOL, exclusion_s=float(d_star), fit=fit,
                          fit_eq10=fit10, kappa1=k1, kappa2=k2, mu_eff_range=(float(lo), float(hi)))


def differentiator_name(t: np.ndarray, window_s: float) -> str:
    """Which differentiator :func:`derivatives` uses at this rate and window."""
    n = int(round(window_s * sample_rate(t))) | 1
    if n >= SG_MIN_SAMPLES:
        return f"Savitzky-Golay degree {SG_DEGREE}, {n} samples ({n / sample_rate(t) * 1e3:.1f} ms), centred"
    return "quintic interpolating spline (window holds < 11 samples)"


# ----------------------------------------------------------------------------- spectrogram


class SpectrogramResult(BaseModel):
    """The paper's spectrogram settings and the dominant spectral line of x1 per column."""

    model_config = ConfigDict(extra="forbid")
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


# ----------------------------------------------------------------------------- transitions


class TransitionCfg(BaseModel):
    """Thresholds of the transition detectors (documented in docs/analyses-001.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    min_prominence: float = Field(0.05, description="a cycle's peak rises >= this fraction of the run's robust "
                                                    "range (P99.5-P0.5) above its surroundings; below: quiet")
    minor_peak: float = Field(0.25, description="peaks smaller than this fraction of the largest within "
                                                "+-neighbourhood_s are wiggles inside a cycle, not cycles")
    neighbourhood_s: float = Field(1.0, gt=0)
    mismatch_tol: float = Field(0.04, description="tau: a cycle repeats with period n when the n-step second "
                                                  "difference of peak rise and of interval is < tau of their "
                                                  "local median (drift-free; quasi-steady run ~0.01, noise "
                                                  "and period-2 alternation of the paper's Fig. 9b >> 0.05)")
    median_cycles: int = Field(7, ge=3, description="median of the mismatch over this many cycles")
    min_cycles: int = Field(6, ge=1, description="regime runs shorter than this merge into a neighbour")
    max_period: int = Field(4, ge=1, le=4)
    quiet_gap_periods: float = Field(3.0, description="no cycle for this many local periods (and for at least "
                                                      "quiet_min_s): quiet")
    quiet_min_s: float = Field(0.5, ge=0, description="shorter gaps are a missed peak, not a quiet stretch")
    widening_factor: float = Field(2.0, description="widening: entropy bandwidth of x1' > this times the "
                                                    "median over quasi-steady columns")
    widening_min_columns: int = Field(2, ge=1)
    subharmonic_db: float = Field(-30.0, description="f/2 (or 3f/2) line above this, dB re the f line, "
                                                     "confirms period doubling (quasi-steady run: -50 dB)")


class TransitionSegment(BaseModel):
    """One segment on the timeline: a regime (from cycles) or a widening strip (from the spectrum)."""

    model_config = ConfigDict(extra="forbid")
    track: Literal["regime", "spectrum"]
    kind: str = Field(description="regime: quasi-steady, period-doubling, period-3, period-4, irregular, quiet; "
                                  "spectrum: widening")
    start_s: float
    end_s: float
    n_cycles: int | None = None
    period_s: float | None = Field(None, description="median cycle interval")
    mismatch_p1: float | None = Field(None, description="median period-1 mismatch in the segment")
    mismatch_p2: float | None = None
    subharmonic_db: float | None = Field(None, description="median f/2 line level re f over the columns inside")
    bandwidth_ratio: float | None = Field(None, description="median entropy bandwidth / reference")


class TransitionResult(BaseModel):
    """Segments of the run, both tracks, sorted by start."""

    model_config = ConfigDict(extra="forbid")
    cfg: TransitionCfg
    signal: str
    n_cycles: int
    reference_bandwidth_hz: float
    segments: list[TransitionSegment]


@dataclass
class TransitionTrace:
    """Per-cycle and per-column features behind the segments (for the figure)."""

    cycle_t: np.ndarray
    amp: np.ndarray
    period: np.ndarray  # interval to the next cycle (nan for the last)
    mismatch: np.ndarray  # (max_period, n_cycles) median-filtered mismatch per period n
    label: list[str]
    col_t: np.ndarray
    line_hz: np.ndarray
    sub_db: np.ndarray
    bandwidth_hz: np.ndarray
    spec: tuple[np.ndarray, np.ndarray, np.ndarray] = field(default=None)  # type: ignore[assignment]


def find_cycles(t: np.ndarray, x: np.ndarray, cfg: TransitionCfg) -> tuple[np.ndarray, np.ndarray]:
    """Peak times (parabolic sub-sample) and rises (peak minus the preceding trough) of the cycles of x."""
    lo, hi = np.percentile(x, [0.5, 99.5])
    rng = max(hi - lo, 1e-300)
    pk, props = signal.find_peaks(x, prominence=cfg.min_prominence * rng)
    if pk.size == 0:
        return np.empty(0), np.empty(0)
    prom = props["prominences"]
    fs = sample_rate(t)
    half = max(1, int(round(cfg.neighbourhood_s * fs)))
    keep = np.ones(pk.size, bool)
    j0 = np.searchsorted(pk, pk - half)
    j1 = np.searchsorted(pk, pk + half, side="right")
    for i in range(pk.size):
        keep[i] = prom[i] >= cfg.minor_peak * prom[j0[i]:j1[i]].max()
    pk = pk[keep]
    # sub-sample peak time: parabola through the three samples around the peak
    inner = (pk > 0) & (pk < x.size - 1)
    tp = t[pk].astype(float)
    dt = 1.0 / fs
    k = pk[inner]
    a, b, c = x[k - 1], x[k], x[k + 1]
    den = a - 2 * b + c
    tp[inner] += np.where(den != 0, 0.5 * (a - c) / np.where(den != 0, den, 1.0), 0.0) * dt
    # rise: peak minus the lowest sample since the previous peak (or the signal start)
    starts = np.concatenate([[0], pk[:-1]])
    mins = np.array([x[s:e + 1].min() for s, e in zip(starts, pk)])
    return tp, x[pk] - mins


def _rolling_median(a: np.ndarray, n: int) -> np.ndarray:
    """Centred running median of n (shrinking at the ends), nan-aware."""
    out = np.full(a.size, np.nan)
    h = n // 2
    for i in range(a.size):
        w = a[max(0, i - h): i + h + 1]
        w = w[np.isfinite(w)]
        if w.size:
            out[i] = np.median(w)
    return out


def cycle_mismatch(amp: np.ndarray, period: np.ndarray, n: int, median_cycles: int) -> np.ndarray:
    """Period-n mismatch per cycle: n-step second difference of rise and interval, relative, median-filtered.

    r_n(k) = |a[k+n] - (a[k] + a[k+2n]) / 2| / median(a): zero for any signal that repeats every n cycles
    while drifting linearly (the deceleration), the full alternation |a - b| for period 2 seen with n = 1.
    The larger of the rise and interval values counts; it is assigned to the middle cycle k+n.
    """
    out = np.full(amp.size, np.nan)
    if amp.size < 2 * n + 1:
        return out
    scale_a = _rolling_median(np.abs(amp), 4 * n + 1)
    scale_t = _rolling_median(period, 4 * n + 1)
    ra = np.abs(amp[n:-n] - 0.5 * (amp[:-2 * n] + amp[2 * n:])) / scale_a[n:-n]
    rt = np.abs(period[n:-n] - 0.5 * (period[:-2 * n] + period[2 * n:])) / scale_t[n:-n]
    raw = np.fmax(ra, rt)
    out[n:-n] = raw
    return _rolling_median(out, median_cycles)


def _merge_short(labels: list[str], min_len: int) -> list[str]:
    """Relabel runs shorter than min_len (cycles) as their longer neighbour, shortest first."""
    lab = list(labels)
    while True:
        runs = []
        i = 0
        while i < len(lab):
            j = i
            while j + 1 < len(lab) and lab[j + 1] == lab[i]:
                j += 1
            runs.append((i, j))
            i = j + 1
        short = [(j - i + 1, k) for k, (i, j) in enumerate(runs) if j - i + 1 < min_len and len(runs) > 1]
        if not short:
            return lab
        _, k = min(short)
        i, j = runs[k]
        left = runs[k - 1] if k > 0 else None
        right = runs[k + 1] if k + 1 < len(runs) else None
        pick = max([r for r in (left, right) if r is not None], key=lambda r: r[1] - r[0])
        for q in range(i, j + 1):
            lab[q] = lab[pick[0]]


def detect_transitions(t: np.ndarray, x: np.ndarray, xdot: np.ndarray | None = None,
                       cfg: TransitionCfg = TransitionCfg(), signal_name: str = "x1"
                       ) -> tuple[TransitionResult, TransitionTrace]:
    """Segment a run into regimes (cycle by cycle) and widening strips (spectrogram columns).

    Regime of a cycle: the smallest n in 1..max_period with period-n mismatch < tau gives quasi-steady
    (n = 1), period-doubling (n = 2), period-3/4; none: irregular. Stretches without cycles (gaps longer
    than quiet_gap_periods local periods, or no peak above min_prominence) are quiet. Runs shorter than
    min_cycles merge into their longer neighbour; a boundary lies midway between the two cycles.
    Widening: spectrogram columns (the paper's 512/256 at 100 Hz, on x') whose entropy bandwidth
    exceeds widening_factor x the median over columns centred in quasi-steady segments.
    """
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    tc, amp = find_cycles(t, x, cfg)
    period = np.append(np.diff(tc), np.nan)
    mism = np.vstack([cycle_mismatch(amp, period, n, cfg.median_cycles) for n in range(1, cfg.max_period + 1)]) \
        if tc.size else np.zeros((cfg.max_period, 0))
    names = {1: "quasi-steady", 2: "period-doubling", 3: "period-3", 4: "period-4"}
    labels = []
    for k in range(tc.size):
        lab = "irregular"
        for n in range(1, cfg.max_period + 1):
            if np.isfinite(mism[n - 1, k]) and mism[n - 1, k] < cfg.mismatch_tol:
                lab = names[n]
                break
        else:
            if not np.isfinite(mism[:, k]).any():
                lab = None  # too close to an end to judge: takes its neighbour's label
        labels.append(lab)
    # cycles at the ends that cannot be judged take the nearest judged label
    judged = [i for i, lab in enumerate(labels) if lab is not None]
    if judged:
        for i in range(len(labels)):
            if labels[i] is None:
                labels[i] = labels[min(judged, key=lambda j: abs(j - i))]
    labels = _merge_short([str(lab) for lab in labels], cfg.min_cycles)

    # quiet gaps: no cycle for quiet_gap_periods local periods (and the run's ends beyond the last cycle)
    local_T = _rolling_median(period, 9) if tc.size else np.empty(0)
    segs: list[TransitionSegment] = []
    t0, t1 = float(t[0]), float(t[-1])

    def add_regime(kind: str, a: float, b: float, idx: np.ndarray) -> None:
        if b <= a:
            return
        seg = TransitionSegment(track="regime", kind=kind, start_s=a, end_s=b, n_cycles=int(idx.size))
        if idx.size:
            per = period[idx]
            per = per[np.isfinite(per)]
            seg.period_s = float(np.median(per)) if per.size else None
            for n, name in ((1, "mismatch_p1"), (2, "mismatch_p2")):
                if n <= cfg.max_period:
                    v = mism[n - 1, idx]
                    v = v[np.isfinite(v)]
                    setattr(seg, name, float(np.median(v)) if v.size else None)
        segs.append(seg)

    if tc.size < 3:
        add_regime("quiet", t0, t1, np.arange(tc.size))
    else:
        # group cycles into runs of equal label, split at quiet gaps
        gap_after = np.zeros(tc.size, bool)
        gap_after[:-1] = np.diff(tc) > np.maximum(cfg.quiet_gap_periods * np.nan_to_num(local_T[:-1], nan=np.inf),
                                                  cfg.quiet_min_s)
        start_i = 0
        cur_start = t0
        first_T = float(np.nanmedian(period[: min(9, period.size)]))
        if tc[0] - t0 > max(cfg.quiet_gap_periods * first_T, cfg.quiet_min_s):
            add_regime("quiet", t0, float(tc[0] - 0.5 * first_T), np.empty(0, int))
            cur_start = float(tc[0] - 0.5 * first_T)
        for i in range(1, tc.size + 1):
            end_run = i == tc.size or labels[i] != labels[start_i] or gap_after[i - 1]
            if not end_run:
                continue
            idx = np.arange(start_i, i)
            if i == tc.size:
                last_T = float(np.nanmedian(period[max(0, i - 9): i - 1])) if i > 1 else 0.0
                end = float(min(t1, tc[i - 1] + last_T))
                add_regime(labels[start_i], cur_start, end, idx)
                if t1 - tc[i - 1] > max(cfg.quiet_gap_periods * last_T, cfg.quiet_min_s):
                    add_regime("quiet", end, t1, np.empty(0, int))
                else:
                    segs[-1].end_s = t1
            elif gap_after[i - 1]:
                lt = float(local_T[i - 1]) if np.isfinite(local_T[i - 1]) else float(period[i - 2])
                end = float(tc[i - 1] + lt)
                add_regime(labels[start_i], cur_start, end, idx)
                nxt = float(tc[i] - 0.5 * lt)
                add_regime("quiet", end, nxt, np.empty(0, int))
                cur_start = nxt
            else:
                b = float(0.5 * (tc[i - 1] + tc[i]))
                add_regime(labels[start_i], cur_start, b, idx)
                cur_start = b
            start_i = i
        _merge_adjacent(segs)

    # spectral features per column of the paper's spectrogram, on x' (harmonics weigh more, as in Fig. 5)
    v = np.gradient(x, t) if xdot is None else np.asarray(xdot, float)
    f, ct, pxx = paper_spectrogram(t, v, SPEC_FS, SPEC_NPERSEG, SPEC_NOVERLAP)
    line = dominant_line(f, pxx)
    sub = subharmonic_db(f, pxx, line)
    bw = entropy_bandwidth(f, pxx)
    inside_qs = np.zeros(ct.size, bool)
    for s in segs:
        if s.kind == "quasi-steady":
            inside_qs |= (ct >= s.start_s) & (ct <= s.end_s)
    ref = float(np.median(bw[inside_qs])) if inside_qs.any() else float(np.percentile(bw, 25))
    wide = bw > cfg.widening_factor * ref
    half = 0.5 * (SPEC_NPERSEG - SPEC_NOVERLAP) / SPEC_FS
    k = 0
    while k < ct.size:
        if not wide[k]:
            k += 1
            continue
        j = k
        while j + 1 < ct.size and wide[j + 1]:
            j += 1
        if j - k + 1 >= cfg.widening_min_columns:
            a = float(max(t0, ct[k] - half))
            b = float(min(t1, ct[j] + half))
            segs.append(TransitionSegment(track="spectrum", kind="widening", start_s=a, end_s=b,
                                          bandwidth_ratio=float(np.median(bw[k:j + 1]) / ref),
                                          subharmonic_db=float(np.median(sub[k:j + 1]))))
        k = j + 1
    for s in segs:
        if s.track == "regime":
            m = (ct >= s.start_s) & (ct <= s.end_s)
            if m.any():
                s.subharmonic_db = float(np.median(sub[m]))
                s.bandwidth_ratio = float(np.median(bw[m]) / ref)
    segs.sort(key=lambda s: (s.start_s, s.track))
    res = TransitionResult(cfg=cfg, signal=signal_name, n_cycles=int(tc.size), reference_bandwidth_hz=ref,
                           segments=segs)
    trace = TransitionTrace(tc, amp, period, mism, labels, ct, line, sub, bw, (f, ct, pxx))
    return res, trace


def _merge_adjacent(segs: list[TransitionSegment]) -> None:
    """Join consecutive regime segments of the same kind (e.g. split by a gap that was not quiet)."""
    i = 0
    while i + 1 < len(segs):
        a, b = segs[i], segs[i + 1]
        if a.kind == b.kind and abs(a.end_s - b.start_s) < 1e-9:
            a.end_s = b.end_s
            a.n_cycles = (a.n_cycles or 0) + (b.n_cycles or 0)
            del segs[i + 1]
        else:
            i += 1


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


# ----------------------------------------------------------------------------- the whole run


class PlaneWindow(BaseModel):
    """A time window of the phase/configuration-plane figure."""

    model_config = ConfigDict(extra="forbid")
    start_s: float
    end_s: float
    vb_mean_m_per_s: float
    x1_range_mm: tuple[float, float]
    y1_range_mm: tuple[float, float]


class PaperMark(BaseModel):
    """A segment the paper reports for the V0 = 0.25 m/s, Tmax = 160 s run, beside what we found there."""

    model_config = ConfigDict(extra="forbid")
    start_s: float
    end_s: float
    paper: str
    found: list[str] = Field(description="regime kinds (with their share of the interval) and widening share")


class BrakeRunResult(BaseModel):
    """``daq analyse brake-run`` output (one JSON object)."""

    model_config = ConfigDict(extra="forbid")
    data: str
    rig: str = "brake-2dof"
    rig_config: str
    rate_hz: float
    duration_s: float
    n_samples: int
    resampled: bool = Field(description="the time base was not uniform and was interpolated onto one")
    belt_V0_m_per_s: float = Field(description="measured vb fitted by eq. (11): V0 (1 - t/Tmax)")
    belt_Tmax_s: float
    spectrogram: SpectrogramResult
    planes: list[PlaneWindow]
    friction: FrictionResult
    transitions: TransitionResult
    paper_160: list[PaperMark] | None = None
    figures: list[str] = []


@dataclass
class RunContext:
    """Arrays the figures need beyond the JSON."""

    fs: FrictionSeries
    trace: TransitionTrace
    spec_x: tuple[np.ndarray, np.ndarray, np.ndarray]
    spec_v: tuple[np.ndarray, np.ndarray, np.ndarray]
    alpha: float
    beta: float
    mu0_cfg: float
    gamma_cfg: float
    paper_marks: bool


REQUIRED = ("x1", "phi", "vb")
MIN_DURATION_S = 2 * SPEC_NPERSEG / SPEC_FS  # two spectrogram windows


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


def default_planes(t0: float, t1: float, width: float, n: int = 6) -> list[tuple[float, float]]:
    """n windows of ``width`` spread evenly over the run (the first one after the start-up second)."""
    width = min(width, (t1 - t0) / n)
    a = min(t0 + 1.0, t1 - width)
    starts = np.linspace(a, t1 - width, n)
    return [(round(float(s), 2), round(float(s + width), 2)) for s in starts]


def paper_planes(t0: float, t1: float) -> list[tuple[float, float]]:
    """The windows of the paper's Fig. 11 that lie inside the run."""
    wins = [(1.0, 3.0), (98.0, 100.0), (102.0, 104.0), (120.0, 122.0), (136.0, 138.0), (155.0, 157.0)]
    return [w for w in wins if w[0] >= t0 and w[1] <= t1]


def fit_seed_ramp(t: np.ndarray, vb: np.ndarray) -> tuple[float, float]:
    """V0 and Tmax of eq. (11) from the measured belt speed (least-squares line)."""
    slope, v0 = np.polyfit(t, vb, 1)
    return float(v0), float(-v0 / slope) if slope < 0 else float("inf")


def compare_paper_160(tr: TransitionResult) -> list[PaperMark]:
    """For each segment the paper reports on the 160 s run: which of our kinds cover it, and how much."""
    out = []
    for a, b, what in PAPER_160_SEGMENTS:
        share: dict[str, float] = {}
        wide = 0.0
        for s in tr.segments:
            ov = max(0.0, min(b, s.end_s) - max(a, s.start_s))
            if ov <= 0:
                continue
            if s.track == "regime":
                share[s.kind] = share.get(s.kind, 0.0) + ov / (b - a)
            else:
                wide += ov / (b - a)
        found = [f"{k} {v:.0%}" for k, v in sorted(share.items(), key=lambda kv: -kv[1])]
        found.append(f"widening {wide:.0%}")
        out.append(PaperMark(start_s=a, end_s=b, paper=what, found=found))
    return out


def analyse_run(t: np.ndarray, channels: dict[str, np.ndarray], cfg: RigConfig, source: str, *,
                config_source: str = "brake-2dof", plane_window_s: float = 2.0,
                planes: list[tuple[float, float]] | None = None, diff_window_s: float = 0.02,
                tcfg: TransitionCfg = TransitionCfg(), paper_marks: bool = False,
                say: Callable[[str], None] = lambda s: None) -> tuple[BrakeRunResult, RunContext]:
    """All of paper 001's analyses on one recording (pure: arrays in, result and figure data out)."""
    if cfg.rig != "brake-2dof":
        raise InputError(config_source, "rig", f"must be brake-2dof, got {cfg.rig!r}")
    if not diff_window_s > 0:
        raise InputError("--diff-window", "diff_window", "must be > 0")
    t, ch, resampled = prepare(t, channels, source)
    rate = sample_rate(t)
    p = brake_params(cfg)
    fr = cfg.friction
    say(f"kinematics and inverse dynamics ({differentiator_name(t, diff_window_s)})")
    fs = friction_series(cfg, t, ch["x1"], ch["phi"], ch["vb"], diff_window_s)
    say("fitting law (7) on slip samples away from the measured transition bias")
    fric = identify_friction(fs, p, diff_window_s, fr.alpha_s_per_m, fr.beta, cfg.contact.v_stick_m_per_s, source)
    say("spectrograms (512/256 at 100 Hz) and transition detection")
    spec_x = paper_spectrogram(t, fs.x1, SPEC_FS, SPEC_NPERSEG, SPEC_NOVERLAP)
    spec_v = paper_spectrogram(t, fs.x1d, SPEC_FS, SPEC_NPERSEG, SPEC_NOVERLAP)
    modes = brake2dof.linear_modes(p, _geo_weight(cfg))
    spec = SpectrogramResult(times_s=spec_x[1].tolist(), line_hz=dominant_line(spec_x[0], spec_x[2]).tolist(),
                             line_hz_velocity=dominant_line(spec_v[0], spec_v[2]).tolist(),
                             modes_hz=[float(m) for m in modes])
    trans, trace = detect_transitions(t, fs.x1, fs.x1d, tcfg, "x1")
    t0, t1 = float(t[0]), float(t[-1])
    if planes is None:
        planes = (paper_planes(t0, t1) if paper_marks else []) or default_planes(t0, t1, plane_window_s)
    pw = []
    for a, b in planes:
        if not (t0 <= a < b <= t1 + 1e-9):
            raise InputError("--planes", f"{a:g}:{b:g}", f"must lie inside the run ({t0:g}..{t1:g} s)")
        m = (t >= a) & (t <= b)
        pw.append(PlaneWindow(start_s=a, end_s=b, vb_mean_m_per_s=float(np.mean(fs.vb[m])),
                              x1_range_mm=(float(fs.x1[m].min() * 1e3), float(fs.x1[m].max() * 1e3)),
                              y1_range_mm=(float(fs.y1[m].min() * 1e3), float(fs.y1[m].max() * 1e3))))
    v0, tmax = fit_seed_ramp(t, fs.vb)
    res = BrakeRunResult(data=source, rig_config=config_source, rate_hz=rate, duration_s=t1 - t0, n_samples=int(t.size),
                         resampled=resampled, belt_V0_m_per_s=v0, belt_Tmax_s=tmax, spectrogram=spec, planes=pw,
                         friction=fric, transitions=trans,
                         paper_160=compare_paper_160(trans) if paper_marks else None)
    ctx = RunContext(fs, trace, spec_x, spec_v, fr.alpha_s_per_m, fr.beta, fr.mu0, fr.gamma_s_per_m, paper_marks)
    return res, ctx


def _geo_weight(cfg: RigConfig) -> float:
    """Weight of the geometric effect in the rig's seed model (1 = the paper's nonlinear model)."""

    return float(effect_vector(cfg)[0][E.GEO_WEIGHT])


# ----------------------------------------------------------------------------- figures

KIND_COLOURS = {"quasi-steady": "#4daf4a", "period-doubling": "#377eb8", "period-3": "#984ea3",
                "period-4": "#a65628", "irregular": "#e41a1c", "quiet": "#999999", "widening": "#ff7f00"}


def _save(fig, path) -> None:


    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def _envelope(t: np.ndarray, y: np.ndarray, buckets: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """A dense trace as a min/max zigzag per bucket: looks the same as every sample, draws 10x faster."""
    if t.size <= 4 * buckets:
        return t, y
    n = t.size // buckets * buckets
    tb = t[:n].reshape(buckets, -1).mean(axis=1)
    yb = y[:n].reshape(buckets, -1)
    return np.repeat(tb, 2), np.column_stack([yb.min(axis=1), yb.max(axis=1)]).ravel()


def _spec_panel(ax, spec, title: str, modes: list[float], fmax: float = 50.0):
    f, tt, pxx = spec
    db = 10 * np.log10(pxx + 1e-30)
    top = np.percentile(db, 99.9)
    im = ax.pcolormesh(tt, f, db, shading="auto", cmap="jet", vmin=top - 90, vmax=top, rasterized=True)
    for m in modes:
        ax.axhline(m, color="white", lw=0.7, ls="--", alpha=0.7)
    ax.set_ylim(0, fmax)
    ax.set_ylabel("f [Hz]")
    ax.set_title(title, fontsize=10)
    return im


def spectrogram_figure(res: BrakeRunResult, ctx: RunContext, path) -> None:
    """Time histories of x1 and x1' over their spectrograms (paper Figs. 4, 5, 10)."""

    fs = ctx.fs
    fig, ax = plt.subplots(4, 1, figsize=(12, 11), sharex=True, constrained_layout=True,
                           gridspec_kw={"height_ratios": [1, 2, 1, 2]})
    ax[0].plot(*_envelope(fs.t, fs.x1 * 1e3), lw=0.3, color="C0")
    ax[0].set_ylabel("x1 [mm]")
    ax[0].set_title("block displacement x1", fontsize=10)
    modes = res.spectrogram.modes_hz
    im = _spec_panel(ax[1], ctx.spec_x, "spectrogram of x1, 10 log10(PSD) [dB re 1 m²/Hz]; dashed: linearised "
                     f"modes {', '.join(f'{m:.2f}' for m in modes)} Hz", modes)
    fig.colorbar(im, ax=ax[1], label="dB", pad=0.01)
    ax[2].plot(*_envelope(fs.t, fs.x1d), lw=0.3, color="C0", label="x1' (estimated from x1)")
    ax[2].plot(fs.t, fs.vb, lw=1.0, color="C3", label="vb (measured)")
    ax[2].set_ylabel("x1' [m/s]")
    ax[2].legend(loc="lower right", fontsize=8)
    ax[2].set_title("block velocity x1' (the sticking phases ride on the belt speed)", fontsize=10)
    im = _spec_panel(ax[3], ctx.spec_v, "spectrogram of x1' [dB re 1 (m/s)²/Hz] (512-sample Hamming window, "
                     "overlap 256, 100 Hz, as the paper)", modes)
    fig.colorbar(im, ax=ax[3], label="dB", pad=0.01)
    ax[3].set_xlabel("t [s]")
    fig.suptitle(f"paper 001 spectrograms: {_name(res.data)} (belt V0 = {res.belt_V0_m_per_s:.3f} m/s, "
                 f"Tmax = {res.belt_Tmax_s:.0f} s)")
    _save(fig, path)


def _name(p: str) -> str:

    return Path(p).name


def planes_figure(res: BrakeRunResult, ctx: RunContext, path) -> None:
    """Phase planes (x1, x1') and configuration planes (x1, y1) in time windows (paper Figs. 6, 7, 11)."""

    fs = ctx.fs
    n = len(res.planes)
    fig, ax = plt.subplots(2, n, figsize=(3.2 * n + 1, 7), constrained_layout=True, squeeze=False)
    for j, w in enumerate(res.planes):
        m = (fs.t >= w.start_s) & (fs.t <= w.end_s)
        a = ax[0, j]
        a.plot(fs.x1[m] * 1e3, fs.x1d[m], lw=0.5, color="C0")
        a.axhline(w.vb_mean_m_per_s, color="C3", lw=0.8, ls="--", label=f"mean vb {w.vb_mean_m_per_s:.3f}")
        a.set_title(f"phase plane {w.start_s:g} < t < {w.end_s:g} s", fontsize=9)
        a.set_xlabel("x1 [mm]")
        a.set_ylabel("x1' [m/s]")
        a.legend(loc="lower right", fontsize=7)
        b = ax[1, j]
        b.plot(fs.x1[m] * 1e3, fs.y1[m] * 1e3, lw=0.5, color="C2")
        b.set_title(f"configuration {w.start_s:g} < t < {w.end_s:g} s", fontsize=9)
        b.set_xlabel("x1 [mm]")
        b.set_ylabel("y1 = r phi [mm]")
    fig.suptitle(f"paper 001 phase and configuration planes: {_name(res.data)}")
    _save(fig, path)


def friction_figure(res: BrakeRunResult, ctx: RunContext, path) -> None:
    """mu_eff(t), mu against V_rel with the fitted law (7), F/(m g) against eq. (10), and the bias profile."""

    fs = ctx.fs
    fr = res.friction
    mu0, gam = fr.fit.params["mu0"].value, fr.fit.params["gamma"].value
    used = (fs.slip == 1) & (np.abs(fs.v_rel) >= fr.v_min_m_per_s) & (fs.dist_s >= fr.exclusion_s)
    fig, ax = plt.subplots(2, 2, figsize=(13, 9), constrained_layout=True)
    # (a) a one-second zoom of mu_eff(t)
    T = fs.t[-1] - fs.t[0]
    a0 = fs.t[0] + 0.25 * T
    m = (fs.t >= a0) & (fs.t <= a0 + 1.0)
    a = ax[0, 0]
    a.plot(fs.t[m], fs.mu_eff[m], lw=0.8, color="0.4", label="F/(m g), all samples")
    a.plot(fs.t[m], np.where(used[m], fs.mu_eff[m], np.nan), lw=1.2, color="C0", label="samples fitted")
    a.plot(fs.t[m], np.where(fs.slip[m] == 0, fs.mu_eff[m], np.nan), lw=1.2, color="C1",
           label="stick/creep (|V_rel| < v_stick)")
    a.set_xlabel("t [s]")
    a.set_ylabel("mu_eff = F/(m g)")
    a.set_title("effective friction coefficient (eq. 10's left side), 1 s of the run", fontsize=10)
    a.legend(fontsize=8, loc="lower right")
    # (b) mu against V_rel
    vv = np.linspace(min(-0.05, np.nanpercentile(fs.v_rel, 0.5)), max(0.05, np.nanpercentile(fs.v_rel, 99.5)), 800)
    b = ax[0, 1]
    stride = max(1, fs.t.size // 40000)
    b.plot(fs.v_rel[::stride], fs.mu[::stride], ".", ms=1, color="0.75", label="all samples (mu = F/N)")
    b.plot(fs.v_rel[used][::stride], fs.mu[used][::stride], ".", ms=1, color="C0", alpha=0.5,
           label="fitted samples")
    b.plot(vv, mu_brake(vv, mu0, gam, ctx.alpha, ctx.beta), color="C3", lw=1.5,
           label=f"fit: mu0 = {mu0:.4f} ± {fr.fit.params['mu0'].std:.4f}, gamma = {gam:.3f} ± "
                 f"{fr.fit.params['gamma'].std:.3f} s/m")
    b.plot(vv, mu_brake(vv, ctx.mu0_cfg, ctx.gamma_cfg, ctx.alpha, ctx.beta), color="k", lw=0.8, ls="--",
           label=f"rig config law (mu0 = {ctx.mu0_cfg:g}, gamma = {ctx.gamma_cfg:g})")
    b.set_ylim(-1.0, 1.0)
    b.set_xlabel("V_rel = x1' - vb [m/s]")
    b.set_ylabel("mu = F/N")
    b.set_title(f"law (7) fitted (alpha = {ctx.alpha:g}, beta = {ctx.beta:g} held)", fontsize=10)
    b.legend(fontsize=7, loc="upper left", markerscale=8)
    # (c) F/(m g) against V_rel and eq. (10)
    c = ax[1, 0]
    c.plot(fs.v_rel[::stride], fs.mu_eff[::stride], ".", ms=1, color="0.75", label="F/(m g), all samples")
    p_m10 = fr.fit_eq10.params
    c.plot(vv, (1 + fr.kappa1) * mu_brake(vv, mu0, gam, ctx.alpha, ctx.beta)
           / (1 + fr.kappa2 * mu_brake(vv, mu0, gam, ctx.alpha, ctx.beta)), color="C3", lw=1.5,
           label="eq. (10) of the fitted law (7)")
    c.plot(vv, mu_brake(vv, mu0, gam, ctx.alpha, ctx.beta), color="C3", lw=0.8, ls=":", label="law (7) itself")
    c.set_ylim(-2.0, 2.0)
    c.set_xlabel("V_rel [m/s]")
    c.set_ylabel("mu_eff = F/(m g)")
    c.set_title(f"eq. (10), quasi-static: kappa1 = {fr.kappa1:.3f}, kappa2 = {fr.kappa2:.4f}; law (7) fitted\n"
                f"through it: mu0 = {p_m10['mu0'].value:.3f}, gamma = {p_m10['gamma'].value:.2f} (biased: in slip "
                "N of eq. (6) swings)", fontsize=9)
    c.legend(fontsize=8, loc="upper left", markerscale=8)
    # (d) bias profile
    d = ax[1, 1]
    prof = [bb for bb in fr.bias_profile if bb.n > 0]
    lo = np.array([bb.d_from_s for bb in prof]) * 1e3
    hi = np.array([bb.d_to_s if np.isfinite(bb.d_to_s) else bb.d_from_s + (lo[1] - lo[0]) / 1e3 for bb in prof]) * 1e3
    mid = 0.5 * (lo + hi)
    d.plot(mid, [bb.median for bb in prof], "o-", color="C0", label="median residual")
    d.plot(mid, [bb.rms for bb in prof], "s-", color="C1", label="rms residual")
    d.axhspan(-fr.bias_tolerance, fr.bias_tolerance, color="C0", alpha=0.15, label=f"|bias| <= {fr.bias_tolerance}")
    d.axvline(fr.exclusion_s * 1e3, color="k", ls="--", label=f"chosen exclusion {fr.exclusion_s * 1e3:.1f} ms")
    d.set_xlabel("distance to the nearest stick-slip transition [ms] (last bin: and beyond)")
    d.set_ylabel("mu residual vs preliminary fit")
    d.set_title("bias of friction from twice-differentiated x1, by distance to a transition", fontsize=10)
    d.text(0.98, 0.5, fr.differentiator.replace(", centred", "").replace(" (", "\n("), transform=d.transAxes,
           ha="right", fontsize=8, color="0.3")
    d.legend(fontsize=8)
    fig.suptitle(f"paper 001 effective friction and law (7): {_name(res.data)} "
                 f"({fr.fit.n_points} samples fitted, residual rms {fr.fit.rms:.4f})")
    _save(fig, path)


def timeline_figure(res: BrakeRunResult, ctx: RunContext, path) -> None:
    """The segments on a timeline under the x1 spectrogram, with the features that decided them."""

    tr = ctx.trace
    trans = res.transitions
    cfg = trans.cfg
    fig, ax = plt.subplots(5, 1, figsize=(13, 12), sharex=True, constrained_layout=True,
                           gridspec_kw={"height_ratios": [2.2, 0.8, 1.2, 1.2, 1.0]})
    im = _spec_panel(ax[0], ctx.spec_x, "spectrogram of x1 [dB] with the detected segment boundaries",
                     res.spectrogram.modes_hz, fmax=40.0)
    fig.colorbar(im, ax=ax[0], label="dB", pad=0.01)
    for s in trans.segments:
        if s.track == "regime":
            ax[0].axvline(s.start_s, color="white", lw=0.8)
    # timeline tracks
    tl = ax[1]
    for s in trans.segments:
        y = 1.0 if s.track == "regime" else 0.0
        tl.broken_barh([(s.start_s, s.end_s - s.start_s)], (y - 0.4, 0.8), color=KIND_COLOURS.get(s.kind, "k"))
    tl.set_yticks([1.0, 0.0], ["regime\n(cycles)", "spectrum"])
    tl.set_ylim(-0.6, 1.6)
    kinds = sorted({s.kind for s in trans.segments}, key=list(KIND_COLOURS).index)
    tl.legend(handles=[Patch(color=KIND_COLOURS[k], label=k) for k in kinds], ncol=len(kinds), fontsize=8,
              loc="lower left", bbox_to_anchor=(0, 1.0), frameon=False)
    # cycle mismatch
    c = ax[2]
    for n in range(1, min(2, cfg.max_period) + 1):
        c.semilogy(tr.cycle_t, np.clip(tr.mismatch[n - 1], 1e-5, None), lw=0.9,
                   label=f"period-{n} mismatch" + (" (alternation)" if n == 1 else ""))
    c.axhline(cfg.mismatch_tol, color="k", ls="--", lw=0.8, label=f"tau = {cfg.mismatch_tol}")
    c.set_ylabel("relative mismatch")
    c.legend(fontsize=8, loc="upper center", ncol=3)
    c.set_title("cycle-to-cycle: n-step second difference of peak rise / interval", fontsize=9, loc="right")
    # subharmonic line
    s_ = ax[3]
    s_.plot(tr.col_t, tr.sub_db, "o-", ms=3, color="C4", label="f/2 or 3f/2 line re f line [dB]")
    s_.axhline(cfg.subharmonic_db, color="C4", ls="--", lw=0.8, label=f"{cfg.subharmonic_db:g} dB")
    s_.set_ylabel("sub-harmonic [dB]")
    s_.legend(fontsize=8, loc="upper left")
    b = ax[4]
    b.plot(tr.col_t, tr.bandwidth_hz / trans.reference_bandwidth_hz, "o-", ms=3, color="C1",
           label=f"entropy bandwidth of x1' / reference ({trans.reference_bandwidth_hz:.2f} Hz)")
    b.axhline(cfg.widening_factor, color="C1", ls="--", lw=0.8, label=f"widening: x {cfg.widening_factor:g}")
    b.set_yscale("log")
    b.set_ylabel("bandwidth ratio")
    b.set_xlabel("t [s]")
    b.legend(fontsize=8, loc="upper left")
    if ctx.paper_marks:
        for a_ in ax:
            for x in PAPER_160_BOUNDARIES:
                a_.axvline(x, color="m", ls=":", lw=1.0)
    marks = ("\ndotted magenta: the paper's Fig. 8 segment boundaries (98, 110, 130, 135, 140, 150 s)"
             if ctx.paper_marks else "")
    fig.suptitle(f"paper 001 transitions: {_name(res.data)} ({trans.n_cycles} cycles); detected segments below the "
                 f"spectrogram{marks}")
    _save(fig, path)


FIGURES = {"spectrogram.png": spectrogram_figure, "planes.png": planes_figure, "friction.png": friction_figure,
           "transitions.png": timeline_figure}
