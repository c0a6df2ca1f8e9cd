"""The effects catalog: every physical effect as a parameterised term with a neutral value.

Why one vector for all effects: the simulator and the models call the same
compiled equations; an effect that is "off" is simply at its neutral value, so
adding or removing an effect never changes code, only numbers. The slots of
that vector are named by :class:`E`; each rig's equations read the slots that
apply to it. Stateful effects (stick time, force rate, temperature, belt lag)
carry their state in the common *contact tail* of every rig's state vector,
see :data:`TAIL`.

Decision record: docs/decisions/0001-physics-in-one-place.md.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np
from pydantic import BaseModel, ConfigDict

from .jit import helper, kernel


class E(IntEnum):
    """Slots of the effect/environment vector ``e`` shared by all rigs."""

    NL_WEIGHT = 0  # normal-load: 0 = nominal constant load, 1 = instantaneous load
    GEO_WEIGHT = 1  # geometric: 0 = linear springs, no angular-body gravity, 1 = paper 001
    C1 = 2  # viscous-damping (brake): c1 [N s/m]
    C2 = 3  # viscous-damping (brake): c2 [N s/m]
    D_BELT = 4  # viscous-damping (belt-ndof): dimensionless d
    C_PHI = 5  # viscous-damping (drum): [N m s/rad]
    AS_AMP = 6  # accel-sign: relative difference of the two kinetic branches [-]
    ST_GAIN = 7  # stick-time: relative static-peak increase at long stick [-]
    ST_TAU = 8  # stick-time: adhesion time constant [s]
    FR_GAIN = 9  # force-rate: static-peak gain per e-fold of load rate [-]
    FR_Q0 = 10  # force-rate: reference load rate [N/s]
    BF_TORQUE = 11  # bearing-friction (brake pivot): dry torque [N m]
    BF_MU1 = 12  # bearing-friction (drum): reduced bearing coefficient mu1 [-]
    BF_EPS = 13  # bearing-friction: smoothing rate of sgn(phi_dot) [rad/s]
    TEMP_COEF = 14  # temperature: d(mu)/mu per kelvin [1/K]
    TEMP_REF = 15  # temperature: reference temperature [degC]
    VB_TAU = 16  # belt-speed: first-order lag of the drive [s]
    VB_RIPPLE = 17  # belt-speed: relative ripple amplitude [-]
    VB_WAVELEN = 18  # belt-speed: ripple wavelength in belt travel [m] (drum: [rad])
    VS_D = 19  # velocity-strengthening: d(mu)/dv [s/m] (belt-ndof: dimensionless)
    # environment and contact properties (not effects, but read by the same terms)
    V_STICK = 20  # relative speed below which the contact counts as stuck/creeping [m/s]
    T_AMB = 21  # ambient temperature [degC]
    TH_R = 22  # thermal resistance contact->ambient [K/W]
    TH_TAU = 23  # thermal time constant [s]
    TH_DRIFT = 24  # ambient drift [K/s]
    FR_TAU = 25  # force-rate: time constant of the load-rate tracker while stuck [s]
    ST_RESET = 26  # stick-time: decay time of the stick clock while slipping [s]
    USER0 = 27  # parameters of a user effect (daq/models/user_effects.py), neutral 0
    USER1 = 28
    USER2 = 29
    USER3 = 30
    # the catalog's other forms of its phenomena (see EffectSpec.forms)
    ST_LOG_GAIN = 31  # stick-time, Dieterich's logarithmic aging: b in 1 + b ln(1 + t_s/tau) [-]
    AS_BODY_AMP = 32  # accel-sign keyed to the body's acceleration: mu x (1 + amp) while it accelerates [-]
    TEMP_ARR = 33  # temperature, Arrhenius-like: mu x exp(theta (1/T - 1/T_ref)), T in kelvin; theta [K]
    AS_BODY_A0 = 34  # accel-sign (body form): acceleration scale of its smooth switch tanh(a/a0) [m/s^2]
    ST_DC = 35  # stick-time (log form): Dieterich's critical slip distance Dc of the aging law [m]; 0 = stick clock
    # rate-and-state (daq/physics/rsf.py): mu += a asinh(v/(2 v_ref)) + b psi, psi = ln(v_ref theta / Dc)
    RS_B = 36  # rate-and-state, aging law: the state's effect b [-]
    RS_B_SLIP = 37  # rate-and-state, slip law: the state's effect b [-] (the law the state evolves by)
    RS_A = 38  # rate-and-state: the direct effect a [-]
    RS_DC = 39  # rate-and-state: critical slip distance Dc [m]; 0: the model has no contact state (RK4, not ROS2)
    RS_VREF = 40  # rate-and-state: reference speed v_ref of the law [m/s] (the direct effect's regularisation)


N_E = len(E)
DC_MIN = 2e-4  # [m] the smallest Dc the aging law uses: |v|/Dc stays within RK4's stable step at 0.5 ms


class TAIL(IntEnum):
    """Offsets of the contact tail appended to every rig's mechanical state."""

    TS = 0  # stick (adhesion) clock [s]
    Q = 1  # load rate remembered from the last stick [N/s]
    TEMP = 2  # contact temperature [degC]
    VLAG = 3  # drive speed after the drive's lag [m/s]
    POS = 4  # drive travel [m] (drum: drum angle [rad])
    PSI = 5  # rate-and-state: the contact's state psi = ln(v_ref theta / Dc) [-] (belt-ndof, one mass)


