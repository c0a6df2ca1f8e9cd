"""Paper 000's friction law identified from belt-ndof trajectories: the whole analysis and its result.

Why an analysis of its own: the paper identifies its friction model from measured
trajectories of 1-3 masses on a belt (its Figs. 9-11): the kinetic characteristic
f(w) on an accelerating and a decelerating branch by least squares, and the static
limit f_s against stick time t_s and force rate delta. Each step is a pure function
over numpy arrays; the CLI (daq/cli/paper000.py) does the I/O, figures.py draws.

Method (``belt_law``). Two stages:

1. *Equation error* (the paper's least squares, equation_error.py): f(w) points from
   twice-differentiated positions away from the transitions, fitted with the whole
   law. Biased by the transitions (amp 5 % off); it gives the start values of stage 2.
2. *Output error over slip windows* (what the parameters come from; windows.py,
   output_error.py). Steps: f_s by a scan of the levels the data pass through,
   alpha_drop from a grid, then the kinetic part, then everything; a second pass
   places every window at the fitted law, and while a window that fits worse than
   twice the median (a segmentation error) was in the fit, or the fit is not at the
   noise, refits on windows spread over the record among those that fit. The
   break-away levels of all good windows, with their stick times and the load rate
   at the simulated break-away, are the data of the static fit (static_law.py).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel

from daq.errors import InputError
from daq.physics import beltndof

from .equation_error import KINETIC, LAW, FrictionPoints, fit_kinetic_points, friction_points, merge_points
from .output_error import LAW_HI, LAW_LO, N_SUB, fit_output_error, scan_break_levels, window_rms
from .preparation import BeltRun, find_sticks
from .static_law import fit_static
from .windows import SlipWindow, WindowSimulator, slip_windows

MAX_PASSES = 3  # refits on the best-fitting windows (see belt_law)
RMS_AT_NOISE = 1.15  # a law fit with a larger rms [noise units] is not at the noise
ALPHA_GRID = (1.0, 2.0, 4.0, 8.0, 16.0)  # start values of alpha_drop tried before the law fit


class Estimate(BaseModel):
    value: float
    std: float | None  # None: not determined by the data (e.g. alpha_drop when no kept point lies on the drop)


class RecordingSummary(BaseModel):
    path: str
    n_masses: int
    belt_speed_m_per_s: float  # median drive speed
    belt_speed_s: float  # dimensionless s of eq. (2)
    drive: str
    sticks: int
    windows: int
    left_out: dict[str, int]
    w_max: float  # largest |w| seen while slipping (kept points)


class Episode(BaseModel):
    recording: int
    mass: int  # 1-based
    t_break_s: float
    t_s_s: float | None  # stick time [s] (None if the stick began before the record)
    delta_N_per_s: float  # load rate at the break-away [N/s]
    delta_mean_N_per_s: float  # mean load rate over the stick [N/s]
    f_s: float
    f_s_std: float


class BeltLawResult(BaseModel):
    """JSON of ``daq analyse belt-law``."""

    analysis: str = "belt-law"
    paper: str = "000"
    method: str
    recordings: list[RecordingSummary]
    mechanics: dict[str, float | int | str]
    law: dict[str, Estimate]  # output error: alpha_drop, f_k0, k_fall, w_min, k_rise, amp
    law_rms_noise_units: float
    equation_error: dict[str, Estimate]  # the paper's least squares on f(w) points (biased, see docs)
    equation_error_rms: float
    static: dict[str, Estimate] | None
    static_rms: float | None
    force_rate_q0_N_per_s: float
    episodes: list[Episode]
    points: dict[str, list[float]]  # the kept f(w) points: w, f, growing, s, mass, recording
    windows_in_law_fit: int
    warnings: list[str]
    seconds: float


@dataclass
class BeltLawAnalysis:
    result: BeltLawResult
    points: FrictionPoints
    runs: list[BeltRun]


def _spread_pick(items: list, k: int) -> list:
    if len(items) <= k:
        return list(items)
    return [items[int(i)] for i in np.unique(np.linspace(0, len(items) - 1, k).round())]


def belt_law(runs: list[BeltRun], masses: list[int] | None = None, windows_per_mass: int = 6,
             progress=None, max_nfev: int = 40) -> BeltLawAnalysis:
    """Identify paper 000's friction law from recordings (ideally at several constant belt speeds).

    See the module docstring for the two stages. ``masses`` (0-based) restricts which
    contacts are identified (all by default; every mass rides the same belt with the
    same law). ``windows_per_mass`` slip windows per recording and mass, spread over the
    record, enter the law fit (a limit cycle repeats itself; more windows cost time,
    not information); every window then gets its break-away level with the law fixed.
    """

    t_start = time.perf_counter()
    say = progress or (lambda msg: None)
    warnings: list[str] = []
    pts, all_windows, summaries = _points_and_windows(runs, masses, say)
    try:
        ee = fit_kinetic_points(pts)
    except ValueError as exc:
        raise InputError(runs[0].source, "x1", f"equation-error fit impossible: {exc}") from None
    say("equation error (paper's least squares): " + ", ".join(f"{k}={v:.4g}" for k, v in zip(ee.names, ee.values)))
    law0 = np.clip(ee.values, LAW_LO + 1e-6, LAW_HI - 1e-6)
    sub = _spread_per_mass(runs, all_windows, windows_per_mass)
    say(f"output error over {len(sub)} slip windows: break-away levels, then the kinetic branches, then the "
        "whole law")
    law, sub = _law_from_start(runs, sub, law0, max_nfev, say)
    law, sub, fs_all, fs_std, per_all, limit = _refit_on_windows_that_fit(runs, all_windows, law, sub,
                                                                          windows_per_mass, max_nfev, say)
    n_bad = int(np.sum(~(per_all <= limit)))
    if n_bad:
        warnings.append(f"{n_bad} of {len(all_windows)} slip windows fit worse than twice the median (or could "
                        "not be placed): left out of the law and the static data")
    if law.rms > RMS_AT_NOISE:
        warnings.append(f"the law fit is at {law.rms:.3g} noise units, not at the noise: model error or a local "
                        "minimum (compare with --windows N)")
    say("law: " + ", ".join(f"{k}={v:.4g}" for k, v in zip(law.names, law.values))
        + f"; rms {law.rms:.3g} noise units")
    episodes = _episodes(runs, all_windows, law.values, fs_all, fs_std, per_all <= limit)
    q0 = runs[0].mech.q0_N_per_s
    static = _static_law(runs, episodes, q0, warnings)
    w_max = max(s.w_max for s in summaries)
    if w_max < law.values[LAW.index("w_min")]:
        warnings.append(f"largest |w| seen ({w_max:.3g}) is below w_min: k_rise and w_min are extrapolated")
    mech = runs[0].mech
    k = pts.kept
    res = BeltLawResult(
        method="output error over slip windows (daq.physics.beltndof.simulate) from the equation-error start; "
               "static limit: least squares of the windows' break-away levels against stick time and force rate",
        recordings=summaries,
        mechanics={"mass_kg": mech.mass_kg, "stiffness_N_per_m": mech.stiffness_N_per_m,
                   "normal_force_N": mech.normal_force_N, "d": mech.d, "tau0_s": mech.tau0,
                   "x_unit_m": mech.x_unit, "v_unit_m_per_s": mech.v_unit, "config": mech.config_source},
        law={k_: Estimate(value=float(v), std=float(s)) for k_, v, s in zip(law.names, law.values, law.std)},
        law_rms_noise_units=law.rms,
        equation_error={k_: Estimate(value=float(v), std=float(s) if s > 0 else None)
                        for k_, v, s in zip(ee.names, ee.values, ee.std)},
        equation_error_rms=ee.rms,
        static=({k_: Estimate(value=float(v), std=float(s)) for k_, v, s in zip(static.names, static.values, static.std)}
                if static else None),
        static_rms=static.rms if static else None,
        force_rate_q0_N_per_s=q0,
        episodes=episodes,
        points={"w": pts.w[k].tolist(), "f": pts.f[k].tolist(), "growing": pts.growing[k].tolist(),
                "s": pts.s[k].tolist(), "mass": (pts.mass[k] + 1).tolist(), "recording": pts.run[k].tolist()},
        windows_in_law_fit=len(sub),
        warnings=warnings,
        seconds=time.perf_counter() - t_start)
    return BeltLawAnalysis(res, pts, runs)


def _points_and_windows(runs: list[BeltRun], masses: list[int] | None, say
                        ) -> tuple[FrictionPoints, list[SlipWindow], list[RecordingSummary]]:
    """The f(w) points (merged over the recordings), the slip windows and a summary of every recording."""
    all_pts, all_windows, summaries = [], [], []
    for k, run in enumerate(runs):
        ms = [m for m in (masses if masses is not None else range(run.n)) if m < run.n]
        if not ms:
            raise InputError(run.source, "--mass", f"the recording has {run.n} mass(es)")
        sticks = [find_sticks(run, i) for i in range(run.n)]
        pts = friction_points(run, sticks, k, masses=ms)
        wins, left = slip_windows(run, sticks, k, masses=ms)
        all_pts.append(pts)
        all_windows += wins
        kept = pts.kept
        summaries.append(RecordingSummary(
            path=run.source, n_masses=run.n, belt_speed_m_per_s=float(np.median(run.vb)),
            belt_speed_s=float(np.median(run.vb) / run.mech.v_unit), drive=run.vb_source,
            sticks=sum(len(sticks[m]) for m in ms), windows=len(wins), left_out=left,
            w_max=float(np.max(np.abs(pts.w[kept]))) if kept.any() else 0.0))
        say(f"{run.source}: {run.n} mass(es), s = {summaries[-1].belt_speed_s:.3f}, "
            f"{summaries[-1].sticks} sticks, {len(wins)} slip windows")
    pts = merge_points(all_pts)
    if not all_windows:
        raise InputError(runs[0].source if len(runs) == 1 else ", ".join(r.source for r in runs), "x1",
                         "no stick-slip episode found (the law is identified from stick-slip cycles)")
    return pts, all_windows, summaries


def _spread_per_mass(runs: list[BeltRun], windows: list[SlipWindow], per_mass: int) -> list[SlipWindow]:
    """Up to ``per_mass`` of ``windows`` for every recording and mass, spread over the record."""
    sub = []
    for k in range(len(runs)):
        for m in range(runs[k].n):
            sub += _spread_pick([w for w in windows if w.run == k and w.mass == m], per_mass)
    return sub


def _best_alpha_drop(runs: list[BeltRun], sub: list[SlipWindow], law0: np.ndarray) -> float:
    """The value of ALPHA_GRID whose law (else ``law0``) fits ``sub`` best, break-away levels scanned.

    The equation error rarely sees the drop (it is inside the excluded samples), and a gradient
    started at a too steep drop finds a flat cost (the drop is over within one step).
    """
    best = None
    for ad in ALPHA_GRID:
        trial = law0.copy()
        trial[0] = ad
        scan_break_levels(runs, sub, trial)
        cost = float(np.sum(window_rms(runs, sub, trial, np.array([w.fs_guess for w in sub])) ** 2))
        if best is None or cost < best[0]:
            best = (cost, ad)
    return best[1]


def _law_from_start(runs: list[BeltRun], sub: list[SlipWindow], law0: np.ndarray, max_nfev: int, say):
    """First output-error fit of the law on ``sub`` from the equation-error start ``law0`` (alpha_drop
    set in place from the grid): break-away levels, the kinetic part, then everything. Returns the
    fit and the windows it used (those far off already at the start law left out)."""
    law0[0] = _best_alpha_drop(runs, sub, law0)
    scan_break_levels(runs, sub, law0)
    sub = [w for w in sub if w.valid]
    _, fs, _ = fit_output_error(runs, sub, law0, free=(), max_nfev=max_nfev)
    # the kinetic part first (alpha_drop held): the equation-error start is biased, and a drop fitted
    # against a biased kinetic line steepens to compensate, into a flat valley that is slow to leave
    f2, fs, _ = fit_output_error(runs, sub, law0, free=KINETIC, fs0=fs, max_nfev=max_nfev)
    scan_break_levels(runs, sub, f2.values)
    fs = np.array([w.fs_guess for w in sub])
    # windows the segmentation got structurally wrong (a graze taken for a stick, a neighbour's unseen
    # break, a window starting after the break) are off by tens of noise units even with the start law
    per = window_rms(runs, sub, f2.values, fs)
    wrong = (per > max(10.0, 5.0 * float(np.median(per)))) | ~np.array([w.valid for w in sub])
    if wrong.any():
        say(f"{int(wrong.sum())} window(s) far off already at the start law: left out")
        sub = [w for w, b in zip(sub, wrong) if not b]
    law, _, _ = fit_output_error(runs, sub, f2.values, progress=say, max_nfev=3 * max_nfev)
    return law, sub


def _levels_of_all_windows(runs: list[BeltRun], all_windows: list[SlipWindow], law_values: np.ndarray,
                           max_nfev: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Break-away level, its std and the rms [noise units] of every window with the law held
    (nan, nan, inf for a window that could not be placed)."""
    scan_break_levels(runs, all_windows, law_values)
    ok = np.array([w.valid for w in all_windows])
    out = np.full(len(all_windows), np.nan), np.full(len(all_windows), np.nan), np.full(len(all_windows), np.inf)
    idx = np.flatnonzero(ok)
    if idx.size:
        wins = [all_windows[j] for j in idx]
        _, f_, s_ = fit_output_error(runs, wins, law_values, free=(), max_nfev=max_nfev)
        out[0][idx], out[1][idx], out[2][idx] = f_, s_, window_rms(runs, wins, law_values, f_)
    return out


