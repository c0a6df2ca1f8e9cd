"""Poincaré section of a belt-ndof trajectory: period-k or irregular, and the limit cycle (paper 000, Figs. 8, 19).

Why from the data alone: the paper judges the periodicity of the vibrations from the
measured trajectories, with no model; so does this, from the smoothed positions and
velocities of prepare()'s recording (preparation.py). The section is our choice (the
paper does not say which it used): see ``poincare``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel

from daq.signals import savgol

from .preparation import BeltRun, sg_gain


class PoincareResult(BaseModel):
    """JSON of ``daq analyse poincare``."""

    analysis: str = "poincare"
    paper: str = "000"
    path: str
    n_masses: int
    mass: int  # 1-based: whose velocity defines the section
    section: str
    level: float  # dimensionless velocity level c of the section
    belt_speed_s: float
    skip_s: float
    points_total: int
    points_steady: int
    classification: str  # "period-k", "irregular", "too few crossings", "no oscillation (steady sliding or rest)"
    period: int | None  # k of period-k
    period_s: float | None  # duration of one period of the section sequence [s]
    distance_by_k: dict[str, float]  # k -> 90th percentile of |P_{n+k} - P_n| (normalised)
    tolerance: float
    distinct_points: int  # clusters of steady section points at the tolerance
    section_points: dict[str, list[float]]  # t [s] and every coordinate (dimensionless) of every crossing
    stick_fraction: float  # share of the steady part the section mass spends stuck


@dataclass
class PoincareAnalysis:
    result: PoincareResult
    t: np.ndarray
    x: np.ndarray  # dimensionless positions (n, N), smoothed
    v: np.ndarray  # dimensionless velocities (n, N)
    cross_t: np.ndarray
    points: np.ndarray  # (m, 2n) section states: x_1..x_n, v_1..v_n
    steady: np.ndarray  # bool per crossing


SKIP_FRACTION = 0.4  # default transient: this share of the record


def poincare(run: BeltRun, mass: int = 0, skip_s: float | None = None, kmax: int = 8,
             half: int = 3) -> PoincareAnalysis:
    """Poincaré section and periodicity of a belt-ndof trajectory (paper 000: periodicity of the vibrations).

    Section (our choice, the paper does not say which it used): the instants the
    velocity of mass ``mass`` crosses the level c = mid-range of its velocity
    *downward* (a Schmitt trigger with hysteresis against noise), each crossing
    giving the point P = (x_1..x_n, x'_1..x'_n) of all masses, dimensionless. In a
    stick-slip cycle this is once per slip, where the mass moves fastest backward
    relative to the belt... at mid-speed, far from the stick (where the state is
    pinned to the belt) and from the turning points (where timing noise is largest).

    Periodicity: d_k = 90th percentile over n of max |P_{n+k} - P_n| with each
    coordinate scaled by its range over the steady part; the motion is period-k for
    the smallest k <= kmax with d_k below the tolerance (8 x the scaled noise of a
    section point, at least 0.01), else irregular (quasi-periodic or chaotic: the
    steady points do not repeat). The first ``skip_s`` seconds (default: 40 % of the
    record; a chain of masses can take seconds to settle on its cycle) are the
    transient and are not classified.
    """
    mech = run.mech
    dtd = 1.0 / run.rate / mech.tau0
    xd = run.x / mech.x_unit
    xs = savgol(xd, half, 0)
    vs = savgol(xd, half, 1, dtd)
    t = run.t
    skip = SKIP_FRACTION * (t[-1] - t[0]) if skip_s is None else float(skip_s)
    steady_s = t >= t[0] + skip
    v = vs[mass]
    lo, hi = np.quantile(v[steady_s], [0.01, 0.99])
    c = 0.5 * (lo + hi)
    sig_v = run.sigma_x[mass] / mech.x_unit * sg_gain(half, 1) / dtd
    cross = _downward_crossings(v, c, max(4.0 * sig_v, 0.05 * (hi - lo)))
    n = run.n
    pts, ct = _section_points(xs, vs, t, cross)
    steady = ct >= t[0] + skip
    P = pts[steady]
    scale, tol = _scale_and_tolerance(run, xs[:, steady_s], vs[:, steady_s], half, dtd)
    dist, period = _return_distances(P, scale, tol, kmax)
    if hi - lo < 8.0 * sig_v:
        cls = "no oscillation (steady sliding or rest)"
        period = None
    elif P.shape[0] < 6:
        cls = "too few crossings"
        period = None
    elif period is None:
        cls = "irregular"
    else:
        cls = f"period-{period}"
    period_s = float(np.median(ct[steady][period:] - ct[steady][:-period])) if period and P.shape[0] > period else None
    stuck = np.abs(vs[mass] - run.vb / mech.v_unit) < 4.0 * sig_v + 0.01 * np.abs(run.vb / mech.v_unit)
    names = [f"x{i + 1}" for i in range(n)] + [f"v{i + 1}" for i in range(n)]
    res = PoincareResult(
        path=run.source, n_masses=n, mass=mass + 1,
        section=f"downward crossings of x'{mass + 1} = c (c = mid-range of x'{mass + 1} over the steady part); "
                "coordinates x_i = K X_i / F0, v_i = dx_i/dt in t = tau / sqrt(M/K)",
        level=float(c), belt_speed_s=float(np.median(run.vb) / mech.v_unit), skip_s=skip,
        points_total=int(cross.size), points_steady=int(P.shape[0]), classification=cls, period=period,
        period_s=period_s, distance_by_k=dist, tolerance=tol, distinct_points=_distinct_points(P / scale, tol),
        section_points={"t": ct.tolist(), **{nm: pts[:, i].tolist() for i, nm in enumerate(names)}},
        stick_fraction=float(np.mean(stuck[steady_s])))
    return PoincareAnalysis(res, t, xs, vs, ct, pts, steady)


def _downward_crossings(v: np.ndarray, c: float, h: float) -> np.ndarray:
    """Fractional sample indices where ``v`` crosses ``c`` downward, by a Schmitt trigger of hysteresis ``h``.

    Armed above c + h; a downward crossing of c counts once v then reaches c - h before it
    returns above c + h (noise around c gives one crossing, not several).
    """
    cross = []
    armed = False
    cand = None
    for j in range(1, v.size):
        if v[j] > c + h:
            armed, cand = True, None
        elif armed and cand is None and v[j - 1] > c >= v[j]:
            cand = j - 1 + (v[j - 1] - c) / (v[j - 1] - v[j])
        if cand is not None and v[j] < c - h:
            cross.append(cand)
            armed, cand = False, None
    return np.asarray(cross, dtype=float)


def _section_points(xs: np.ndarray, vs: np.ndarray, t: np.ndarray, cross: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Section points (m, 2n) = positions and velocities of all masses at the crossings (linear
    interpolation between samples), and the crossing times."""
    if not cross.size:
        return np.zeros((0, 2 * xs.shape[0])), np.zeros(0)
    i0 = np.floor(cross).astype(int)
    fr = cross - i0
    i1 = np.minimum(i0 + 1, t.size - 1)
    pts = np.vstack([xs[:, i0] * (1 - fr) + xs[:, i1] * fr, vs[:, i0] * (1 - fr) + vs[:, i1] * fr]).T
    return pts, t[i0] * (1 - fr) + t[i1] * fr


