"""``daq analyse rsf``: every velocity step and slide-hold-slide hold of one or many recordings, reduced as a
rate-and-state lab reduces them (issue 27).

Which recordings: a one-mass belt-ndof rig (a spring-slider, ``driven = "spring"``, or a slider on a belt held by
a spring to a wall: in both, friction balances the spring, mu = k x1 / N, and the load point moves at vb). A
press's .mat file gets here through ``daq import --map`` (x1 from the friction column, vb from the programme
column). The programme is read from ``vb_set`` when the file has it (the commanded speed), else from ``vb``.

What comes out, per event: the peak and steady-state changes of friction (from the better law's fitted curve,
free of noise), a, b, a - b, Dc and the machine stiffness with standard errors by each state law, and which law
the event favours (or "undecided"); per recording, the healing rate beta over its holds. Rows for a table
(CSV/JSON) and the curves for the figures. The numerical core is daq/estimation/rsf_fit.py (one event's fit) and
rsf_programme.py (the events read from the programme) over the integrator of daq/physics/rsf.py; this module only
reads, loops and collects.
"""

from __future__ import annotations

import math
import multiprocessing
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import Field

from daq.config import RigConfig, config_for_recording
from daq.errors import InputError
from daq.estimation.rsf_fit import Healing, LawFit, fit_law, friction_curve, healing_rate, law_verdict, start_values
from daq.estimation.rsf_programme import Event, events, load_point_travel, plateaus, programme_table
from daq.io.loading import load_data
from daq.strict import Closed

RIG = "belt-ndof"
LAW_NAMES = ("aging", "slip")
RETRY_STIFFNESS = (10.0, 0.1)  # a failed fit is tried again from these multiples of the starting stiffness


class RsfEvent(Closed):
    """One velocity step or one hold, reduced."""

    data: str
    index: int
    kind: str = Field(description="'step' (v1 -> v2) or 'hold' (v1 -> rest for hold_s -> v2)")
    t_event_s: float
    load_point_m: float = Field(description="load-point travel at the change")
    v1_m_per_s: float
    v2_m_per_s: float
    hold_s: float
    peak_change: float = Field(description="friction's peak (trough for a step down) after the change, less the "
                                           "level before it, from the favoured law's fitted curve")
    steady_change: float = Field(description="steady level at v2 less the level at v1: (a - b) ln(v2/v1)")
    fits: dict[str, LawFit]
    law: str = Field(description="the state law the event favours, or 'undecided between ...'")
    law_margin: float = Field(description="Delta RSS / sigma^2 between the two laws (2 ln likelihood ratio)")


class RsfFile(Closed):
    data: str
    rate_Hz: float
    samples: int
    k_rig_per_m: float = Field(description="the rig file's spring over its normal load, k / N")
    events: list[RsfEvent]
    healing: Healing | None = Field(description="beta over the recording's holds (None: fewer than two)")


class RsfResult(Closed):
    """What ``daq analyse rsf`` prints with --json (and writes to REPORT/rsf.json)."""

    analysis: str = "rsf"
    laws: list[str]
    stiffness: str = Field(description="'fitted' or 'fixed' at the rig file's k / N")
    files: list[RsfFile]
    seconds: float
    seconds_per_event: float
    figures: list[str] = Field(default_factory=list)


@dataclass
class Curves:
    """What the figures draw for one recording: the data against load-point travel and each event's fit."""

    data: str
    travel: np.ndarray
    mu: np.ndarray
    fitted: list[tuple[slice, np.ndarray]] = field(default_factory=list)