def _fit_limit(per_all: np.ndarray) -> float:
    """rms above which a window does not fit: twice the median of those placed, at least 2."""
    fin = np.isfinite(per_all)
    return max(2.0, 2.0 * float(np.median(per_all[fin]))) if fin.any() else 2.0


def _refit_on_windows_that_fit(runs: list[BeltRun], all_windows: list[SlipWindow], law, sub: list[SlipWindow],
                               windows_per_mass: int, max_nfev: int, say):
    """Further passes (at most MAX_PASSES): with a law near the truth the windows the segmentation got
    wrong stand out (tens of noise units against ~1); while a window worse than twice the median was
    in the fit, or the fit is not at the noise (a local minimum), refit on windows of each recording
    and mass spread over the record among those within twice the median.

    Returns the law, the windows of its fit, every window's level, level std and rms at that law, and
    the rms limit of a window that fits.
    """
    j_of = {id(w): j for j, w in enumerate(all_windows)}
    for _ in range(MAX_PASSES):
        fs_all, fs_std, per_all = _levels_of_all_windows(runs, all_windows, law.values, max_nfev)
        limit = _fit_limit(per_all)
        # spread over the record among the good ones (picking the best-fitting would favour the
        # windows that agree with the current law, and lock it in)
        sub2 = _spread_per_mass(runs, [w for j, w in enumerate(all_windows) if per_all[j] <= limit],
                                windows_per_mass)
        bad_in_fit = any(not per_all[j_of[id(w)]] <= limit for w in sub)
        if not sub2 or (not bad_in_fit and law.rms <= RMS_AT_NOISE) or {id(w) for w in sub2} == {id(w) for w in sub}:
            return law, sub, fs_all, fs_std, per_all, limit
        say(f"refit on {len(sub2)} windows that fit ({int(np.sum(~(per_all <= limit)))} of "
            f"{len(all_windows)} fit worse than twice the median; the fit had rms {law.rms:.3g})")
        law, _, _ = fit_output_error(runs, sub2, law.values, fs0=np.array([fs_all[j_of[id(w)]] for w in sub2]),
                                     progress=say, max_nfev=3 * max_nfev)
        sub = sub2
    fs_all, fs_std, per_all = _levels_of_all_windows(runs, all_windows, law.values, max_nfev)
    return law, sub, fs_all, fs_std, per_all, _fit_limit(per_all)


