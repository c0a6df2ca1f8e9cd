"""Rate-and-state protocols on a spring-slider (tests only): velocity steps and slide-hold-slide, written with
plain scipy and nothing from daq.

Why a second implementation: ``daq analyse rsf`` fits its own integrator (daq/physics/rsf.py: the
regularised asinh law, the state as psi = ln(v0 theta/Dc), Dormand-Prince with Hermite outputs). These records
come from the textbook form instead: mu = mu0 + a ln(v/v0) + b ln(v0 theta/Dc) (no regularisation), the state
as ln theta, LSODA at tight tolerances, outputs by the solver's own dense output, and, by default, the slider's
inertia (m v' = k (x_lp - x) - N mu): the analysis neglects it, as a rock lab's tools do, and must still recover
the parameters. A shared mistake in the law, the state's evolution or the frame would need to be made twice.

    x_lp' = V(t) (piecewise linear programme),   x' = v,   m v' = k (x_lp - x) - N mu(v, theta)
    aging: theta' = 1 - v theta / Dc        slip: theta' = -(v theta / Dc) ln(v theta / Dc)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp


@dataclass
class RsfSlider:
    a: float = 0.010
    b: float = 0.014
    dc: float = 20e-6  # [m]
    mu0: float = 0.60  # at v0
    v0: float = 10e-6  # [m/s]
    k: float = 3000.0  # machine stiffness [N/m]
    n: float = 1.0  # normal load [N]
    m: float = 0.0  # slider mass [kg]; 0: quasi-static (no inertia)
    law: str = "aging"


def programme(segments: list[tuple[float, float]], rise_s: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(speed, duration) pieces as a piecewise-linear table; each change takes rise_s."""
    ts, vs = [0.0], [segments[0][0]]
    t = 0.0
    for i, (v, dur) in enumerate(segments):
        if i > 0:
            t += rise_s
            ts.append(t)
            vs.append(v)
        t += dur - (rise_s if i > 0 else 0.0)
        ts.append(t)
        vs.append(v)
    return np.array(ts), np.array(vs)


def velocity_steps(speeds: list[float], slip_m: float, rise_s: float = 0.01):
    """A plateau of slip_m of load-point travel at each speed in turn."""
    return programme([(v, slip_m / v) for v in speeds], rise_s)


def slide_hold_slide(v: float, slide_m: float, holds_s: list[float], rise_s: float = 0.01):
    """Slide slide_m at v, hold, slide again, for each hold time."""
    seg = [(v, slide_m / v)]
    for h in holds_s:
        seg += [(0.0, h), (v, slide_m / v)]
    return programme(seg, rise_s)


def _friction(s: RsfSlider, v: float, ln_theta: float) -> float:
    return s.mu0 + s.a * math.log(v / s.v0) + s.b * (math.log(s.v0 / s.dc) + ln_theta)


def _speed(s: RsfSlider, mu: float, ln_theta: float) -> float:
    return s.v0 * math.exp((mu - s.mu0 - s.b * (math.log(s.v0 / s.dc) + ln_theta)) / s.a)


def _dln_theta(s: RsfSlider, v: float, ln_theta: float) -> float:
    theta = math.exp(ln_theta)
    if s.law == "aging":
        return (1.0 - v * theta / s.dc) / theta
    x = v * theta / s.dc
    return -(x * math.log(x)) / theta


def record(s: RsfSlider, rt: np.ndarray, rv: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(t, mu) sampled at rate_hz from steady sliding at the programme's first speed."""
    t_out = np.arange(0.0, rt[-1], 1.0 / rate_hz)
    pieces_t, pieces_mu = [], []
    for lo, hi, dense in _solved(s, rt, rv):
        sel = (t_out >= lo) & (t_out < hi)
        if sel.any():
            z = dense(t_out[sel])
            pieces_t.append(t_out[sel])
            pieces_mu.append(z[0] if s.m == 0.0 else s.k * z[0] / s.n)
    return np.concatenate(pieces_t), np.concatenate(pieces_mu)


_SOLVED: dict[tuple, list] = {}


def _solved(s: RsfSlider, rt: np.ndarray, rv: np.ndarray) -> list[tuple[float, float, object]]:
    """The programme's solution as (start, end, dense output) per piece, solved once per slider and programme in a
    process: the solve does not depend on the rate it is sampled at (the coverage test samples each at two rates)."""
    key = (tuple(vars(s).items()), np.asarray(rt, dtype=float).tobytes(), np.asarray(rv, dtype=float).tobytes())
    if key not in _SOLVED:
        if len(_SOLVED) >= 8:
            _SOLVED.pop(next(iter(_SOLVED)))
        _SOLVED[key] = _solve(s, rt, rv)
    return _SOLVED[key]


def _solve(s: RsfSlider, rt: np.ndarray, rv: np.ndarray) -> list[tuple[float, float, object]]:
    v_start = rv[0]
    ln_theta0 = math.log(s.dc / v_start)
    mu_start = _friction(s, v_start, ln_theta0)
    pieces = []
    if s.m > 0.0:
        # state: (spring extension e = x_lp - x, ln v, ln theta); the slider never stops (v > 0 under RSF)
        def rhs(t, y):
            e, lnv, lth = y
            v = math.exp(lnv)
            vlp = np.interp(t, rt, rv)
            mu = _friction(s, v, lth)
            return [vlp - v, (s.k * e - s.n * mu) / (s.m * v), _dln_theta(s, v, lth)]

        y = [mu_start * s.n / s.k, math.log(v_start), ln_theta0]
    else:
        def rhs(t, y):
            mu, lth = y
            v = _speed(s, mu, lth)
            return [s.k / s.n * (np.interp(t, rt, rv) - v), _dln_theta(s, v, lth)]

        y = [mu_start, ln_theta0]
    for lo, hi in zip(rt[:-1], rt[1:]):  # one solve per piece: the corners of the programme are not smoothed
        if hi <= lo:
            continue
        sol = solve_ivp(rhs, (lo, hi), y, method=("Radau" if s.m > 0.0 else "LSODA"), rtol=1e-10, atol=1e-13, dense_output=True)
        if not sol.success:
            raise RuntimeError(sol.message)
        pieces.append((lo, hi, sol.sol))
        y = sol.y[:, -1]
    return pieces