def _scale_and_tolerance(run: BeltRun, xs_steady: np.ndarray, vs_steady: np.ndarray, half: int,
                         dtd: float) -> tuple[np.ndarray, float]:
    """Range of each section coordinate over the steady part, and the tolerance of a repeat in those
    units: 8 x the largest scaled noise of a section point, at least 0.01."""
    mech = run.mech
    scale = np.concatenate([np.ptp(xs_steady, axis=1), np.ptp(vs_steady, axis=1)])
    scale = np.where(scale > 0, scale, 1.0)
    sig_x = run.sigma_x / mech.x_unit * sg_gain(half, 0)
    sig_vv = run.sigma_x / mech.x_unit * sg_gain(half, 1) / dtd
    noise = np.concatenate([sig_x, sig_vv]) / scale
    return scale, max(0.01, 8.0 * float(np.max(noise)))


def _return_distances(P: np.ndarray, scale: np.ndarray, tol: float, kmax: int) -> tuple[dict[str, float], int | None]:
    """d_k (90th percentile of the scaled max |P_{n+k} - P_n|) for k = 1..kmax, and the smallest k with
    d_k below the tolerance (None: no such k)."""
    dist: dict[str, float] = {}
    period = None
    for k in range(1, kmax + 1):
        if P.shape[0] < k + 3:
            break
        d = np.max(np.abs(P[k:] - P[:-k]) / scale, axis=1)
        dist[str(k)] = float(np.quantile(d, 0.9))
        if period is None and dist[str(k)] < tol:
            period = k
    return dist, period


def _distinct_points(scaled: np.ndarray, tol: float) -> int:
    """Number of clusters of (scaled) section points at the tolerance, by greedy clustering."""
    centres: list[np.ndarray] = []
    for p in scaled:
        if not any(np.max(np.abs(p - q)) < tol for q in centres):
            centres.append(p)
    return len(centres)