def _episodes(runs: list[BeltRun], all_windows: list[SlipWindow], law_values: np.ndarray, fs_all: np.ndarray,
              fs_std: np.ndarray, good: np.ndarray) -> list[Episode]:
    """Stick episodes of the good windows: break-away time (simulated at the fitted law), stick time,
    load rates and break-away level."""
    episodes = []
    sims = [WindowSimulator(r, n_sub=N_SUB) for r in runs]
    for w, f_s, sd, ok in zip(all_windows, fs_all, fs_std, good):
        if not ok:
            continue
        run = runs[w.run]
        fine = 4
        states, modes = sims[w.run].simulate(w, law_values, f_s, fine=fine)
        slip = np.flatnonzero(modes[:, w.mass] == beltndof.SLIP)
        if not slip.size:
            continue
        t_break = float(run.t[w.j0] + (slip[0] - 0.5) / (run.rate * fine))
        t_stick0 = run.t[w.stick.start] - 0.5 / run.rate
        t_s = None if w.stick.open_start else t_break - t_stick0
        episodes.append(Episode(recording=w.run, mass=w.mass + 1, t_break_s=t_break, t_s_s=t_s,
                                delta_N_per_s=_load_rate(run, w, states[max(slip[0] - 1, 0)], t_break),
                                delta_mean_N_per_s=w.delta_mean, f_s=float(f_s), f_s_std=float(sd)))
    return episodes


