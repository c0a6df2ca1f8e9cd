"""Fixed-step RK4 for the smooth-law rigs.

Why fixed-step RK4: the regularised friction laws make the creep phase only
mildly stiff (eigenvalue ~ -3e3 /s on brake-2dof), well inside RK4's stability
region at dt = 0.5 ms, and a fixed step makes the cost predictable (the speed
bar is 45 ms for 45 s). Accuracy is not assumed: tests halve the step and check
convergence.

Why a factory: the loop must call the rig's right-hand side directly (a runtime
dispatch between rigs, or a function argument, costs 3x in numba's reference
counting). A closure would do that but numba cannot cache closures; so each rig
gets a copy of one template function with its rhs bound as a global and its own
name, which numba caches on disk like any module-level function.

Decision record: docs/decisions/0011-fixed-step-rk4-smooth-laws.md.
"""

from __future__ import annotations

import types

import numpy as np
from numba import njit

from daq.physics.contact import N_AUX


def _rk4_template(s0, t0, dt, n_sub, n_out, p, e, rt, rv):
    """Integrate from s0 at t0; return states and aux at t0 + i*n_sub*dt for i < n_out.

    ``rhs`` is a global of this function's copy, bound per rig by make_rk4.
    """
    ns = s0.size
    states = np.empty((n_out, ns))
    auxs = np.empty((n_out, N_AUX))
    s = s0.copy()
    k1 = np.empty(ns)
    k2 = np.empty(ns)
    k3 = np.empty(ns)
    k4 = np.empty(ns)
    tmp = np.empty(ns)
    aux = np.empty(N_AUX)
    h2 = 0.5 * dt
    for i in range(n_out):
        if i > 0:
            t = t0 + (i - 1) * n_sub * dt
            for _ in range(n_sub):
                rhs(t, s, p, e, rt, rv, k1, aux)  # noqa: F821 - bound per rig
                for j in range(ns):
                    tmp[j] = s[j] + h2 * k1[j]
                rhs(t + h2, tmp, p, e, rt, rv, k2, aux)  # noqa: F821
                for j in range(ns):
                    tmp[j] = s[j] + h2 * k2[j]
                rhs(t + h2, tmp, p, e, rt, rv, k3, aux)  # noqa: F821
                for j in range(ns):
                    tmp[j] = s[j] + dt * k3[j]
                rhs(t + dt, tmp, p, e, rt, rv, k4, aux)  # noqa: F821
                for j in range(ns):
                    s[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
                t += dt
        rhs(t0 + i * n_sub * dt, s, p, e, rt, rv, k1, aux)  # noqa: F821
        for j in range(ns):
            states[i, j] = s[j]
        for j in range(N_AUX):
            auxs[i, j] = aux[j]
    return states, auxs


def make_rk4(rhs, tag: str, cache: bool = True):
    """A compiled RK4 integrator calling ``rhs(t, s, p, e, rt, rv, ds, aux)`` directly.

    The template's code is rebound with ``rhs`` as a global and a per-rig qualified
    name, so numba's on-disk cache keeps one entry per rig (a closure would recompile
    in every process).
    """
    g = dict(_rk4_template.__globals__)
    g["rhs"] = rhs
    fn = types.FunctionType(_rk4_template.__code__, g, f"rk4_{tag}")
    fn.__qualname__ = f"rk4_{tag}"
    fn.__module__ = __name__
    fn.__doc__ = _rk4_template.__doc__
    return njit(cache=cache, error_model="numpy")(fn)
