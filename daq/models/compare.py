"""Model versus measurement: the error, its noise floor, and where the model fails.

Why these breakdowns: a single error number says *that* a model fails; the
breakdown by regime (stick/creep, slip, accelerating vs decelerating sliding,
belt-speed bands), by time and by signal says *where*, which is what points to
the missing physics. Forward-simulation invariants (stick-slip frequency, slip
amplitude, stick fraction, spectrogram) and the cycles' distributions (stick time,
force drop, slip duration, period: cycle_features.py) judge the model on cycle
features, which phase drift cannot swamp.

Decision record: docs/decisions/0009-held-out-scoring-and-noise-floor.md.
"""

from __future__ import annotations

import math

import numpy as np

from daq.physics.contact import AUX
from daq.signals import dominant_frequency, paper_spectrogram

from . import robust
from .cycle_features import load_cycles, side_by_side
from .session import Fitted, Session

N_TIME_BINS = 10
CYCLE_SEED = 7  # the noise put on the free run before its cycles are read (fixed: the same JSON every run)
OUTLIER_SIGMAS = 5.0  # a residual this many noise levels off counts as an outlier (Gaussian noise: 6e-7 of samples)
ERROR_DEFINITION = ("rms of model - measured of the primary signal on the held-out windows (every third short "
                    "window, never used to fit the model's parameters), each simulated from the data's state at its "
                    "start (multiple shooting; start velocities, and at slow sampling positions, fitted per window); "
                    "the very error diagnose scores. error_all_windows: the same over fit and held-out windows (flagged "
                    "transients are not scored)")


def _rms(x: np.ndarray) -> float:
    return float(math.sqrt(np.mean(x * x))) if x.size else float("nan")


def residual_samples(session: Session, fitted: Fitted) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, int]]:
    """Sample indices and residuals (model - measured) of every scored window (fit and held-out; a flagged
    transient is not scored: one at ~1 mm made "all windows" 114 um against 30 um held out and every regime's
    bar ~1e-4 m on a 750 000-sample belt record), start excluded; and per output how many of the samples the
    fit's loss counts at less than their square (beyond Huber's threshold: robust.py)."""
    scored = session.win.scored()
    pr = fitted.problem
    shot = pr.shoot(fitted.values, scored, fitted.start_values(scored))
    z = np.stack([(shot.pred[k][:, pr.r0:] - shot.meas[k][:, pr.r0:]) / session.m.sigma[k] for k in pr.outputs], axis=1)
    capped = robust.downweighted(np.nan_to_num(z, nan=1e6), pr.loss)
    return (shot.index[:, 1:].ravel(), {k: (shot.pred[k][:, 1:] - shot.meas[k][:, 1:]).ravel() for k in shot.pred},
            {k: int(capped[i]) for i, k in enumerate(pr.outputs)})


def residual_outliers(session: Session, res: dict[str, np.ndarray]) -> dict[str, int]:
    """Per output, the scored samples the fitted model misses by more than OUTLIER_SIGMAS noise levels: what
    spike repair left (bursts, smaller glitches) or where the model fails (decision 25)."""
    return {k: int(np.sum(np.abs(r) > OUTLIER_SIGMAS * session.m.sigma[k])) for k, r in res.items()}


