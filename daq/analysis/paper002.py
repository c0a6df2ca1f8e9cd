"""Paper 002 (Furmanik, drum-pendulum): the friction coefficient mu(t) by eq. (2) and law (3) fitted to it.

Why this module: the paper identifies its friction model in two steps, and so do we.

1. mu(t) by eq. (2), from the measured phi, phi', phi'' and the thrust N:
       mu(t) = [I0 phi''/R + k Rs^2/R sin(phi) cos(phi) + mu1 Z r0/R sgn(phi')] / (N sgn(v_wz)),
   v_wz = (omega - phi') R the relative sliding velocity. The bracket is evaluated through the rig's
   own compiled equations (daq/physics/drum.py via daq/estimation/rigmodels.DrumModel: the
   right-hand side with the friction switched off, so eq. (1) row 1 gives Z, and the seed
   model's viscous pivot damping, which the paper omits, is included; it is < 1e-4 in mu).
   Kinematics are the *measured* channels, as on the paper's stand (Fig. 2): phi from strain
   gauge A, phi' = vel/R from the induction velocity gauge D, phi'' = accel/R from the piezo
   accelerometer C (both tangential at the friction radius R), N from strain gauge B (the
   instantaneous thrust, not the nominal P: the drum is out of round). Nothing is
   differentiated: vel and accel get a zero-phase cubic smoothing over +-5 ms, the drum
   speed has its 100 Hz zero-order hold undone (``drum_surface_speed``). Only when a file
   lacks vel/accel are they taken as centred Savitzky-Golay derivatives of phi, and the
   result says so.
2. Law (3) fitted by nonlinear least squares in v = |v_wz|:
       mu(v) = A [1 - exp(-B v)] exp(-C v) + D v + E,
   evaluated with the shared physics law ``daq.physics.friction.mu_drum`` (sgn regularised
   over the rig's eps = 0.2 mm/s, far below the samples used), by variable projection: A, D,
   E are linear given B, C, so a log grid over (B, C) and then scipy least_squares over
   (log B, log C) with A, D, E solved at every step. Standard errors from the five-parameter
   Jacobian, inflated by the residuals' integrated autocorrelation time (samples 1 ms apart
   are not independent).

Sample selection (the SPEC's hint, measured, see docs/campaign.md): mu(t) is not a function
of v where the contact sticks or reverses (|v_wz| small: static friction is whatever holds
the pendulum), and any smoothing or differentiation smears the acceleration jump at each
stick-slip transition into the neighbouring samples. Measured on simulated stick-slip, phi''
from a +-5 ms Savitzky-Golay second derivative of phi is 6-12x noisier than the accelerometer
everywhere, and twice as noisy and biased within 5 ms of a transition; the gauges smoothed
+-5 ms are biased only within 5 ms. We fit samples with |v_wz| >= v_min (default 3 mm/s:
below it the law is so steep that the gauges' remaining noise pushes the fit along the A-B
valley, measured) that are not within ``guard_s`` (default 15 ms) of a slower sample.
``differentiation_check`` reports the differentiated-vs-gauge comparison on every recording
(data only, no truth).

One cell's run (``cell_ramp``): the paper records the pendulum's friction-induced vibration at a
constant drum speed v0 for each (P, v0). A hold alone visits only a band of v (one point
when the sliding is steady: below ~6.6 mm/s and above ~20 mm/s law (3) with D = 1.5 is
velocity-strengthening), which cannot identify five parameters. So each cell is: lead-in
0 -> v0, hold at v0 (the paper's run), then a slow sweep of the drum speed v0 -> v_hi ->
v_lo (exponential, so time per decade of v is equal and the hump at a few mm/s is densely
sampled) -> v0. The fit uses every selected sample of the cell.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from daq.config import RigConfig, config_for_recording
from daq.errors import InputError
from daq.estimation.rigmodels import DrumModel
from daq.io.interchange import Recording, atomic_path
from daq.io.loading import load_data
from daq.physics import drum
from daq.physics.friction import mu_drum
from daq.ramps import Ramp, Segment
from daq.sim.effectset import effect_vector, parse_effect

RIG = "drum-pendulum"
PARAMS = ("A", "B", "C", "D", "E")
UNITS = {"A": "-", "B": "s/m", "C": "s/m", "D": "s/m", "E": "-"}
LAW = "mu(v) = A [1 - exp(-B v)] exp(-C v) + D v + E,  v = v_wz = (omega - phi') R  [m/s]"

V_MIN = 3e-3  # [m/s] slower samples are not fitted (stick, reversal; and see mu_series)
GUARD_S = 0.015  # [s] around every such sample
GAUGE_HALF_S = 0.005  # [s] half-width of the zero-phase cubic smoothing of the vel and accel gauges
SG_HALF_S = 0.005  # [s] half-width of the Savitzky-Golay derivatives of phi (fallback and check)
DRUM_SMOOTH_S = 0.05  # [s] half-width of the local quadratic through the drum speed updates
REL_SE_IDENTIFIED = 0.25  # a coefficient with se/|value| above this is reported as not identified
LOG_BOUNDS = ((0.1, 1e5), (0.01, 1e5))  # [s/m] search ranges of B and C (log scale)

# one cell's programme (times before --time-scale); see cell_ramp
LEAD_IN_S = 2.0
HOLD_S = 10.0
SWEEP_S = 30.0
BAND = (5e-4, 0.06)  # [m/s] the sweep's low and high drum speeds (v_hi at least 2 v0)


# ----------------------------------------------------------------------------- one cell's programme


def cell_ramp(v0: float, *, hold_s: float = HOLD_S, sweep_s: float = SWEEP_S, band: tuple[float, float] = BAND,
              time_scale: float = 1.0, max_accel: float = 0.2, max_speed: float = 0.2) -> Ramp:
    """The drum-speed programme of one cell (P, v0): lead-in, hold at v0, sweep v0 -> v_hi -> v_lo -> v0.

    ``time_scale`` multiplies every duration (a compressed run), but no segment is made steeper
    than 3/4 of the drive's acceleration limit (the regulator then follows it). The sweep's
    share: 30 % up (linear), 55 % down (exponential towards 0, ending at v_lo: equal time per
    decade of v), 15 % back to v0.
    """
    lo, hi = float(band[0]), max(float(band[1]), 2.0 * v0)
    hi = min(hi, max_speed)
    if not (0 < lo < v0 <= hi):
        raise InputError("--speeds", "v0", f"{v0:g} m/s must lie inside the sweep band ({lo:g}, {hi:g}] m/s")
    a_max = 0.75 * max_accel

    def lin(dur: float, dv: float) -> float:
        return max(dur * time_scale, abs(dv) / a_max)

    down = 0.55 * sweep_s * time_scale
    tau = down / math.log(hi / lo)
    # an exponential from hi towards 0 starts steepest: hi / tau
    if hi / tau > a_max:
        tau = hi / a_max
        down = tau * math.log(hi / lo)
    segs = [Segment(kind="linear", duration_s=lin(LEAD_IN_S, v0), to_m_per_s=v0),
            Segment(kind="hold", duration_s=max(hold_s * time_scale, 1e-3)),
            Segment(kind="linear", duration_s=lin(0.30 * sweep_s, hi - v0), to_m_per_s=hi),
            Segment(kind="exponential", duration_s=down, to_m_per_s=0.0, tau_s=tau),
            Segment(kind="linear", duration_s=lin(0.15 * sweep_s, v0 - lo), to_m_per_s=v0),
            Segment(kind="linear", duration_s=lin(0.5, v0), to_m_per_s=0.0)]
    return Ramp(name=f"paper-002 cell v0={v0:g} m/s (hold {hold_s:g} s, sweep {lo:g}-{hi:g} m/s in {sweep_s:g} s, "
                     f"time scale {time_scale:g})", start_m_per_s=0.0, segment=segs)


# ----------------------------------------------------------------------------- kinematics and mu(t)


def sg(x: np.ndarray, rate: float, half_s: float, deriv: int = 0, degree: int = 3) -> np.ndarray:
    """Centred Savitzky-Golay smoothing or derivative over +-half_s (zero phase, offline)."""
    half = max(2, int(round(half_s * rate)))
    n = min(2 * half + 1, x.size - (1 - x.size % 2))
    return savgol_filter(x, n, min(degree, n - 1), deriv=deriv, delta=1.0 / rate, mode="interp")


def drum_surface_speed(t: np.ndarray, omega: np.ndarray, R: float, half_s: float = DRUM_SMOOTH_S) -> np.ndarray:
    """Drum surface speed R omega(t) from the opto-electronic gauge, its zero-order hold undone.

    Why: gauge E updates at 100 Hz; on a 1 kHz time base each reading is held for ~10 samples,
    i.e. it lags by 5 ms on average, which during a sweep is a visible error in v_wz. A held
    reading is the speed at the first sample of its run, so we keep one point per run (runs of
    one sample are the interpolated steps of a resampled recording: dropped), fit a local
    quadratic over +-half_s (noise 0.1 mm/s per reading -> ~0.04 mm/s; +-50 ms keeps the bias
    at the programme's corners below ~0.2 mm/s even at --time-scale 0.1) and evaluate it at
    every sample.
    """
    omega = np.asarray(omega, dtype=float)
    first = np.flatnonzero(np.concatenate([[True], np.diff(omega) != 0]))
    length = np.diff(np.append(first, omega.size))
    keep = length >= 2
    rate = 1.0 / float(np.median(np.diff(t)))
    if keep.sum() < 7 or np.sum(length[keep]) < 0.5 * omega.size:  # not a held signal: smooth it as it is
        return R * sg(omega, rate, half_s, degree=2)
    tk, wk = t[first[keep]], omega[first[keep]]
    period = float(np.median(np.diff(tk)))
    grid = tk[0] + np.arange(int(round((tk[-1] - tk[0]) / period)) + 1) * period
    ws = sg(np.interp(grid, tk, wk), 1.0 / period, half_s, degree=2)
    return R * np.interp(t, grid, ws)


def rig_config_of(rec: Recording, source: str, rig: str | None) -> RigConfig:
    """The rig config a recording carries (its own geometry and thrust), else ``rig`` (id or TOML)."""
    return config_for_recording(rec.meta.get("rig_config"), source, rig, RIG, "drum-mu needs")


@dataclass
class MuSeries:
    """mu(t) by eq. (2) and what it was computed from, per sample."""

    t: np.ndarray
    mu: np.ndarray  # eq. (2): friction coefficient, positive while sliding
    v: np.ndarray  # v_wz = R omega - R phi' [m/s]
    N: np.ndarray  # normal load (thrust gauge B) [N]
    phi: np.ndarray
    used: np.ndarray  # bool: samples the law is fitted to
    kinematics: dict[str, str]
    mu_diff: np.ndarray | None = None  # the same with phi' and phi'' differentiated from phi
    info: dict[str, object] = field(default_factory=dict)


def _mu_from(model, phi, vel, accel, thrust, v_drive):
    """eq. (2) through the rig physics: F (common convention) / N, turned into the paper's sign."""

    f = {"phi": phi, "vel": vel, "accel": accel, "thrust": thrust, "drum_speed": v_drive / model.p[drum.P.R],
         "drum_speed'": np.zeros_like(phi)}
    est = model.infer(f)
    v_wz = v_drive - vel
    # paper: mu = [bracket] / (N sgn v_wz), bracket = -F (our F acts on the pendulum, v_rel = -v_wz)
    sgn = np.where(v_wz >= 0, 1.0, -1.0)
    return -est.F / (est.N * sgn), est.N, v_wz


def mu_series(rec: Recording, cfg: RigConfig, source: str, *, v_min: float = V_MIN, guard_s: float = GUARD_S,
              mu1: float = 0.0) -> MuSeries:
    """mu(t) by eq. (2) from the measured channels, the relative sliding speed, and the sample selection."""

    for c in ("phi", "thrust", "drum_speed"):
        if c not in rec.channels:
            raise InputError(source, c, "missing channel (drum-mu needs phi, thrust, drum_speed; vel, accel)")
    t = np.asarray(rec.t, dtype=float)
    if t.size < 50:
        raise InputError(source, "t", f"only {t.size} samples")
    rate = 1.0 / float(np.median(np.diff(t)))
    reqs = [parse_effect(f"bearing-friction:mu1={mu1:g}", "--mu1")] if mu1 > 0 else []
    e, _ = effect_vector(cfg, reqs)
    model = DrumModel(cfg, e)
    R = float(cfg.mechanics.R_m)
    ch = {k: np.asarray(v, dtype=float) for k, v in rec.channels.items()}
    for c in ("phi", "thrust", "drum_speed", "vel", "accel"):
        if c in ch and not np.all(np.isfinite(ch[c])):
            raise InputError(source, c, "has missing (NaN) samples inside the record")
    phi, thrust = ch["phi"], ch["thrust"]
    if np.nanmin(thrust) <= 0:
        raise InputError(source, "thrust", f"normal load must be > 0 N (min {np.nanmin(thrust):.3g} N)")
    v_drive = drum_surface_speed(t, ch["drum_speed"], R, DRUM_SMOOTH_S)
    vel_d = R * sg(phi, rate, SG_HALF_S, 1)
    acc_d = R * sg(phi, rate, SG_HALF_S, 2)
    kin = {"phi": "phi (strain gauge A)", "N": "thrust (strain gauge B, instantaneous)",
           "drum": f"drum_speed x R (gauge E; zero-order hold undone, local quadratic +-{DRUM_SMOOTH_S:g} s)"}
    vel = ch.get("vel")
    acc = ch.get("accel")
    smooth = f"cubic smoothing +-{GAUGE_HALF_S * 1e3:g} ms"
    kin["phi_dot"] = (f"vel / R (induction velocity gauge D, {smooth})" if vel is not None else
                      f"d phi/dt (Savitzky-Golay +-{SG_HALF_S * 1e3:g} ms; no vel channel)")
    kin["phi_ddot"] = (f"accel / R (piezo accelerometer C, {smooth})" if acc is not None else
                       f"d2 phi/dt2 (Savitzky-Golay +-{SG_HALF_S * 1e3:g} ms; no accel channel)")
    vel = sg(vel, rate, GAUGE_HALF_S) if vel is not None else vel_d
    acc = sg(acc, rate, GAUGE_HALF_S) if acc is not None else acc_d
    mu, N, v = _mu_from(model, phi, vel, acc, thrust, v_drive)
    mu_d, _, _ = _mu_from(model, phi, vel_d, acc_d, thrust, v_drive)
    slow = np.abs(v) < v_min
    g = max(0, int(round(guard_s * rate)))
    near = _dilate(slow, g)
    edge = np.zeros(t.size, dtype=bool)
    ne = max(int(round(DRUM_SMOOTH_S * rate)), int(round(SG_HALF_S * rate)) + 1)
    edge[:ne] = edge[-ne:] = True
    used = ~near & ~edge & np.isfinite(mu)
    info = {"v_min_m_per_s": v_min, "guard_s": guard_s, "samples": int(t.size), "rate_Hz": rate,
            "slow": int(slow.sum()), "guard": int((near & ~slow).sum()), "used": int(used.sum()),
            "transitions": int(np.count_nonzero(np.diff(slow.astype(np.int8)))), "mu1": mu1}
    return MuSeries(t, mu, v, N, phi, used, kin, mu_d, info)


def _dilate(mask: np.ndarray, n: int) -> np.ndarray:
    """mask widened by n samples on both sides."""
    if n <= 0 or not mask.any():
        return mask.copy()
    c = np.concatenate([[0], np.cumsum(mask.astype(np.int64))])
    i = np.arange(mask.size)
    lo = np.clip(i - n, 0, mask.size)
    hi = np.clip(i + n + 1, 0, mask.size)
    return (c[hi] - c[lo]) > 0


def transition_distance(used_slow: np.ndarray, rate: float) -> np.ndarray:
    """Time [s] from each sample to the nearest sample of ``used_slow`` (inf if there is none)."""
    idx = np.flatnonzero(used_slow)
    if idx.size == 0:
        return np.full(used_slow.size, np.inf)
    i = np.arange(used_slow.size)
    k = np.searchsorted(idx, i)
    left = idx[np.clip(k - 1, 0, idx.size - 1)]
    right = idx[np.clip(k, 0, idx.size - 1)]
    return np.minimum(np.abs(i - left), np.abs(right - i)) / rate


def differentiation_check(s: MuSeries) -> dict[str, object]:
    """mu(t) with phi', phi'' differentiated from phi against mu(t) from the gauges, by distance to stick.

    Data only (no truth): where the two routes differ by more than their noise, the
    differentiated one is the biased one (the gauges are not filtered at all).
    """
    if s.mu_diff is None:
        return {}
    rate = float(s.info["rate_Hz"])
    dist = transition_distance(np.abs(s.v) < float(s.info["v_min_m_per_s"]), rate)
    d = s.mu_diff - s.mu
    ok = np.isfinite(d) & (np.abs(s.v) >= float(s.info["v_min_m_per_s"]))
    out: dict[str, object] = {"window_s": 2 * SG_HALF_S, "note": "mu via Savitzky-Golay phi', phi'' minus mu via "
                              "the velocity gauge and accelerometer; bias = mean, rms = root mean square"}
    for name, m in (("within_10ms", dist <= 0.010), ("10_to_30ms", (dist > 0.010) & (dist <= 0.030)),
                    ("beyond_30ms", dist > 0.030)):
        sel = ok & m
        out[name] = {"samples": int(sel.sum()),
                     "bias": float(np.mean(d[sel])) if sel.any() else None,
                     "rms": float(np.sqrt(np.mean(d[sel] ** 2))) if sel.any() else None}
    return out


# ----------------------------------------------------------------------------- law (3)


def law(v: np.ndarray, th: np.ndarray | tuple, eps: float) -> np.ndarray:
    """Law (3) at sliding speeds v >= 0 through the shared physics law (plus D v)."""
    A, B, C, D, E = (float(x) for x in th)
    return mu_drum(np.asarray(v, dtype=float), A, B, C, E, eps, 1.0) + D * np.asarray(v, dtype=float)


class Coef(BaseModel):
    model_config = ConfigDict(extra="forbid")
    value: float
    se: float | None = Field(description="standard error (Jacobian, inflated by the residual autocorrelation)")
    unit: str
    identified: bool = Field(description=f"se / |value| < {REL_SE_IDENTIFIED}")


class LawFit(BaseModel):
    """Law (3) fitted to (v, mu) samples: coefficients with standard errors, R^2, residual rms."""

    model_config = ConfigDict(extra="forbid")
    coefficients: dict[str, Coef]
    R2: float
    R: float = Field(description="sqrt(R2), the correlation coefficient paper 002 prints (R = 0.7837 in Fig. 5)")
    rms: float
    n: int
    n_eff: float = Field(description="samples / integrated autocorrelation time of the residuals")
    v_range_m_per_s: tuple[float, float]
    converged: bool
    message: str
    correlation: dict[str, dict[str, float]]

    def theta(self) -> np.ndarray:
        return np.array([self.coefficients[k].value for k in PARAMS])


def _basis(v: np.ndarray, B: float, C: float, eps: float) -> np.ndarray:
    """Columns multiplying A, E and D in law (3), from the shared law itself (A, E, D enter linearly)."""
    return np.column_stack([mu_drum(v, 1.0, B, C, 0.0, eps, 1.0), mu_drum(v, 0.0, B, C, 1.0, eps, 1.0), v])


def _project(v: np.ndarray, mu: np.ndarray, B: float, C: float, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """(theta, residual) with A, E, D by linear least squares for given B, C (variable projection)."""
    X = _basis(v, B, C, eps)
    coef, *_ = np.linalg.lstsq(X, mu, rcond=None)
    return np.array([coef[0], B, C, coef[2], coef[1]]), X @ coef - mu


def _start(v: np.ndarray, mu: np.ndarray, eps: float) -> np.ndarray:
    """The best (B, C) of a log grid, A, D, E projected out (a subsample: it only has to find the valley)."""
    step = max(1, v.size // 6000)
    vs, ms = v[::step], mu[::step]
    best = (np.inf, None)
    for B in np.geomspace(LOG_BOUNDS[0][0], LOG_BOUNDS[0][1], 31):
        for C in np.geomspace(LOG_BOUNDS[1][0], LOG_BOUNDS[1][1], 31):
            th, r = _project(vs, ms, B, C, eps)
            ss = float(r @ r)
            if ss < best[0]:
                best = (ss, th)
    return best[1]


def integrated_autocorrelation(r: np.ndarray, max_lag: int = 2000) -> float:
    """1 + 2 sum of the residuals' autocorrelation up to its first non-positive lag (>= 1)."""
    r = r - r.mean()
    n = r.size
    if n < 10:
        return 1.0
    m = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(r, m)
    ac = np.fft.irfft(f * np.conj(f), m)[: min(n, max_lag)]
    ac = ac / ac[0]
    tau = 1.0
    for k in range(1, ac.size):
        if ac[k] <= 0:
            break
        tau += 2.0 * ac[k]
    return max(1.0, float(tau))


def fit_law(v: np.ndarray, mu: np.ndarray, eps: float) -> LawFit:
    """Law (3) by nonlinear least squares on samples in time order (v > 0 sliding speed, mu by eq. (2)).

    Variable projection: the search runs over (log B, log C) only, with A, D, E solved linearly
    at every step, so it cannot stall in the long curved A-B valley (A(1 - exp(-B v)) ~ A B v
    while B v is small) and needs no start values from the user. Standard errors come from the
    full five-parameter Jacobian at the optimum.
    """
    v = np.asarray(v, dtype=float)
    mu = np.asarray(mu, dtype=float)
    if v.size < 20:
        raise ValueError(f"only {v.size} samples to fit")
    x0 = _start(v, mu, eps)
    lo = np.log([LOG_BOUNDS[0][0], LOG_BOUNDS[1][0]])
    hi = np.log([LOG_BOUNDS[0][1], LOG_BOUNDS[1][1]])
    z0 = np.clip(np.log(x0[1:3]), lo + 1e-9, hi - 1e-9)
    res = least_squares(lambda z: _project(v, mu, math.exp(z[0]), math.exp(z[1]), eps)[1], z0, bounds=(lo, hi),
                        method="trf", x_scale=1.0, diff_step=1e-7, xtol=1e-12, ftol=1e-12, gtol=1e-12,
                        max_nfev=400)
    th, r = _project(v, mu, math.exp(res.x[0]), math.exp(res.x[1]), eps)
    n = v.size
    s2 = float(r @ r) / max(n - 5, 1)
    tau = integrated_autocorrelation(r)
    J = np.empty((n, 5))
    for i in range(5):
        h = 1e-6 * max(abs(th[i]), 1e-6)
        d = np.zeros(5)
        d[i] = h
        J[:, i] = (law(v, th + d, eps) - law(v, th - d, eps)) / (2 * h)
    try:
        cov = np.linalg.inv(J.T @ J) * s2 * tau
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
        corr = cov / np.outer(se, se)
    except np.linalg.LinAlgError:
        se = np.full(5, np.nan)
        corr = np.full((5, 5), np.nan)
    ss_tot = float(np.sum((mu - mu.mean()) ** 2))
    r2 = 1.0 - float(r @ r) / ss_tot if ss_tot > 0 else float("nan")
    at_bound = bool(np.any(np.isclose(res.x, lo, atol=1e-6) | np.isclose(res.x, hi, atol=1e-6)))
    coefs = {}
    for k, val, s in zip(PARAMS, th, se):
        ok = bool(np.isfinite(s) and abs(val) > 0 and s / abs(val) < REL_SE_IDENTIFIED)
        coefs[k] = Coef(value=float(val), se=float(s) if np.isfinite(s) else None, unit=UNITS[k], identified=ok)
    return LawFit(coefficients=coefs, R2=r2, R=math.sqrt(max(r2, 0.0)) if np.isfinite(r2) else float("nan"),
                  rms=float(np.sqrt(np.mean(r ** 2))), n=int(n), n_eff=n / tau,
                  v_range_m_per_s=(float(v.min()), float(v.max())), converged=bool(res.success) and not at_bound,
                  message=str(res.message) + (" (B or C at its bound)" if at_bound else ""),
                  correlation={a: {b: float(corr[i, j]) for j, b in enumerate(PARAMS) if j != i}
                               for i, a in enumerate(PARAMS)})


# ----------------------------------------------------------------------------- the whole analysis


class DrumMuResult(BaseModel):
    """What ``daq analyse drum-mu`` prints with --json (and writes to REPORT/drum-mu.json)."""

    model_config = ConfigDict(extra="forbid")
    analysis: str = "drum-mu"
    data: str
    rig: str
    law: str = LAW
    sgn_eps_m_per_s: float = Field(description="sgn(v) regularisation of the law as the rig applies it")
    kinematics: dict[str, str]
    thrust_N: dict[str, float] = Field(description="the thrust gauge over the used samples: mean, std, min, max")
    drum_speed_m_per_s: dict[str, float] = Field(description="surface speed: median, min, max over the record")
    selection: dict[str, float | int]
    fit: LawFit
    differentiation_check: dict[str, object]
    seconds: float
    figures: list[str] = Field(default_factory=list)


def analyse_drum_mu(path: str | Path, *, rig: str | None = None, v_min: float = V_MIN, guard_s: float = GUARD_S,
                    mu1: float = 0.0, t_from: float | None = None,
                    t_to: float | None = None) -> tuple[DrumMuResult, MuSeries]:
    """Read a drum-pendulum recording, mu(t) by eq. (2), law (3) fitted; (result, the series for figures)."""


    t0 = time.perf_counter()
    src = str(path)
    if not Path(path).is_file():
        raise InputError(src, "(file)", "no such file")
    if not v_min > 0:
        raise InputError("--v-min", "--v-min", "must be > 0")
    if not guard_s >= 0:
        raise InputError("--guard", "--guard", "must be >= 0")
    if not mu1 >= 0:
        raise InputError("--mu1", "--mu1", "must be >= 0")
    rec = load_data(path, rig or (RIG if Path(path).suffix.lower() in (".csv", ".tdms") else None))
    cfg = rig_config_of(rec, src, rig)
    if t_from is not None or t_to is not None:
        m = (rec.t >= (t_from if t_from is not None else -np.inf)) & (rec.t <= (t_to if t_to is not None else np.inf))
        if m.sum() < 50:
            raise InputError(src, "--from/--to", "fewer than 50 samples in the interval")
        rec = Recording(rec.rig, rec.t[m], {k: v[m] for k, v in rec.channels.items()}, rec.units, rec.meta)
    s = mu_series(rec, cfg, src, v_min=v_min, guard_s=guard_s, mu1=mu1)
    u = s.used
    if u.sum() < 200:
        raise InputError(src, "vel", f"only {int(u.sum())} samples slide faster than {v_min:g} m/s away from "
                         "stick: nothing to fit law (3) to (did the drum turn?)")
    eps = float(cfg.friction.sgn_eps_m_per_s)
    fit = fit_law(np.abs(s.v[u]), s.mu[u], eps)
    res = DrumMuResult(
        data=src, rig=cfg.rig, sgn_eps_m_per_s=eps, kinematics=s.kinematics,
        thrust_N={"mean": float(np.mean(s.N[u])), "std": float(np.std(s.N[u])), "min": float(np.min(s.N[u])),
                  "max": float(np.max(s.N[u]))},
        drum_speed_m_per_s=_drum_stats(rec, cfg),
        selection={k: v for k, v in s.info.items() if isinstance(v, (int, float))},
        fit=fit, differentiation_check=differentiation_check(s), seconds=time.perf_counter() - t0)
    return res, s


def _drum_stats(rec: Recording, cfg: RigConfig) -> dict[str, float]:
    v = np.asarray(rec.channels["drum_speed"], dtype=float) * cfg.mechanics.R_m
    return {"median": float(np.median(v)), "min": float(np.min(v)), "max": float(np.max(v))}


# ----------------------------------------------------------------------------- figures


def figures(res: DrumMuResult, s: MuSeries, outdir: Path) -> list[Path]:
    """mu(t) with the used samples marked; mu vs v with the fit; residuals vs v and t."""

    matplotlib.use("Agg")

    outdir.mkdir(parents=True, exist_ok=True)
    eps = res.sgn_eps_m_per_s
    th = res.fit.theta()
    name = Path(res.data).name
    c = res.fit.coefficients
    coef_txt = (f"A={c['A'].value:.4g}  B={c['B'].value:.4g} s/m  C={c['C'].value:.4g} s/m  "
                f"D={c['D'].value:.4g} s/m  E={c['E'].value:.4g}  R²={res.fit.R2:.4f}")
    paths = []
    u = s.used
    av = np.abs(s.v)

    # 1: mu(t)
    fig, axs = plt.subplots(3, 1, figsize=(12, 8.5), sharex=True, constrained_layout=True)
    ax = axs[0]
    ax.plot(s.t, s.mu, lw=0.3, color="0.7", label="not used (|v_wz| < v_min, guard, record edges)")
    ax.plot(s.t, np.where(u, s.mu, np.nan), lw=0.4, color="C0", label="μ(t) by eq. (2), used for law (3)")
    lo, hi = np.nanpercentile(s.mu[u], [0.5, 99.5])
    pad = 0.3 * (hi - lo) + 1e-3
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_ylabel("μ [-]")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"{name}: friction coefficient μ(t) by paper 002 eq. (2) "
                 "from φ, φ̇ (gauge D), φ̈ (accelerometer C)")
    vmin = float(res.selection["v_min_m_per_s"])
    axs[1].plot(s.t, s.v * 1e3, lw=0.4, color="C1", label="v_wz")
    axs[1].axhline(vmin * 1e3, color="k", lw=0.7, ls=":", label=f"±v_min = {vmin * 1e3:g} mm/s")
    axs[1].axhline(-vmin * 1e3, color="k", lw=0.7, ls=":")
    axs[1].set_ylabel("v_wz = R(ω − φ̇) [mm/s]")
    axs[1].legend(loc="upper right", fontsize=8)
    axs[2].plot(s.t, s.N, lw=0.4, color="C2")
    axs[2].set_ylabel("N (thrust gauge B) [N]")
    axs[2].set_xlabel("t [s]")
    for a in axs:
        a.grid(alpha=0.3)
    paths.append(_save(fig, outdir / "mu_t.png"))

    # 2: mu vs v with the fit

    fig, ax = plt.subplots(1, 2, figsize=(13, 5.5), constrained_layout=True)
    vv = np.geomspace(max(av[u].min(), 1e-5), av[u].max(), 400)
    edges = np.geomspace(vv[0], vv[-1] * 1.0001, 40)
    idx = np.digitize(av[u], edges)
    full = [i for i in range(1, edges.size) if np.sum(idx == i) >= 20]
    mids = np.array([np.median(av[u][idx == i]) for i in full])
    meds = np.array([np.median(s.mu[u][idx == i]) for i in full])
    step = max(1, int(u.sum()) // 8000)
    for k, axk in enumerate(ax):
        axk.plot(av[u][::step] * 1e3, s.mu[u][::step], ".", ms=1.2, alpha=0.3, color="C0")
        axk.plot(mids * 1e3, meds, "o", ms=4, color="C1")
        axk.plot(vv * 1e3, law(vv, th, eps), color="k", lw=1.5)
        axk.set_xlabel("sliding speed v_wz [mm/s]" + (" (log scale)" if k else ""))
        axk.set_ylabel("μ [-]")
        if k:
            _log_mm(axk)
        lo, hi = np.nanpercentile(s.mu[u], [0.2, 99.8])
        axk.set_ylim(lo - 0.15 * (hi - lo), hi + 0.15 * (hi - lo))
        axk.grid(alpha=0.3)
    ax[0].legend([Line2D([], [], ls="", marker=".", color="C0"), Line2D([], [], ls="", marker="o", ms=4, color="C1"),
                  Line2D([], [], color="k", lw=1.5)], ["μ(t) samples used", "bin medians", "law (3) fitted"],
                 fontsize=8, loc="upper center")
    fig.suptitle(f"{name}: law (3) fitted, P ≈ {res.thrust_N['mean']:.1f} N\n{coef_txt}", fontsize=10)
    paths.append(_save(fig, outdir / "mu_v.png"))

    # 3: residuals
    r = s.mu[u] - law(av[u], th, eps)
    rmed = np.array([np.median(r[idx == i]) for i in full])
    fig, ax = plt.subplots(1, 2, figsize=(13, 4.8), constrained_layout=True)
    ax[0].plot(av[u][::step] * 1e3, r[::step], ".", ms=1.2, alpha=0.3, label="samples")
    ax[0].plot(mids * 1e3, rmed, "o-", ms=3, lw=1, color="C3", label="bin medians")
    _log_mm(ax[0])
    ax[0].axhline(0, color="k", lw=0.8)
    ax[0].set_xlabel("sliding speed v_wz [mm/s] (log scale)")
    ax[0].set_ylabel("μ − law (3) [-]")
    ax[0].set_title(f"residuals vs v (rms {res.fit.rms:.2g}, R² = {res.fit.R2:.4f})", fontsize=10)
    ax[0].legend([Line2D([], [], ls="", marker=".", color="C0"), Line2D([], [], marker="o", ms=3, color="C3")],
                 ["samples", "bin medians"], fontsize=8, loc="upper right")
    ax[1].plot(s.t[u][::step], r[::step], ".", ms=1.2, alpha=0.3, color="C2")
    ax[1].axhline(0, color="k", lw=0.8)
    ax[1].set_xlabel("t [s]")
    ax[1].set_ylabel("μ − law (3) [-]")
    ax[1].set_title(f"residuals vs time (n = {res.fit.n}, effective {res.fit.n_eff:.0f})", fontsize=10)
    q = np.nanpercentile(np.abs(r), 99.8)
    for a in ax:
        a.grid(alpha=0.3)
        a.set_ylim(-1.3 * q, 1.3 * q)
    fig.suptitle(f"{name}: residuals of law (3)", fontsize=11)
    paths.append(_save(fig, outdir / "residuals.png"))
    return paths


def _save(fig, path: Path) -> Path:
    """Write a figure atomically (no half-written PNG after a crash) and close it."""


    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path


def _log_mm(ax) -> None:
    """Log x axis in mm/s with plain tick labels (1, 2, 5, 10, ...)."""

    ax.set_xscale("log")
    lo, hi = ax.get_xlim()
    ticks = [x for x in (0.1, 0.2, 0.5, 1, 2, 3, 5, 10, 20, 30, 50, 100, 200) if lo <= x <= hi]
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