N_TAIL = len(TAIL)


# ---------------------------------------------------------------------------
# Catalog (Python side): names, parameters, neutral values, where each applies
# ---------------------------------------------------------------------------


class ParamSpec(BaseModel):
    """One parameter of an effect; ``neutral`` is the value at which the effect vanishes."""

    model_config = ConfigDict(frozen=True)
    key: str
    slot: E
    unit: str
    neutral: float
    lo: float
    hi: float
    doc: str


class FormSpec(BaseModel):
    """Another published form of an effect's phenomenon: its own parameters (and slots), its own neutral."""

    model_config = ConfigDict(frozen=True)
    meaning: str
    params: dict[str, tuple[ParamSpec, ...]]  # rig id (or "*") -> the keys that rig uses


class EffectSpec(BaseModel):
    """An effect is a phenomenon; where the literature writes it in more than one form, ``forms`` holds
    the others. ``params`` is the default form (``default_form``). Every form vanishes at its neutral
    values, so a model with the effect at neutral is exactly the model without it, whatever the form.
    """

    model_config = ConfigDict(frozen=True)
    name: str
    meaning: str
    seed: str
    rigs: tuple[str, ...]
    params: dict[str, tuple[ParamSpec, ...]]  # rig id -> the keys that rig uses (the default form)
    stateful: bool = False
    default_form: str = ""
    forms: dict[str, FormSpec] = {}
    forms_told_apart_by: str = ""  # the run that separates the forms, where the literature knows one

    def form_names(self) -> list[str]:
        """Every form, the default first ("" when the effect has only one form)."""
        return [self.default_form, *self.forms]

    def form_meaning(self, form: str | None) -> str:
        if not form or form == self.default_form:
            return self.meaning
        return self.forms[form].meaning

    def form_applies(self, rig: str, form: str | None) -> bool:
        """Whether a form exists on a rig (a form with parameters elsewhere but none here does not)."""
        if rig not in self.rigs:
            return False
        table = self.params if not form or form == self.default_form else self.forms[form].params
        return rig in table or "*" in table

    def params_for(self, rig: str, form: str | None = None) -> tuple[ParamSpec, ...]:
        table = self.params if not form or form == self.default_form else self.forms[form].params
        return table.get(rig, table.get("*", ()))


def _p(key: str, slot: E, unit: str, neutral: float, lo: float, hi: float, doc: str) -> ParamSpec:
    return ParamSpec(key=key, slot=slot, unit=unit, neutral=neutral, lo=lo, hi=hi, doc=doc)


ALL_RIGS = ("belt-ndof", "brake-2dof", "drum-pendulum")


def _rate_state_params(b_slot: E) -> tuple[ParamSpec, ...]:
    """rate-and-state's parameters; the two forms differ only in b's slot (the slot says which law the state follows)."""
    return (
        _p("a", E.RS_A, "-", 0.0, -0.05, 0.2, "the direct effect: mu += a asinh(v / (2 v_ref))"),
        _p("b", b_slot, "-", 0.0, -0.1, 0.3, "the state's effect: mu += b ln(v_ref theta / Dc)"),
        _p("dc", E.RS_DC, "m", 0.0, 0.0, 1e-2, "critical slip distance Dc (0: no contact state, the model without "
                                                 "the effect)"),
        _p("v_ref", E.RS_VREF, "m/s", 1e-7, 1e-12, 1e-2, "reference speed: below ~3 v_ref the direct effect flattens "
                                                         "(a shifts f_k0 by a ln v_ref)"),
    )

