"""The static limit f_s(t_s, Delta): the stick-time and force-rate effects fitted to the windows' break-away levels.

Why its own fit: the output-error stage (output_error.py) gives every slip window its
own break-away level as a nuisance; with their stick times and the load rate at the
simulated break-away (belt_law.py) they are the data of this small least squares,
the paper's Fig. 11. The law itself is the simulator's (daq.physics.effects.static_factor,
physics in one place), so the result compares with ``daq sim --effect stick-time:...``.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from daq.physics.effects import static_factor

from .equation_error import LsqFit, std_from_jac

STATIC = ("f_s0", "stick_time_gain", "stick_time_tau_s", "force_rate_gain")


def static_law(t_s: np.ndarray, delta: np.ndarray, f_s0: float, g_t: float, tau: float, g_d: float,
               q0: float) -> np.ndarray:
    """f_s(t_s, Delta) of the stick-time and force-rate effects: daq.physics.effects.static_factor, vectorised."""

    return f_s0 * np.array([static_factor(float(a), float(b), g_t, tau, g_d, q0) for a, b in
                            zip(np.atleast_1d(t_s), np.atleast_1d(delta))])


def fit_static(t_s: np.ndarray, delta: np.ndarray, f_s: np.ndarray, q0: float) -> LsqFit:
    """Least squares of the break-away levels against stick time [s] and force rate [N/s].

    f_s = f_s0 (1 + g_t (1 - exp(-t_s/tau)) + g_d ln(1 + |Delta|/q0)), q0 fixed (with
    Delta >> q0 the log is ln Delta - ln q0 and q0 trades off against f_s0 and g_d; the
    model files fix it for the same reason). tau is started from a grid over the
    observed stick times; with g_t -> 0 it is undetermined and its std says so.
    """

    t_s, delta, f_s = (np.asarray(a, dtype=float) for a in (t_s, delta, f_s))
    if f_s.size < 5:
        raise ValueError(f"{f_s.size} break-away episodes: too few for the static law (need 5)")

    def resid(th):
        return static_law(t_s, delta, th[0], th[1], th[2], th[3], q0) - f_s

    lo = np.array([0.01, 0.0, 1e-3, 0.0])
    hi = np.array([20.0, 5.0, 100.0, 5.0])
    best = None
    for tau in np.geomspace(max(1e-3 * 2, 0.3 * np.min(t_s)), max(3.0 * np.max(t_s), 0.01), 5):
        th0 = np.array([float(np.min(f_s)) * 0.8, 0.2, tau, 0.05])
        r = least_squares(resid, np.clip(th0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi), x_scale="jac")
        if best is None or r.cost < best.cost:
            best = r
    res = resid(best.x)
    return LsqFit(STATIC, best.x, std_from_jac(best.jac, res, 4), float(np.sqrt(np.mean(res**2))), int(res.size),
                  {"q0_N_per_s": q0})
