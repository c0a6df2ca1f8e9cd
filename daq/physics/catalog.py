"""The effects catalog: every physical effect as a parameterised term with a neutral value (data, no compiled code).

Why one vector for all effects: the simulator and the models call the same
compiled equations; an effect that is "off" is simply at its neutral value, so
adding or removing an effect never changes code, only numbers. The slots of
that vector are named by :class:`E`; each rig's equations read the slots that
apply to it. Stateful effects (stick time, force rate, temperature, belt lag)
carry their state in the common *contact tail* of every rig's state vector,
see :data:`TAIL`.

Why apart from the compiled terms (:mod:`daq.physics.effects`): a config names its effects, so every process that
reads one imports the catalog, and most of them (the daemon, the recorder, the web page's process) never simulate:
with the terms beside it each paid numba's import, 0.4-0.5 s of CPU a process on this 2-core machine
(``python -X importtime``), times every daemon, recorder and command the suite starts.

Decision record: docs/decisions/0001-physics-in-one-place.md.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
from pydantic import BaseModel, ConfigDict



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
# [s] the shortest lag the drive (belt-speed, lag-ripple) uses: RK4 on (v_cmd - v_lag)/tau is stable for h/tau < 2.785,
# so at the brake's 0.5 ms a fitted tau under 0.18 ms diverged to 1e300 and overflowed a fit (decision 50); under
# 1 ms a lag is two samples of a 1 kHz record, which nothing resolves
VB_TAU_MIN = 1e-3


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