CATALOG: dict[str, EffectSpec] = {
    s.name: s
    for s in [
        EffectSpec(
            name="normal-load", seed="001, 002", rigs=("brake-2dof", "drum-pendulum"),
            meaning="friction follows the instantaneous normal load (eq. 6 / thrust gauge), not a constant one",
            params={"*": (_p("weight", E.NL_WEIGHT, "-", 0.0, 0.0, 1.5,
                             "blend from nominal (0) to instantaneous (1) normal load"),)},
        ),
        EffectSpec(
            name="geometric", seed="001", rigs=("brake-2dof",),
            meaning="geometric nonlinearity and gravity of the angular body",
            params={"*": (_p("weight", E.GEO_WEIGHT, "-", 0.0, 0.0, 1.5,
                             "scales the x1^2/2r spring terms and the angular body's gravity (1 = paper 001)"),)},
        ),
        EffectSpec(
            name="viscous-damping", seed="000, 001", rigs=ALL_RIGS,
            meaning="viscous terms c1, c2, d",
            params={
                "brake-2dof": (
                    _p("c1", E.C1, "N s/m", 0.0, 0.0, 1.0, "damper between block and angular body"),
                    _p("c2", E.C2, "N s/m", 0.0, 0.0, 1.0, "damper in the vertical spring"),
                ),
                "belt-ndof": (_p("d", E.D_BELT, "-", 0.0, 0.0, 2.0, "dimensionless damping d of eq. (3)"),),
                "drum-pendulum": (_p("c", E.C_PHI, "N m s/rad", 0.0, 0.0, 1.0, "pendulum air/structural damping"),),
            },
        ),
        EffectSpec(
            name="accel-sign", seed="000", rigs=ALL_RIGS,
            meaning="kinetic friction differs between accelerating and decelerating relative motion",
            params={"*": (_p("amp", E.AS_AMP, "-", 0.0, -0.5, 0.5,
                             "mu x (1+amp) while |v_rel| grows, mu x (1-amp) while it shrinks"),)},
            default_form="relative",
            forms={"body": FormSpec(
                meaning="kinetic friction differs while the body accelerates and while it decelerates "
                        "(paper 000's wording: keyed to the body's acceleration, not the sliding one)",
                params={rig: (_p("amp", E.AS_BODY_AMP, "-", 0.0, -0.5, 0.5,
                                 "mu x (1 + amp tanh(a/a0)): higher while the body accelerates along the drive"),
                              _p("a0", E.AS_BODY_A0, "m/s^2", 1.0, 0.05, 50.0,
                                 "acceleration scale of the switch (small: a sign; large: linear in a)"))
                        for rig in ("brake-2dof", "drum-pendulum")})},  # belt-ndof's law has its own branches
        ),
        EffectSpec(
            name="stick-time", seed="000", rigs=ALL_RIGS,
            meaning="static (peak) friction grows with adhesion time",
            stateful=True,
            params={"*": (
                _p("gain", E.ST_GAIN, "-", 0.0, 0.0, 2.0, "relative peak increase after long adhesion"),
                _p("tau", E.ST_TAU, "s", 1.0, 0.01, 100.0, "adhesion time constant"),
            )},
            default_form="saturating",
            forms_told_apart_by="sticks of many lengths, over at least two decades (slide-hold-slide: "
                                "docs/ramps/slide-hold-slide.toml): the saturating form levels off past tau, "
                                "the log form keeps growing",
            forms={"log": FormSpec(
                meaning="static (peak) friction grows with the logarithm of adhesion time (Dieterich)",
                params={"*": (
                    _p("gain", E.ST_LOG_GAIN, "-", 0.0, 0.0, 2.0, "b in 1 + b ln(1 + theta/tau)"),
                    _p("tau", E.ST_TAU, "s", 1.0, 0.001, 100.0, "cut-off time of the aging law"),
                    _p("dc", E.ST_DC, "m", 0.0, 0.0, 0.01,
                       "Dieterich's Dc: theta follows d theta/dt = 1 - |v_rel| theta/Dc (0: the stick clock)"),
                )})},
        ),
        EffectSpec(
            name="force-rate", seed="000", rigs=ALL_RIGS,
            meaning="static friction depends on the force rate during stick",
            stateful=True,
            params={"*": (
                _p("gain", E.FR_GAIN, "-", 0.0, 0.0, 2.0, "relative peak increase per e-fold of load rate"),
                _p("q0", E.FR_Q0, "N/s", 1.0, 1e-3, 1e4, "reference load rate"),
            )},
        ),
        EffectSpec(
            name="bearing-friction", seed="002", rigs=("brake-2dof", "drum-pendulum"),
            meaning="dry friction torque in the pivot bearing",
            params={
                "brake-2dof": (_p("torque", E.BF_TORQUE, "N m", 0.0, 0.0, 0.05, "dry pivot torque Q"),),
                "drum-pendulum": (_p("mu1", E.BF_MU1, "-", 0.0, 0.0, 0.5, "reduced bearing coefficient mu1"),),
            },
        ),
        EffectSpec(
            name="temperature", seed="002", rigs=ALL_RIGS,
            meaning="friction coefficient varies with contact temperature",
            params={"*": (
                _p("coef", E.TEMP_COEF, "1/K", 0.0, -0.1, 0.1, "relative change of mu per kelvin"),
                _p("ref", E.TEMP_REF, "degC", 20.0, -50.0, 300.0, "temperature at which mu is nominal"),
            )},
            default_form="linear",
            forms={"arrhenius": FormSpec(
                meaning="friction coefficient varies with contact temperature as exp(theta (1/T - 1/T_ref))",
                params={"*": (
                    _p("theta", E.TEMP_ARR, "K", 0.0, -20000.0, 20000.0,
                       "activation temperature E/R of mu x exp(theta (1/T - 1/T_ref)), T in kelvin"),
                    _p("ref", E.TEMP_REF, "degC", 20.0, -50.0, 300.0, "temperature at which mu is nominal"),
                )})},
        ),
        EffectSpec(
            name="belt-speed", seed="001", rigs=ALL_RIGS,
            meaning="the belt does not follow the command (ripple, lag); drive the model with measured speed",
            stateful=True,
            params={"*": ()},
            default_form="measured",
            forms={"lag-ripple": FormSpec(
                meaning="the belt follows the command through a first-order lag and a ripple periodic in travel",
                params={"*": (
                    _p("tau", E.VB_TAU, "s", 0.0, 0.0, 5.0, "first-order lag of the drive"),
                    _p("ripple", E.VB_RIPPLE, "-", 0.0, 0.0, 0.5, "relative speed ripple"),
                    _p("wavelength", E.VB_WAVELEN, "m", 1.0, 1e-3, 100.0,
                       "ripple period in belt travel (drum: in drum angle, rad)"),
                )})},
        ),
        EffectSpec(
            name="rate-and-state", seed="rate-and-state (Dieterich 1979, Ruina 1983)", rigs=("belt-ndof",),
            meaning="friction follows the slip speed's logarithm at once (a) and a contact state that ages at rest "
                    "and renews over a slip Dc (b): rate-and-state with Dieterich's aging law",
            stateful=True,
            params={"belt-ndof": _rate_state_params(E.RS_B)},
            default_form="aging",
            forms_told_apart_by="velocity steps up and down by 10x or more (docs/ramps/velocity-steps.toml: the slip "
                                "law's response is symmetric in up and down steps, the aging law's is not) and "
                                "holds over decades (docs/ramps/slide-hold-slide.toml: the aging law heals at rest, "
                                "the slip law does not)",
            forms={"slip": FormSpec(
                meaning="friction follows the slip speed's logarithm at once (a) and a contact state renewed only "
                        "by slip (b): rate-and-state with Ruina's slip law (no healing at rest)",
                params={"belt-ndof": _rate_state_params(E.RS_B_SLIP)})},
        ),
        EffectSpec(
            name="velocity-strengthening", seed="002", rigs=ALL_RIGS,
            meaning="friction rises linearly with slip speed (Dv term)",
            params={"*": (_p("D", E.VS_D, "s/m", 0.0, -5.0, 20.0,
                             "mu += D v_rel (belt-ndof: dimensionless f += D w)"),)},
        ),
    ]
}

