"""Model versus measurement: the error, its noise floor, and where the model fails.

Why these breakdowns: a single error number says *that* a model fails; the
breakdown by regime (stick/creep, slip, accelerating vs decelerating sliding,
belt-speed bands), by time and by signal says *where*, which is what points to
the missing physics. Forward-simulation invariants (stick-slip frequency, slip
amplitude, stick fraction, spectrogram) and the cycles' distributions (stick time,
force drop, slip duration, period: cycle_features.py) judge the model on cycle
features, which phase drift cannot swamp. Three readings say where in the cycle and in the
mechanics a model fails (issue 31: a measured record the catalog did not explain): the error by
cycle phase (slip, loading, at the peak load, read from the record), the loading rates early and
late in the stick against the drive's speed (a stuck slider is loaded at the drive's speed; later
slower is creep), and the motion's spectral line against the rig file's lowest natural frequency.

Decision record: docs/decisions/0009-held-out-scoring-and-noise-floor.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.signal import medfilt, welch

from daq.physics.contact import AUX
from daq.signals import dominant_frequency, frequency_against_amplitude, paper_spectrogram, ringing_by_amplitude

from ..fit import robust
from ..fit.cycle_features import PHASES, cycle_phases, load_cycles, side_by_side
from ..fit.session import Fitted, Session

N_TIME_BINS = 10
# within this of 50 or 60 Hz (or their 2nd, 3rd harmonics) a line is the mains' hum on the gauge, not motion (the
# lab's 42 um/s and 1.1 mm/s records: 49.99 and 50.00 Hz, the strongest line of both)
MAINS_TOLERANCE = 0.01
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


@dataclass
class Drawn:
    """The arrays compare's figures draw, kept out of its JSON: the scored samples and their residuals, the free
    run (sample indices, predictions, states, aux), the cycles of record and model, and where the record rings above
    the rig's mechanics each window's amplitude and frequency (ringing_windows; None elsewhere)."""

    idx: np.ndarray
    res: dict[str, np.ndarray]
    fidx: np.ndarray
    pred: dict[str, np.ndarray]
    states: np.ndarray
    aux: np.ndarray
    cycles: tuple[dict, dict]
    ringing: tuple[np.ndarray, np.ndarray] | None = None


class Compared(NamedTuple):
    """compare's answer: the SPEC's compare JSON, and the arrays its figures draw (kept out of the JSON)."""

    result: dict
    drawn: Drawn


def compare(session: Session, fitted: Fitted, floor: dict[str, float]) -> Compared:
    """The SPEC's compare JSON (error and noise floor of the primary signal, and the breakdowns), and the arrays
    its figures draw."""
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
    cyc = cycle_readings(session, fitted, idx, res[primary], fidx, pred[primary])
    readings = cyc.readings
    out.update(readings)
    try:
        ts, fm = spectral_line(tt, m.outputs[primary][fidx])
        _, fs = spectral_line(tt, pred[primary])
        out["spectral_line"] = {"t": ts.tolist(), "measured_Hz": fm.tolist(), "model_Hz": fs.tolist()}
    except ValueError:
        out["spectral_line"] = None
    return Compared(result=out, drawn=Drawn(idx=idx, res=res, fidx=fidx, pred=pred, states=states, aux=aux,
                                          cycles=cyc.cycles, ringing=cyc.ringing))


def loading(record: dict[str, np.ndarray], model: dict[str, np.ndarray], drive_speed: float) -> dict:
    """The medians of the loading rates early and late in the stick (cycle_features.loading_rates) over the drive's
    speed, record and model: 1 where the contact holds and the mechanics are the rig file's, less late where the
    slider creeps before it slips. NaN without cycles or without a drive."""
    def ratio(c: dict[str, np.ndarray], k: str) -> float:
        x = c[k][np.isfinite(c[k])]
        return float(np.median(x) / drive_speed) if x.size and drive_speed > 0.0 else float("nan")
    return {"drive_speed": drive_speed,
            **{f"{k}_{who}": ratio(c, f"load_rate_{k}") for who, c in (("record", record), ("model", model))
               for k in ("early", "late")}}


def by_cycle_phase(cycles: dict[str, np.ndarray], at: np.ndarray, n: int, res: np.ndarray) -> dict:
    """The error (rms of model - measured) of the residual samples ``res`` at ``at`` (indices into the ``n``
    samples the record's ``cycles`` were read from) per cycle phase, and each phase's share of the samples; empty
    where the record has no cycles."""
    code = cycle_phases(n, cycles)
    ok = (at >= 0) & (at < n)
    ph = np.where(ok, code[np.clip(at, 0, n - 1)], 0)
    return {name: {"error": _rms(res[ph == c]), "fraction": float(np.mean(ph == c))}
            for c, name in PHASES.items() if np.any(ph == c)}


RINGS_OFF = 0.1  # a record ringing more than this share off the rig's natural frequency rings off its mechanics


def motion(t: np.ndarray, record: np.ndarray, model: np.ndarray, modes_hz: dict[str, list[float]]) -> dict:
    """Where the record and the model ring: the strongest line of each within a factor 2 of the rig's lowest natural
    frequency (its mechanics without friction, SimRig.modes_hz), the mains' lines masked (MAINS_TOLERANCE), and the
    model's power in that band over the record's. Why a band: the strongest line of the whole spectrum is the cycle,
    the drift or the hum (the lab's records: 50 Hz at 42 um/s, a 0.5 Hz wander at 1.1 mm/s); near the natural
    frequency it is the motion, and a record that rings off it while the model rings on it (4.3 mm/s: 56.9 Hz
    against 43.1 Hz) has mechanics other than the rig file's, or a contact that adds stiffness (ringing_windows)."""
    natural = min(next(iter(modes_hz.values()))) if modes_hz else float("nan")
    out = {"natural_Hz": natural, "band_Hz": [natural / 2.0, natural * 2.0], "line_Hz_record": float("nan"),
           "line_Hz_model": float("nan"), "band_power_model_over_record": float("nan")}
    rate = 1.0 / float(np.median(np.diff(t)))
    if not np.isfinite(natural) or natural * 2.0 >= rate / 2.0 or t.size < 64:
        return out
    spectra = []
    for x in (record, model):
        f, pxx = welch(medfilt(x, 5) - np.mean(x), fs=rate, nperseg=min(x.size, int(8.0 * rate)))
        spectra.append(pxx)
    band = (f >= natural / 2.0) & (f <= natural * 2.0)
    for mains in (50.0, 60.0):
        for h in (1, 2, 3):
            band &= np.abs(f / (mains * h) - 1.0) > MAINS_TOLERANCE
    if not band.any():
        return out
    out["line_Hz_record"] = float(f[band][np.argmax(spectra[0][band])])
    out["line_Hz_model"] = float(f[band][np.argmax(spectra[1][band])])
    out["band_power_model_over_record"] = float(spectra[1][band].sum() / max(spectra[0][band].sum(), 1e-300))
    return out


def ringing_windows(t: np.ndarray, record: np.ndarray, mo: dict, noise: float,
                    drive: float) -> tuple[dict, np.ndarray, np.ndarray] | None:
    """Where a record rings more than RINGS_OFF above the rig's natural frequency (``mo``: :func:`motion`'s reading),
    its ringing read window by window: how its frequency moves with its amplitude
    (signals.frequency_against_amplitude, with the smallest swings' peak speed against the drive's: below it the
    slider slides throughout), and each window's amplitude and frequency (for the figure). A spring and a mass ring
    at one frequency whatever the amplitude, so this is the first reading between those two readings. None below:
    ringing below its mechanics is what sticking does (every simulated stick-slip record), and the reading costs
    0.5-1 s a record at 100 Hz, too much for every compare."""
    line = mo["line_Hz_record"]
    if not line > (1.0 + RINGS_OFF) * mo["natural_Hz"]:
        return None
    amps, freqs = ringing_by_amplitude(record, 1.0 / float(np.median(np.diff(t))), line, noise)
    amp = frequency_against_amplitude(amps, freqs)
    amp["swing_speed_small"] = 2.0 * math.pi * amp["line_Hz_small"] * amp["amplitude_q25"]
    amp["drive_speed"] = float(drive)
    return amp, amps, freqs


def where_it_lives(session: Session, fitted: Fitted) -> dict:
    """compare's readings of where in the cycle and in the mechanics a fitted model fails (cycle_readings), for
    diagnose to state when no catalog effect explains the error, or only part of it: by_cycle_phase, loading,
    motion, and the cycles' summaries of record and model."""
    idx, res, _ = residual_samples(session, fitted)
    fidx, pred, _, _ = session.free_run(fitted)
    readings = cycle_readings(session, fitted, idx, res[session.primary], fidx, pred[session.primary]).readings
    cycles = readings["cycles"]
    return {"by_cycle_phase": readings["by_cycle_phase"], "loading": cycles["loading"], "motion": readings["motion"],
            "cycles": {"record": cycles["record"], "model": cycles["model"]}}


class CycleReadings(NamedTuple):
    """compare's cycle readings (JSON) and what its figures draw of them."""

    readings: dict
    cycles: tuple[dict, dict]  # the record's and the model's cycle tables
    ringing: tuple[np.ndarray, np.ndarray] | None  # each window's amplitude and frequency (ringing_windows)


def cycle_readings(session: Session, fitted: Fitted, idx: np.ndarray, res: np.ndarray, fidx: np.ndarray,
                   pred: np.ndarray) -> CycleReadings:
    """From the primary signal's residual samples (``res`` at ``idx``) and the free run (``pred`` at ``fidx``): the
    cycles record / model side by side with their loading, the error by cycle phase, the ringing; and the two
    cycle tables and the ringing's windows (for the figures). The free run is read with the record's noise on it (fixed seed), by the same
    rule as the record."""
    m, primary = session.m, session.primary
    tt, x = m.t[fidx], m.outputs[primary][fidx]
    noisy = pred + np.random.default_rng(CYCLE_SEED).normal(0.0, m.sigma[primary], pred.size)
    cyc_rec, cyc_model = load_cycles(tt, x, m.sigma[primary]), load_cycles(tt, noisy, m.sigma[primary])
    drive = float(np.median(np.abs(m.drive_command[fidx])))
    out = {"cycles": {**side_by_side(cyc_rec, cyc_model), "signal": primary, "unit": m.units[primary],
                      "loading": loading(cyc_rec, cyc_model, drive)},
           "by_cycle_phase": by_cycle_phase(cyc_rec, idx - fidx[0], fidx.size, res),
           "motion": motion(tt, x, noisy, fitted.problem.sim(fitted.values).modes_hz())}
    ringing = ringing_windows(tt, x, out["motion"], m.sigma[primary], drive)
    if ringing is not None:
        out["motion"]["by_amplitude"] = ringing[0]
    return CycleReadings(out, (cyc_rec, cyc_model), None if ringing is None else ringing[1:])