def _static_law(runs: list[BeltRun], episodes: list[Episode], q0: float, warnings: list[str]):
    """Fit of the static limit to the complete stick episodes (None: fewer than 5); appends to ``warnings``."""
    use = [e for e in episodes if e.t_s_s is not None and e.t_s_s > 0 and np.isfinite(e.delta_N_per_s)]
    if len(use) < 5:
        warnings.append(f"{len(use)} complete stick episodes: too few for the static law")
        return None
    static = fit_static(np.array([e.t_s_s for e in use]), np.array([e.delta_N_per_s for e in use]),
                        np.array([e.f_s for e in use]), q0)
    # conditions: (t_s, Delta) pairs distinct by more than 10 % in either; a limit cycle repeats one
    cond = {(round(math.log(e.t_s_s) / 0.1), round(math.log1p(abs(e.delta_N_per_s)) / 0.1)) for e in use}
    if len(cond) < 4:
        warnings.append(f"only {len(cond)} distinct (stick time, force rate) conditions: the static law's "
                        "4 parameters are not all determined (vary belt speed and spring stiffness)")
    if any(r.n > 1 for r in runs):
        warnings.append("static law from a chain of masses: measured unreliable on simulated chains (a stick "
                        "time the position data see can contain micro-slips that restart the stick clock; "
                        "docs/analyses-000.md); identify it from one-mass records")
    return static


def _load_rate(run: BeltRun, w: SlipWindow, state: np.ndarray, t: float) -> float:
    """Rate [N/s] of the force a stuck mass needs, at the simulated break-away: what the static law reads.

    As daq.physics.beltndof._stick_need: D vb' + (K v)_i with the mass at belt speed and
    its neighbours at their simulated velocities (belt jerk neglected).
    """
    n = run.n
    vb = float(np.interp(t, w.rt, w.rv))
    k = int(np.clip(np.searchsorted(w.rt, t) - 1, 0, w.rt.size - 2))
    dvb = float((w.rv[k + 1] - w.rv[k]) / (w.rt[k + 1] - w.rt[k]))
    vel = np.ascontiguousarray(state[n:2 * n], dtype=float).copy()
    vel[w.mass] = vb
    mech = run.mech
    damp = mech.d * math.sqrt(mech.stiffness_N_per_m * mech.mass_kg)
    return float(damp * dvb + beltndof.chain_at(vel, w.mass, n, mech.stiffness_N_per_m))