# Environment slots every rig config must give (they are not effects: no neutral value).
ENVIRONMENT_SLOTS: dict[str, E] = {
    "v_stick": E.V_STICK,
    "t_ambient": E.T_AMB,
    "r_thermal": E.TH_R,
    "tau_thermal": E.TH_TAU,
    "ambient_drift": E.TH_DRIFT,
    "force_rate_tau": E.FR_TAU,
    "stick_reset_tau": E.ST_RESET,
}


# sgn(phi_dot) of the bearing torque, regularised as tanh(w / eps) [rad/s]. Why not a hard
# sign: under a fixed-step integrator a hard sign at the pendulum's turning points makes the
# trajectory depend erratically on the parameters, which no fit can descend; 2e-3 rad/s is the
# contact law's own regularisation (0.2 mm/s) at the drum radius.
BEARING_SGN_EPS = 2e-3


def neutral_vector() -> np.ndarray:
    """The effect vector with every effect off."""
    e = np.zeros(N_E)
    e[E.BF_EPS] = BEARING_SGN_EPS
    for spec in CATALOG.values():
        for table in [spec.params, *(f.params for f in spec.forms.values())]:
            for plist in table.values():
                for ps in plist:
                    e[ps.slot] = ps.neutral
    return e


# ---------------------------------------------------------------------------
# Terms (compiled): pure scalar functions
#
# Why scalars only: a compiled helper that takes an array and branches pays an
# atomic reference-count pair per call (~20 ns), which dominated the right-hand
# side. Each rig unpacks p, e and s once and passes numbers.
# ---------------------------------------------------------------------------