def friction_series(path: str | Path, rig: str | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, RigConfig]:
    """(t, mu, programme speed) of a one-mass belt-ndof recording."""
    rec = load_data(path, rig)
    cfg = config_for_recording(rec.meta.get("rig_config"), str(path), rig if rig and Path(rig).suffix else None,
                               RIG, "rate-and-state reduction needs")
    mech = cfg.mechanics
    if mech.n_masses != 1:
        raise InputError(str(path), "mechanics.n_masses", f"{mech.n_masses}: the reduction reads one slider on one "
                                                           "spring (n_masses = 1)")
    if "x1" not in rec.channels:
        raise InputError(str(path), "x1", "no spring extension (x1) in the file")
    speed = None
    for name in ("vb_set", "vb"):
        col = rec.channels.get(name)
        if col is not None and np.all(np.isfinite(col)):
            speed = np.asarray(col, dtype=float)
            break
    if speed is None:
        raise InputError(str(path), "vb", "no load-point programme (vb_set or vb) in the file")
    mu = mech.stiffness_N_per_m * np.asarray(rec.channels["x1"], dtype=float) / mech.normal_force_N
    return np.asarray(rec.t, dtype=float), mu, speed, cfg


def reduce_event(ev: Event, t: np.ndarray, mu: np.ndarray, travel: np.ndarray, rt: np.ndarray, rv: np.ndarray,
                 laws: tuple[str, ...], k_fixed: float | None) -> tuple[dict[str, LawFit], str, float]:
    """Both laws (or the ones asked for) fitted to one event; the stiffness started from the loading slope
    after the change unless it is fixed."""
    sl = slice(ev.i_start, ev.i_end + 1)
    x0 = start_values(ev, t[sl], mu[sl], travel[sl], k_fixed)
    fits = {}
    for law in laws:
        fit = fit_law(ev, t[sl], mu[sl], rt, rv, law, x0, k_fixed)
        for k_factor in RETRY_STIFFNESS if k_fixed is None else ():  # a loading slope misread by noise
            if fit.ok:
                break
            fit = fit_law(ev, t[sl], mu[sl], rt, rv, law, x0 + np.array([0, 0, 0, 0, np.log(k_factor), 0, 0]),
                          None)
        fits[law] = fit
    verdict, margin = law_verdict(fits)
    return fits, verdict, margin


def fitted_curve(fit: LawFit, t: np.ndarray, rt: np.ndarray, rv: np.ndarray, v1: float) -> np.ndarray:
    """The fitted law's friction at the samples t (the window's)."""
    x = np.array([fit.mu0.value, fit.a.value, fit.b.value, math.log(fit.Dc_m.value), math.log(fit.k_per_m.value),
                  fit.mu_start, fit.psi_start])
    return friction_curve(x, t[0], t, rt, rv, v1, fit.law)


def analyse_file(path: str | Path, *, rig: str | None, laws: tuple[str, ...], fixed_stiffness: bool,
                 on_event: Callable[[int, int], None] | None = None) -> tuple[RsfFile, Curves]:
    t, mu, speed, cfg = friction_series(path, rig)
    plats = plateaus(speed)
    rt, rv = programme_table(t, plats)
    if rt.size < 2:
        raise InputError(str(path), "vb", "the programme has no plateau of constant speed")
    evs = events(t, plats)
    travel = load_point_travel(t, rt, rv)
    k_rig = cfg.mechanics.stiffness_N_per_m / cfg.mechanics.normal_force_N
    curves = Curves(str(path), travel, mu)
    rows: list[RsfEvent] = []
    holds: list[tuple[float, float]] = []
    for i, ev in enumerate(evs):
        fits, verdict, margin = reduce_event(ev, t, mu, travel, rt, rv, laws, k_rig if fixed_stiffness else None)
        best = fits[verdict] if verdict in fits else min(fits.values(), key=lambda f: f.rss)
        sl = slice(ev.i_start, ev.i_end + 1)
        curve = fitted_curve(best, t[sl], rt, rv, ev.v1)
        curves.fitted.append((sl, curve))
        after = curve[ev.i_restart - ev.i_start:]
        down = ev.kind == "step" and ev.v2 < ev.v1
        peak = float((after.min() if down else after.max()) - best.mu0.value)
        steady = float(best.a_minus_b.value * math.log(ev.v2 / ev.v1)) + 0.0  # a hold's ln(1): 0, not -0
        rows.append(RsfEvent(data=str(path), index=i, kind=ev.kind, t_event_s=float(t[ev.i_event]),
                             load_point_m=float(travel[ev.i_event]), v1_m_per_s=ev.v1, v2_m_per_s=ev.v2,
                             hold_s=ev.hold_s, peak_change=peak, steady_change=steady, fits=fits, law=verdict,
                             law_margin=margin))
        if ev.kind == "hold" and abs(ev.v2 - ev.v1) <= 1e-3 * ev.v1:
            holds.append((ev.hold_s, peak))
        if on_event:
            on_event(i + 1, len(evs))
    heal = healing_rate([h for h, _ in holds], [p for _, p in holds])
    return (RsfFile(data=str(path), rate_Hz=float(1.0 / np.median(np.diff(t))), samples=int(t.size),
                    k_rig_per_m=k_rig, events=rows, healing=heal), curves)


