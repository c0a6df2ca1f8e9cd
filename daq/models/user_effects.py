"""User effects: a friction term in the user's own Python file, used by path from a model file.

Why this shape: the rig equations are compiled (numba), so a user effect must be
compiled too and called from inside the right-hand side. Every rig's rhs calls
``effects.user_mu_factor(...)`` (1 for the built-in physics); a model with a user
effect gets a copy of the rhs in which that name is bound to the user's function,
compiled once per process. Nothing in the package is edited.

A user effect file defines (see docs/user-effects.md for a worked example)::

    from daq.models.user_effects import UserParam

    PARAMS = {"k": UserParam(start=0.0, lo=-0.5, hi=0.5, unit="1/m",
                             doc="relative change of mu per metre of belt travel")}

    def mu_factor(v_rel, t, temp, travel, stick_clock, p0, p1, p2, p3):
        # multiplies the friction coefficient; p0.. are PARAMS in order
        return 1.0 - p0 * travel

Arguments: relative sliding velocity [m/s], time [s], contact temperature [degC],
belt/drum travel [m], stick clock [s], and up to four parameters. Only scalar
arithmetic and ``math`` functions (numba nopython mode).
"""

from __future__ import annotations

import importlib.util
import inspect
import types
from dataclasses import dataclass
from pathlib import Path

from numba import njit

from daq.errors import InputError
from daq.physics import brake2dof, drum
from daq.physics.effects import E
from daq.sim.integrate import make_rk4

MAX_PARAMS = 4
SIGNATURE = ("v_rel", "t", "temp", "travel", "stick_clock", "p0", "p1", "p2", "p3")
_compiled: dict[tuple[str, str], object] = {}  # (file, rig) -> rk4 with the user's term bound


@dataclass(frozen=True)
class UserParam:
    start: float = 0.0
    lo: float | None = None
    hi: float | None = None
    unit: str = "-"
    doc: str = ""


class UserEffect:
    """A loaded user effect: its parameters and its compiled factor, ready to bind into a rig."""

    def __init__(self, path: Path, name: str, params: dict[str, UserParam], fn) -> None:
        self.path = path
        self.name = name
        self.params = params
        self.fn = fn

    def bind(self, sim, values: dict[str, float]) -> None:
        """Put the parameter values into the user slots and the compiled integrator into ``sim``."""
        for i, key in enumerate(self.params):
            sim.e[E.USER0 + i] = values.get(f"effects.{self.name}.{key}", self.params[key].start)
        sim.rk4 = self._integrator(sim)

    def _integrator(self, sim):
        key = (str(self.path), sim.rig_id)
        if key not in _compiled:

            module = {"brake-2dof": brake2dof, "drum-pendulum": drum}.get(sim.rig_id)
            if module is None:
                raise InputError(str(self.path), "(rig)", f"user effects are supported on brake-2dof and "
                                 f"drum-pendulum, not {sim.rig_id}")
            base = module.rhs.py_func
            g = dict(base.__globals__)
            g["user_mu_factor"] = njit(inline="always", error_model="numpy")(self.fn)
            fn = types.FunctionType(base.__code__, g, f"rhs_user_{len(_compiled)}")
            rhs = njit(error_model="numpy")(fn)
            _compiled[key] = make_rk4(rhs, f"user_{len(_compiled)}", cache=False)
        return _compiled[key]


def load_user_effect(path: str | Path, name: str | None = None) -> UserEffect:
    """Import a user effect file; one InputError naming the file and what is wrong."""
    p = Path(path)
    src = str(p)
    if not p.is_file():
        raise InputError(src, "path", "user effect file not found")
    spec = importlib.util.spec_from_file_location(f"daq_user_effect_{abs(hash(src))}", p)
    if spec is None or spec.loader is None:
        raise InputError(src, "path", "not a Python file")
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    except Exception as exc:  # noqa: BLE001 - the user's code: report, do not crash
        raise InputError(src, "(import)", f"{type(exc).__name__}: {exc}") from None
    params = getattr(mod, "PARAMS", None)
    if not isinstance(params, dict) or not all(isinstance(v, UserParam) for v in params.values()):
        raise InputError(src, "PARAMS", "must be a dict of name -> UserParam(...)")
    if len(params) > MAX_PARAMS:
        raise InputError(src, "PARAMS", f"at most {MAX_PARAMS} parameters")
    fn = getattr(mod, "mu_factor", None)
    if not callable(fn):
        raise InputError(src, "mu_factor", "missing: def mu_factor(v_rel, t, temp, travel, stick_clock, p0, p1, p2, p3)")
    args = tuple(inspect.signature(fn).parameters)
    if len(args) != len(SIGNATURE):
        raise InputError(src, "mu_factor", f"takes {len(args)} arguments, needs {len(SIGNATURE)}: "
                         + ", ".join(SIGNATURE))
    try:  # compile now, so a bad function is reported here and not deep inside a fit
        njit(error_model="numpy")(fn)(0.01, 0.0, 22.0, 0.0, 0.0, *[v.start for v in params.values()],
                                      *([0.0] * (MAX_PARAMS - len(params))))
    except Exception as exc:  # noqa: BLE001
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(src, "mu_factor", f"does not compile with numba: {first}") from None
    return UserEffect(p.resolve(), name or getattr(mod, "NAME", p.stem), dict(params), fn)