@helper
def smooth_sign(v: float, eps: float) -> float:
    """tanh(v/eps), the regularised sgn used where the papers write sgn()."""
    if eps <= 0.0:
        return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    return math.tanh(v / eps)


@helper
def user_mu_factor(v_rel: float, t: float, temp: float, travel: float, stick_clock: float,
                   u0: float, u1: float, u2: float, u3: float) -> float:
    """Hook for a user effect: multiplies the friction coefficient. Built-in: 1 (no user effect).

    A model with a user effect rebinds this name in a copy of the rig's rhs to the
    user's compiled function (daq/models/user_effects.py); the package is not edited.
    """
    return 1.0


@helper
def normal_load(n_inst: float, n_nominal: float, weight: float) -> float:
    """normal-load: blend between the nominal and the instantaneous normal load."""
    return n_nominal + weight * (n_inst - n_nominal)


@helper
def stuck_fraction(v_rel: float, v_stick: float) -> float:
    """Smooth indicator (1 = stuck/creeping, 0 = slipping) used by the stateful static effects."""
    x2 = (v_rel / v_stick) ** 2
    return math.exp(-x2) if x2 < 700.0 else 0.0  # avoid libm's slow underflow path


@helper
def static_factor(ts: float, q: float, st_gain: float, st_tau: float, fr_gain: float, fr_q0: float) -> float:
    """stick-time and force-rate: multiplier on the static (peak) part of a friction law.

    stick-time: 1 + gain (1 - exp(-t_s/tau)) (saturating growth, paper 000 Fig. 11);
    force-rate: + gain ln(1 + |q|/q0) (rate-strengthening of the static limit).
    """
    f = 1.0
    if st_gain != 0.0:
        f += st_gain * (1.0 - math.exp(-max(ts, 0.0) / st_tau))
    if fr_gain != 0.0:
        f += fr_gain * math.log1p(abs(q) / fr_q0)
    return f


@helper
def aging_log(ts: float, gain: float, tau: float) -> float:
    """stick-time, logarithmic form (Dieterich): the term gain ln(1 + t_s/tau) added to the static factor."""
    if gain == 0.0:
        return 0.0
    return gain * math.log1p(max(ts, 0.0) / tau)


@helper
def dieterich_rate(v_rel: float, theta: float, dc: float) -> float:
    """Dieterich's aging law for the contact state: d theta/dt = 1 - |v_rel| theta / Dc (a time in contact that
    grows while the contact barely moves and is wiped out over a slip of a few Dc)."""
    return 1.0 - abs(v_rel) * theta / dc


@helper
def temperature_factor(temp: float, coef: float, ref: float) -> float:
    """temperature: linear sensitivity of the friction coefficient around a reference."""
    return 1.0 + coef * (temp - ref)


@helper
def arrhenius_factor(temp: float, theta: float, ref: float) -> float:
    """temperature, Arrhenius-like form: exp(theta (1/T - 1/T_ref)) with T = temp + 273.15 K."""
    if theta == 0.0:
        return 1.0
    return math.exp(theta * (1.0 / (temp + 273.15) - 1.0 / (ref + 273.15)))


