"""Paper 002 step 1: the friction coefficient mu(t) by eq. (2) from the measured kinematics, and which samples to fit.

mu(t) by eq. (2), from the measured phi, phi', phi'' and the thrust N:
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

The Savitzky-Golay smoothing and derivatives are the shared ``daq.signals.sg`` with a minimum
half-width of 2 samples (this analysis' own choice, kept from its former local copy).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from daq.config import RigConfig
from daq.errors import InputError
from daq.estimation.rigmodels import DrumModel
from daq.io.interchange import Recording
from daq.physics import drum
from daq.signals import sg
from daq.sim.effectset import effect_vector, parse_effect

V_MIN = 3e-3  # [m/s] slower samples are not fitted (stick, reversal; and see mu_series)
GUARD_S = 0.015  # [s] around every such sample
GAUGE_HALF_S = 0.005  # [s] half-width of the zero-phase cubic smoothing of the vel and accel gauges
SG_HALF_S = 0.005  # [s] half-width of the Savitzky-Golay derivatives of phi (fallback and check)
DRUM_SMOOTH_S = 0.05  # [s] half-width of the local quadratic through the drum speed updates


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
        return R * sg(omega, rate, half_s, degree=2, min_half=2)
    tk, wk = t[first[keep]], omega[first[keep]]
    period = float(np.median(np.diff(tk)))
    grid = tk[0] + np.arange(int(round((tk[-1] - tk[0]) / period)) + 1) * period
    ws = sg(np.interp(grid, tk, wk), 1.0 / period, half_s, degree=2, min_half=2)
    return R * np.interp(t, grid, ws)


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
    vel_d = R * sg(phi, rate, SG_HALF_S, 1, min_half=2)
    acc_d = R * sg(phi, rate, SG_HALF_S, 2, min_half=2)
    kin = {"phi": "phi (strain gauge A)", "N": "thrust (strain gauge B, instantaneous)",
           "drum": f"drum_speed x R (gauge E; zero-order hold undone, local quadratic +-{DRUM_SMOOTH_S:g} s)"}
    vel = ch.get("vel")
    acc = ch.get("accel")
    smooth = f"cubic smoothing +-{GAUGE_HALF_S * 1e3:g} ms"
    kin["phi_dot"] = (f"vel / R (induction velocity gauge D, {smooth})" if vel is not None else
                      f"d phi/dt (Savitzky-Golay +-{SG_HALF_S * 1e3:g} ms; no vel channel)")
    kin["phi_ddot"] = (f"accel / R (piezo accelerometer C, {smooth})" if acc is not None else
                       f"d2 phi/dt2 (Savitzky-Golay +-{SG_HALF_S * 1e3:g} ms; no accel channel)")
    vel = sg(vel, rate, GAUGE_HALF_S, min_half=2) if vel is not None else vel_d
    acc = sg(acc, rate, GAUGE_HALF_S, min_half=2) if acc is not None else acc_d
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