def _analyse_one(job: tuple) -> tuple[RsfFile, Curves | None]:
    """One file in a worker process (a plain module function: what a process pool can send)."""
    path, rig, laws, fixed_stiffness, keep_curves = job
    f, c = analyse_file(path, rig=rig, laws=laws, fixed_stiffness=fixed_stiffness)
    return f, (c if keep_curves else None)


def analyse_rsf(paths: list[str | Path], *, rig: str | None = None, laws: tuple[str, ...] = LAW_NAMES,
                fixed_stiffness: bool = False, workers: int = 1, keep_curves: int = 1_000_000,
                on_file: Callable[[int, int, str], None] | None = None) -> tuple[RsfResult, list[Curves]]:
    """Every event of every recording; ``on_file(k, n, name)`` reports progress. With ``workers`` > 1 the files
    are shared among that many processes (results in the files' order); the curves the figures draw are kept
    for the first ``keep_curves`` files only (a batch of thousands would ship every sample back)."""
    for law in laws:
        if law not in LAW_NAMES:
            raise InputError("--law", "law", f"'{law}': one of {', '.join(LAW_NAMES)}")
    t0 = time.perf_counter()
    jobs = [(p, rig, laws, fixed_stiffness, k < keep_curves) for k, p in enumerate(paths)]
    results: list[tuple[RsfFile, Curves | None]] = []
    if workers > 1 and len(paths) > 1:
        with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork")) as pool:
            for k, (f, c) in enumerate(pool.map(_analyse_one, jobs)):
                results.append((f, c))
                if on_file:
                    on_file(k + 1, len(paths), f"{Path(f.data).name}: {len(f.events)} events")
    else:
        for k, job in enumerate(jobs):
            f, c = _analyse_one(job)
            results.append((f, c))
            if on_file:
                on_file(k + 1, len(paths), f"{Path(f.data).name}: {len(f.events)} events")
    files = [f for f, _ in results]
    curves = [c for _, c in results if c is not None]
    dt = time.perf_counter() - t0
    n_ev = sum(len(f.events) for f in files)
    return (RsfResult(laws=list(laws), stiffness="fixed" if fixed_stiffness else "fitted", files=files,
                      seconds=dt, seconds_per_event=dt / max(n_ev, 1)), curves)


TABLE_COLUMNS = ("data", "index", "kind", "t_event_s", "load_point_m", "v1_m_per_s", "v2_m_per_s", "hold_s",
                 "peak_change", "steady_change", "law", "law_margin")
LAW_COLUMNS = ("a", "b", "a_minus_b", "Dc_m", "k_per_m")


def table_rows(res: RsfResult) -> list[dict[str, object]]:
    """One row per event: the event's columns, then value and standard error of each parameter by each law."""
    rows = []
    for f in res.files:
        for ev in f.events:
            row: dict[str, object] = {c: getattr(ev, c) for c in TABLE_COLUMNS}
            for law, fit in ev.fits.items():
                for c in LAW_COLUMNS:
                    est = getattr(fit, c)
                    row[f"{law}_{c}"] = est.value
                    row[f"{law}_{c}_se"] = est.se
                row[f"{law}_sigma"] = fit.sigma
                row[f"{law}_ok"] = fit.ok
            rows.append(row)
    return rows