@kernel
def ramp_eval(rt: np.ndarray, rv: np.ndarray, t: float):
    """Piecewise-linear drive programme: value and slope at t (held constant outside the table)."""
    return ramp_eval_side(rt, rv, t, False)


@kernel
def ramp_eval_side(rt: np.ndarray, rv: np.ndarray, t: float, left: bool):
    """ramp_eval, with the slope from the left at a corner when ``left``: what an integrator step that ends on a
    corner must see (the right-hand slope there is the next step's)."""
    n = rt.size
    if t <= rt[0]:
        return rv[0], 0.0
    if t > rt[n - 1] or (t == rt[n - 1] and not left):
        return rv[n - 1], 0.0
    # lo: the last row before t (at t itself when not ``left``); rt[0] is before t and rt[n-1] is not. Why a guess
    # and a walk, not a bisection: a drive table is the record's own time base, evenly spaced, so the row in
    # proportion is the one (a walk of 0-1 rows, where a bisection of a 15 000-row table takes 14 steps: 11 % of the
    # right-hand side of brake-2dof, measured); an uneven table walks further to the same row.
    lo = int((t - rt[0]) / (rt[n - 1] - rt[0]) * (n - 1))
    lo = min(max(lo, 0), n - 2)
    while lo > 0 and not (rt[lo] < t or (rt[lo] == t and not left)):
        lo -= 1
    while lo < n - 2 and (rt[lo + 1] < t or (rt[lo + 1] == t and not left)):
        lo += 1
    hi = lo + 1
    slope = (rv[hi] - rv[lo]) / (rt[hi] - rt[lo])
    return rv[lo] + slope * (t - rt[lo]), slope


@helper
def drive_speed(v_cmd: float, dv_cmd: float, v_lag: float, pos: float, tau: float, ripple: float,
                wavelen: float):
    """belt-speed: actual drive speed and its derivative given the command.

    Returns (v, dv/dt). Without the effect (tau = 0, ripple = 0) the drive follows the command.
    The ripple is periodic in belt travel (a belt joint or an eccentric pulley).
    """
    if tau > 0.0:
        v_base = v_lag
        dv_base = (v_cmd - v_lag) / tau
    else:
        v_base = v_cmd
        dv_base = dv_cmd
    if ripple == 0.0:
        return v_base, dv_base
    k = 2.0 * math.pi / wavelen
    ph = k * pos
    rip = 1.0 + ripple * math.sin(ph)
    v = v_base * rip
    # d/dt [v_base (1 + a sin(k pos))] with d pos/dt = v
    return v, dv_base * rip + v_base * ripple * math.cos(ph) * k * v


@helper
def accel_sign_weight(sgn_v: float, acc_plus: float, acc_minus: float, drive_acc: float) -> float:
    """accel-sign: which kinetic branch applies, given the accelerations each branch would produce.

    The branch multiplier is (1 + amp*w) with w = +1 while |v_rel| grows and -1 while
    it shrinks. The choice depends on the acceleration it causes, so we pick the
    self-consistent branch; when neither is (the friction jump would reverse the
    trend) the contact slides along d|v_rel|/dt = 0 (Filippov), which fixes w in (-1, 1).
    ``acc_plus``/``acc_minus`` are the body accelerations (same units as the drive's)
    with w = +1/-1; returns w.
    """
    g_plus = sgn_v * (acc_plus - drive_acc)  # d|v_rel|/dt on the growing branch
    g_minus = sgn_v * (acc_minus - drive_acc)
    if g_plus > 0.0:
        return 1.0
    if g_minus < 0.0:
        return -1.0
    if g_minus == g_plus:
        return 0.0
    # linear in w: g(w) = g_minus + (w + 1)/2 (g_plus - g_minus) = 0
    return -1.0 + 2.0 * g_minus / (g_minus - g_plus)


