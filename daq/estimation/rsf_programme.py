"""The load point's programme read back from a recording: its plateaus, and the events a rate-and-state lab
reduces (velocity steps, slide-hold-slide holds).

Why from the record and not from the ramp file: a lab's file (a .mat from a press) holds the programme as a
column, and a recorder's file holds the commanded speed (vb_set) beside the measured one; either is a
piecewise-constant signal with short transitions. A plateau is a run of samples within a relative tolerance of
its first value; a transition is what lies between two plateaus, taken as linear (the drive's own ramp).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REL_TOL = 1e-3  # samples of one plateau differ by at most this fraction of its speed...
ABS_TOL = 1e-12  # ...or this many m/s (a hold)
MIN_PLATEAU_SAMPLES = 5
PRE_FRACTION = 0.5  # an event's window starts this far into the plateau before it (its latter part: steady)


@dataclass(frozen=True)
class Plateau:
    i0: int  # first sample
    i1: int  # last sample (inclusive)
    speed: float  # m/s


@dataclass(frozen=True)
class Event:
    """A velocity step (v1 -> v2) or a hold (v1 -> 0 for hold_s -> v2) with the window its fit reads."""

    kind: str  # "step" or "hold"
    i_start: int  # window: samples [i_start, i_end]
    i_event: int  # first sample after the plateau before the change
    i_end: int
    i_restart: int  # first sample after the plateau at rest (a hold); i_event for a step
    v1: float
    v2: float
    hold_s: float = 0.0


def plateaus(vb: np.ndarray) -> list[Plateau]:
    """Runs of (nearly) constant drive speed, at least MIN_PLATEAU_SAMPLES long, in sample order."""
    vb = np.asarray(vb, dtype=float)
    out: list[Plateau] = []
    i = 0
    n = vb.size
    while i < n:
        ref = vb[i]
        tol = max(REL_TOL * abs(ref), ABS_TOL)
        j = i
        while j + 1 < n and abs(vb[j + 1] - ref) <= tol:
            j += 1
        if j - i + 1 >= MIN_PLATEAU_SAMPLES:
            out.append(Plateau(i, j, float(np.median(vb[i:j + 1]))))
        i = j + 1
    return out


def programme_table(t: np.ndarray, plats: list[Plateau]) -> tuple[np.ndarray, np.ndarray]:
    """The piecewise-linear programme (rt, rv): each plateau flat, linear between plateaus."""
    rt: list[float] = []
    rv: list[float] = []
    for p in plats:
        for tt in (t[p.i0], t[p.i1]):
            if rt and tt <= rt[-1]:
                tt = rt[-1] + 1e-12
            rt.append(float(tt))
            rv.append(p.speed)
    return np.asarray(rt), np.asarray(rv)


def load_point_travel(t: np.ndarray, rt: np.ndarray, rv: np.ndarray) -> np.ndarray:
    """Load-point displacement at the samples [m]: the programme integrated from t[0]."""
    grid = np.union1d(rt, [t[0], t[-1]])
    grid = grid[(grid >= t[0]) & (grid <= t[-1])]
    v = np.interp(grid, rt, rv)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(grid))])
    # between grid points v is linear: integrate exactly with the trapezoid from the last grid point
    k = np.clip(np.searchsorted(grid, t, side="right") - 1, 0, grid.size - 1)
    vt = np.interp(t, rt, rv)
    return cum[k] + 0.5 * (v[k] + vt) * (t - grid[k])


def events(t: np.ndarray, plats: list[Plateau]) -> list[Event]:
    """Velocity steps between two moving plateaus; holds (a plateau at rest between two moving ones)."""
    out: list[Event] = []
    for k in range(len(plats) - 1):
        p, q = plats[k], plats[k + 1]
        if p.speed <= 0.0:
            continue
        start = p.i0 + int(PRE_FRACTION * (p.i1 - p.i0))
        if q.speed > 0.0 and abs(q.speed - p.speed) > max(REL_TOL * p.speed, ABS_TOL):
            out.append(Event("step", start, p.i1 + 1, q.i1, p.i1 + 1, p.speed, q.speed))
        elif q.speed <= 0.0 and k + 2 < len(plats) and plats[k + 2].speed > 0.0:
            r = plats[k + 2]
            stopped = 0.5 * (t[p.i1] + t[q.i0])  # halfway through the stop's transition
            restarted = 0.5 * (t[q.i1] + t[r.i0])
            out.append(Event("hold", start, p.i1 + 1, r.i1, q.i1 + 1, p.speed, r.speed,
                             hold_s=float(restarted - stopped)))
    return out
