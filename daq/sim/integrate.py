"""Fixed-step RK4 for the smooth-law rigs.

Why fixed-step RK4: the regularised friction laws make the creep phase only
mildly stiff (eigenvalue ~ -3e3 /s on brake-2dof), well inside RK4's stability
region at dt = 0.5 ms, and a fixed step makes the cost predictable (the speed
bar is 45 ms for 45 s). Accuracy is not assumed: tests halve the step and check
convergence.

Why a factory: the loop must have the rig's right-hand side compiled into it (a
runtime dispatch between rigs, or a function argument, costs 3x in numba's
reference counting; a call, 1.6x: make_rk4). A closure would do that but numba
cannot cache closures; so each rig gets a copy of one template function with its
rhs bound as a global and its own name, which numba caches on disk like any
module-level function.

Decision record: docs/decisions/0011-fixed-step-rk4-smooth-laws.md.
"""

from __future__ import annotations

import types

import numpy as np
from numba import njit

from daq.physics.contact import N_AUX
from daq.physics.jit import helper


def _rk4_template(s0, t0, dt, n_sub, n_out, p, e, rt, rv):
    """Integrate from s0 at t0; return states and aux at t0 + i*n_sub*dt for i < n_out.

    ``rhs`` (compiled into this function, see make_rk4) and ``rhs_out`` (the same equations, called) are globals of
    this function's copy, bound per rig by make_rk4. The four stages of a step are one loop around one ``rhs`` site.
    """
    ns = s0.size
    states = np.empty((n_out, ns))
    auxs = np.empty((n_out, N_AUX))
    s = s0.copy()
    k = np.empty((4, ns))
    tmp = np.empty(ns)
    aux = np.empty(N_AUX)
    h2 = 0.5 * dt
    for i in range(n_out):
        if i > 0:
            t = t0 + (i - 1) * n_sub * dt
            for _ in range(n_sub):
                for stage in range(4):
                    if stage == 0:
                        ts = t
                        for j in range(ns):
                            tmp[j] = s[j]
                    elif stage < 3:
                        ts = t + h2
                        for j in range(ns):
                            tmp[j] = s[j] + h2 * k[stage - 1, j]
                    else:
                        ts = t + dt
                        for j in range(ns):
                            tmp[j] = s[j] + dt * k[2, j]
                    rhs(ts, tmp, p, e, rt, rv, k[stage], aux)  # noqa: F821 - bound per rig
                for j in range(ns):
                    s[j] += dt / 6.0 * (k[0, j] + 2.0 * k[1, j] + 2.0 * k[2, j] + k[3, j])
                t += dt
        rhs_out(t0 + i * n_sub * dt, s, p, e, rt, rv, k[0], aux)  # noqa: F821
        for j in range(ns):
            states[i, j] = s[j]
        for j in range(N_AUX):
            auxs[i, j] = aux[j]
    return states, auxs


def make_rk4(rhs, tag: str, cache: bool = True):
    """A compiled RK4 integrator with ``rhs(t, s, p, e, rt, rv, ds, aux)`` compiled into its step.

    The template's code is rebound with the rig's equations as globals and a per-rig qualified name, so numba's
    on-disk cache keeps one entry per rig (a closure would recompile in every process). ``rhs`` is bound as a copy
    inlined at numba's IR level (``inline="always"``), at the one site of the stage loop; ``rhs_out``, once per
    output sample, is the rig's compiled function as it is.

    Why inlined: called, each of the four evaluations of a step passed its seven arrays as structs on the stack and
    re-read every parameter: the brake's seed run (`daq bench sim`'s kernel) took 36 ms, 80 % of a diagnosis's CPU.
    Inlined at the stage loop's one site it takes 22-23 ms, the same numbers to the bit (every catalog effect on
    brake-2dof and drum-pendulum, 6 s at 1 kHz); inlined at four sites, 20.7 ms, but the two rigs then took 26.5 s
    to compile instead of 8 s (4.5 s called), and a model with a user effect compiles in every process that fits it.
    Measured 2026-11-28 on the 2-core machine of the suite.
    """
    g = dict(_rk4_template.__globals__)
    g["rhs"] = helper(getattr(rhs, "py_func", rhs))  # the project's inlined helper (daq.physics.jit)
    g["rhs_out"] = rhs
    fn = types.FunctionType(_rk4_template.__code__, g, f"rk4_{tag}")
    fn.__qualname__ = f"rk4_{tag}"
    fn.__module__ = __name__
    fn.__doc__ = _rk4_template.__doc__
    return njit(cache=cache, error_model="numpy")(fn)