@helper
def body_accel_factor(g_other: float, f: float, inv_mass: float, amp: float, a0: float) -> float:
    """accel-sign, body form: the factor 1 + amp tanh(a/a0) on the friction, with a the body's acceleration
    that this very friction causes, a = (g_other - f (1 + amp tanh(a/a0))) inv_mass (an implicit equation:
    four Newton steps from the acceleration without the effect; |amp| <= 0.5 keeps it monotone for the
    loads and scales of these rigs). ``g_other`` is every other force on the body (in the units of f)."""
    a = (g_other - f) * inv_mass
    for _ in range(4):
        th = math.tanh(a / a0)
        h = a - (g_other - f * (1.0 + amp * th)) * inv_mass
        dh = 1.0 + f * amp * (1.0 - th * th) / a0 * inv_mass
        if dh < 0.1:
            dh = 0.1
        a -= h / dh
    return 1.0 + amp * math.tanh(a / a0)


@helper
def env_rates(friction_power: float, v_cmd: float, v_drive: float, t: float, temp: float, v_lag: float,
              t_amb: float, drift: float, r_th: float, tau_th: float, vb_tau: float):
    """Rates of temperature, drive lag and drive travel: (dT/dt, dv_lag/dt, dpos/dt)."""
    d_temp = (t_amb + drift * t + r_th * abs(friction_power) - temp) / tau_th
    d_lag = (v_cmd - v_lag) / vb_tau if vb_tau > 0.0 else 0.0
    return d_temp, d_lag, v_drive


@helper
def stick_rates(v_rel: float, load_rate: float, ts: float, q: float, v_stick: float, fr_tau: float,
                st_reset: float):
    """Rates of the stick clock and of the load rate remembered from the last stick.

    While stuck the clock runs and q tracks the tangential load rate; while slipping the
    clock decays (time constant st_reset) and q is held.
    """
    st = stuck_fraction(v_rel, v_stick)
    return st - (1.0 - st) * ts / st_reset, st * (load_rate - q) / fr_tau


@helper
def stick_rates_if_read(v_rel: float, load_rate: float, ts: float, q: float, e_st_gain: float, e_fr_gain: float,
                        v_stick: float, fr_tau: float, st_reset: float):
    """stick_rates, but frozen at zero when neither stick-time nor force-rate reads the clock (saves an exp)."""
    if e_st_gain == 0.0 and e_fr_gain == 0.0:
        return 0.0, 0.0
    return stick_rates(v_rel, load_rate, ts, q, v_stick, fr_tau, st_reset)



# ---------------------------------------------------------------------------
# The chain (compiled): the effects of one contact, in the one order every rig applies them
#
# Why one chain: each rig's rhs calls these steps instead of the terms, so an effect is wired
# once, here, and reaches brake-2dof, drum-pendulum and belt-ndof alike (record 40). A step
# takes the effect vector ``e`` and reads its own slots, so a new effect adds no argument to
# any rig; the rig passes only its mechanics (its law's value, loads, masses) as scalars.
# Inlined, the steps compile to the code the rigs had written out, in the same floating-point
# order. Why each step reads its slots before anything else: an inlined helper that still holds
# an array past a branch or a call pays an atomic reference-count pair per call (see "Terms"),
# which doubled the smooth rigs' rhs time; so a step that takes an array (e, ds, aux) uses it
# only in its first lines, and where two steps with branches meet, the rig calls them in turn.
# The user factor is the rig's own call (daq/models/user_effects.py rebinds it in a copy of
# the rig's rhs), passed in as ``user``.
# ---------------------------------------------------------------------------


@helper
def contact_tail(s, off):
    """The contact's state from the tail at ``off`` of a state vector: (t_s, q, temperature, v_lag, travel)."""
    return s[off + TAIL.TS], s[off + TAIL.Q], s[off + TAIL.TEMP], s[off + TAIL.VLAG], s[off + TAIL.POS]


@helper
def drive_at(t, v_lag, pos, e, rt, rv, left):
    """The drive at t: (commanded speed, actual speed, its rate) after belt-speed; ``left`` as in ramp_eval_side."""
    tau, ripple, wavelen = e[E.VB_TAU], e[E.VB_RIPPLE], e[E.VB_WAVELEN]
    v_cmd, dv_cmd = ramp_eval_side(rt, rv, t, left)
    v, dv = drive_speed(v_cmd, dv_cmd, v_lag, pos, tau, ripple, wavelen)
    return v_cmd, v, dv


@helper
def peak_factor(ts, q, e):
    """Multiplier on the static (peak) part of a rig's law: stick-time (both forms) and force-rate."""
    st_gain, st_tau, fr_gain, fr_q0, log_gain = e[E.ST_GAIN], e[E.ST_TAU], e[E.FR_GAIN], e[E.FR_Q0], e[E.ST_LOG_GAIN]
    return static_factor(ts, q, st_gain, st_tau, fr_gain, fr_q0) + aging_log(ts, log_gain, st_tau)