def regimes(session: Session, idx: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks over the residual samples, from the data (not from the model under test)."""
    m = session.m
    v_stick = m.stick_threshold(session.cfg)
    vr = m.v_rel[idx]
    stuck = np.abs(vr) < v_stick
    grow = m.d_abs_v_rel[idx] > 0
    out = {"stick/creep": stuck, "slip": ~stuck, "slip, accelerating": ~stuck & grow,
           "slip, decelerating": ~stuck & ~grow}
    vb = m.drive_measured[idx]
    edges = np.quantile(m.drive_measured, [0.0, 1 / 3, 2 / 3, 1.0])
    for i in range(3):
        lo, hi = edges[i], edges[i + 1]
        sel = (vb >= lo) & (vb <= hi if i == 2 else vb < hi)
        out[f"belt speed {lo * 1e3:.0f}-{hi * 1e3:.0f} mm/s"] = sel
    return out


def invariants(session: Session, t: np.ndarray, x: np.ndarray, v_rel: np.ndarray) -> dict[str, float]:
    """Cycle features of one signal: stick-slip frequency, slip amplitude, stick fraction."""
    xd = x - np.polynomial.polynomial.polyval(t, np.polynomial.polynomial.polyfit(t, x, 3))
    f = dominant_frequency(t, xd, fmin=0.5) if t.size > 64 else float("nan")
    # slip amplitude: median peak-to-peak per period of the dominant frequency
    n = max(2, int(round(session.m.rate / f))) if np.isfinite(f) and f > 0 else xd.size
    k = xd.size // n
    p2p = np.ptp(xd[: k * n].reshape(k, n), axis=1) if k else np.array([np.ptp(xd)])
    return {"stick_slip_frequency_Hz": float(f), "slip_amplitude": float(np.median(p2p)),
            "stick_fraction": float(np.mean(np.abs(v_rel) < session.m.stick_threshold(session.cfg)))}


def spectral_line(t: np.ndarray, x: np.ndarray, fmin: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """The strongest line of paper 001's spectrogram over time (for side-by-side comparison)."""
    f, tt, pxx = paper_spectrogram(t, x - x.mean())
    ok = f >= fmin
    return tt, f[ok][np.argmax(pxx[ok], axis=0)]


def compare(session: Session, fitted: Fitted, floor: dict[str, float]) -> dict:
    """The SPEC's compare JSON: error and noise floor of the primary signal, and the breakdowns."""
    m = session.m
    primary = session.primary
    idx, res, capped = residual_samples(session, fitted)
    out: dict = {
        "data": session.source,
        "filled_samples": session.rec.meta.get("filled", {}),
        "start_from_data": session.law_guess,
        "outliers": {k: int(v.size) for k, v in session.m.outliers.items()},
        "residual_outliers": residual_outliers(session, res),
        "loss": fitted.problem.loss,  # of the fit (robust.py): huber or squares
        "loss_capped": capped,  # per output, scored samples beyond Huber's threshold (counted linearly, not squared)
        "averaged": session.m.averaged,  # the file's samples per compared sample (block means to the model's step)
        "model": fitted.model.describe(),
        "model_digest": fitted.model.digest(),
        "error": fitted.rms(primary, "held"),
        "error_unit": m.units[primary],
        "error_signal": primary,
        "noise_floor": floor[primary],
        "clock_jitter_s": session.timing_noise(fitted),  # read from the residual, counted in the floor (0: none)
        "error_all_windows": _rms(res[primary]),
        "error_definition": ERROR_DEFINITION,
        "parameters": {k: {"value": fitted.values[k], "std": fitted.fit.std.get(k)} for k in fitted.model.free_names()},
        "by_signal": {k: {"error": _rms(res[k]), "unit": m.units[k], "noise_floor": floor[k],
                          "noise_sigma": m.sigma[k]} for k in m.outputs},
    }
    out["by_regime"] = {name: {"error": _rms(res[primary][mask]), "fraction": float(mask.mean())}
                        for name, mask in regimes(session, idx).items() if mask.any()}
    t_idx = m.t[idx]
    edges = np.linspace(m.t[0], m.t[-1], N_TIME_BINS + 1)
    bins = []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (t_idx >= a) & (t_idx < b)
        if sel.any():
            bins.append({"t0": float(a), "t1": float(b), "error": _rms(res[primary][sel])})
    out["by_time"] = bins
    worst = max(out["by_regime"].items(), key=lambda kv: kv[1]["error"] if np.isfinite(kv[1]["error"]) else -1)
    out["worst_regime"] = worst[0]
    # forward simulation over the whole record
    fidx, pred, states, aux = session.free_run(fitted)

    tt = m.t[fidx]
    meas_inv = invariants(session, tt, m.outputs[primary][fidx], m.v_rel[fidx])
    model_inv = invariants(session, tt, pred[primary], aux[:, AUX.V_REL])
    out["invariants"] = {k: {"measured": meas_inv[k], "model": model_inv[k]} for k in meas_inv}
    # the free run read as the record is: with the record's noise on it (fixed seed), by the same rule
    sigma = m.sigma[primary]
    noisy = pred[primary] + np.random.default_rng(CYCLE_SEED).normal(0.0, sigma, pred[primary].size)
    cyc_rec, cyc_model = load_cycles(tt, m.outputs[primary][fidx], sigma), load_cycles(tt, noisy, sigma)
    out["cycles"] = {**side_by_side(cyc_rec, cyc_model), "signal": primary, "unit": m.units[primary]}
    try:
        ts, fm = spectral_line(tt, m.outputs[primary][fidx])
        _, fs = spectral_line(tt, pred[primary])
        out["spectral_line"] = {"t": ts.tolist(), "measured_Hz": fm.tolist(), "model_Hz": fs.tolist()}
    except ValueError:
        out["spectral_line"] = None
    out["_plot"] = {"idx": idx, "res": res, "fidx": fidx, "pred": pred, "states": states, "aux": aux,
                    "cycles": (cyc_rec, cyc_model)}
    return out