@helper
def mu_factor(temp, e):
    """Multiplier on a rig's whole law: temperature (both forms)."""
    coef, ref, theta = e[E.TEMP_COEF], e[E.TEMP_REF], e[E.TEMP_ARR]
    return temperature_factor(temp, coef, ref) * arrhenius_factor(temp, theta, ref)


@helper
def with_speed_terms(mu_law, factor, speed, e):
    """The law after its multiplier ``factor`` (mu_factor) and the terms added in the slip speed:
    velocity-strengthening (belt-ndof passes its dimensionless w as the speed)."""
    return mu_law * factor + e[E.VS_D] * speed


@helper
def friction_force(mu_law, factor, n_inst, n_nominal, v_rel, user, e):
    """The smooth-law rigs' contact (brake-2dof, drum-pendulum): the law's mu through the chain (``factor`` =
    mu_factor), times the normal load after normal-load. Returns (F, mu, N) before accel-sign."""
    mu = with_speed_terms(mu_law, factor, v_rel, e) * user
    n = normal_load(n_inst, n_nominal, e[E.NL_WEIGHT])
    return mu * n, mu, n


@helper
def accel_sign(f, mu, g_other, inv_mass, v_rel, drive_acc, e):
    """accel-sign, both forms, on (F, mu). The body's acceleration at the contact is (g_other - F) inv_mass
    (g_other: every other force, in F's units); ``drive_acc``: the drive's, in the same units."""
    amp, amp_b, a0 = e[E.AS_AMP], e[E.AS_BODY_AMP], e[E.AS_BODY_A0]
    if amp != 0.0:
        sg = 1.0 if v_rel > 0.0 else (-1.0 if v_rel < 0.0 else 0.0)
        w = accel_sign_weight(sg, (g_other - f * (1.0 + amp)) * inv_mass, (g_other - f * (1.0 - amp)) * inv_mass,
                              drive_acc)
        f = f * (1.0 + amp * w)
        mu = mu * (1.0 + amp * w)
    if amp_b != 0.0:  # the body form: a smooth switch on the body's own acceleration
        fb = body_accel_factor(g_other, f, inv_mass, amp_b, a0)
        f = f * fb
        mu = mu * fb
    return f, mu


@helper
def stick_clock_rates(v_rel, load_rate, ts, q, e):
    """Rates of the stick clock and the remembered load rate (stick-time, force-rate); Dieterich's state
    for the clock where the log form has a Dc."""
    st_gain, log_gain, fr_gain, dc = e[E.ST_GAIN], e[E.ST_LOG_GAIN], e[E.FR_GAIN], e[E.ST_DC]
    v_stick, fr_tau, st_reset = e[E.V_STICK], e[E.FR_TAU], e[E.ST_RESET]
    d_ts, d_q = stick_rates_if_read(v_rel, load_rate, ts, q, abs(st_gain) + abs(log_gain), fr_gain, v_stick, fr_tau,
                                    st_reset)
    if dc > 0.0 and log_gain != 0.0:  # the log form with Dieterich's state for its clock
        d_ts = dieterich_rate(v_rel, ts, max(dc, DC_MIN))
    return d_ts, d_q


@helper
def environment_rates(power, v_cmd, v_drive, t, temp, v_lag, e):
    """Rates of temperature, drive lag and travel (env_rates) from the friction power and the drive."""
    t_amb, drift, r_th, tau_th, vb_tau = e[E.T_AMB], e[E.TH_DRIFT], e[E.TH_R], e[E.TH_TAU], e[E.VB_TAU]
    return env_rates(power, v_cmd, v_drive, t, temp, v_lag, t_amb, drift, r_th, tau_th, vb_tau)


@helper
def set_tail(ds, off, d_ts, d_q, d_psi, env):
    """Fill the contact tail's rates at ``off``: stick clock, load rate, rate-and-state's state, and the three
    of environment_rates (``env``)."""
    ds[off + TAIL.TS] = d_ts
    ds[off + TAIL.Q] = d_q
    ds[off + TAIL.TEMP] = env[0]
    ds[off + TAIL.VLAG] = env[1]
    ds[off + TAIL.POS] = env[2]
    ds[off + TAIL.PSI] = d_psi
