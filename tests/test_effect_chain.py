"""One effect chain for every rig (docs/decisions/0040-one-effect-chain.md).

The effects of a contact (peak factor, temperature, velocity strengthening, user factor, normal load,
accel-sign, stick clock, Dieterich state, environment rates) are one chain in daq/physics/effects.py that
every rig's rhs calls. These tests hold each rig to the same chain, written here a second time in plain
Python from the catalog's meanings: a rig that wired an effect differently (another order, a missed term,
another acceleration for accel-sign) fails, whichever rig it is.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from daq.config import load_rig
from daq.physics import beltndof, brake2dof, drum, friction
from daq.physics.contact import AUX, N_AUX
from daq.physics.effects import (
    DC_MIN,
    TAIL,
    E,
    friction_force,
    mu_factor,
    neutral_vector,
    peak_factor,
    stick_clock_rates,
    with_speed_terms,
)
from daq.sim.effectset import effect_vector
from daq.sim.rigs import make_sim

# every effect of the chain on, at non-neutral values; accel-sign apart (its branch depends on the mechanics)
CHAIN_ON = {E.NL_WEIGHT: 0.7, E.ST_GAIN: 0.3, E.ST_TAU: 0.5, E.FR_GAIN: 0.2, E.FR_Q0: 2.0, E.ST_LOG_GAIN: 0.1,
            E.TEMP_COEF: 0.005, E.TEMP_REF: 21.0, E.TEMP_ARR: 300.0, E.VS_D: 0.3, E.VB_TAU: 0.05,
            E.VB_RIPPLE: 0.05, E.VB_WAVELEN: 0.9, E.AS_AMP: 0.0, E.AS_BODY_AMP: 0.0,
            E.V_STICK: 0.01, E.T_AMB: 22.0, E.TH_R: 150.0, E.TH_TAU: 15.0, E.TH_DRIFT: 0.1, E.FR_TAU: 0.02,
            E.ST_RESET: 0.01}
V_CMD = 0.12
# contact states (v_rel, t_s, q, temperature, v_lag, travel): stuck, creeping, slipping both ways
CONTACTS = [(0.0005, 0.8, 3.0, 35.0, 0.1, 0.2), (-0.004, 0.02, -1.0, 24.0, 0.13, 1.3),
            (0.03, 2.0, 0.5, 60.0, 0.11, 0.05), (-0.25, 0.0, 0.0, 18.0, 0.12, 2.7)]


def _vector(rig: str, over: dict | None = None) -> np.ndarray:
    e, _ = effect_vector(load_rig(rig))
    for k, v in {**CHAIN_ON, **(over or {})}.items():
        e[k] = v
    return e


def _reference(e, t, v_rel, ts, q, temp, v_lag, pos, law, n_inst, n_nom, load_rate):
    """The chain in plain Python: (mu, N, F, rates of t_s, q, temperature, v_lag, travel), accel-sign off."""
    v_drive = v_lag * (1.0 + e[E.VB_RIPPLE] * math.sin(2.0 * math.pi / e[E.VB_WAVELEN] * pos))
    sf = (1.0 + e[E.ST_GAIN] * (1.0 - math.exp(-ts / e[E.ST_TAU])) + e[E.FR_GAIN] * math.log1p(abs(q) / e[E.FR_Q0])
          + e[E.ST_LOG_GAIN] * math.log1p(ts / e[E.ST_TAU]))
    tf = ((1.0 + e[E.TEMP_COEF] * (temp - e[E.TEMP_REF]))
          * math.exp(e[E.TEMP_ARR] * (1.0 / (temp + 273.15) - 1.0 / (e[E.TEMP_REF] + 273.15))))
    mu = (law(v_rel, sf) * tf + e[E.VS_D] * v_rel) * 1.0  # the built-in user factor
    n = n_nom + e[E.NL_WEIGHT] * (n_inst - n_nom)
    f = mu * n
    stuck = math.exp(-(v_rel / e[E.V_STICK]) ** 2)
    d_ts = stuck - (1.0 - stuck) * ts / e[E.ST_RESET]
    if e[E.ST_DC] > 0.0:
        d_ts = 1.0 - abs(v_rel) * ts / max(e[E.ST_DC], DC_MIN)
    d_q = stuck * (load_rate - q) / e[E.FR_TAU]
    d_temp = (e[E.T_AMB] + e[E.TH_DRIFT] * t + e[E.TH_R] * abs(f * v_rel) - temp) / e[E.TH_TAU]
    return mu, n, f, (d_ts, d_q, d_temp, (V_CMD - v_lag) / e[E.VB_TAU], v_drive)


def _brake(e, t, v_rel, ts, q, temp, v_lag, pos):
    """brake-2dof's rhs at a contact state: (aux, tail rates, reference, the law's value without effects)."""
    sim = make_sim(load_rig("brake-2dof"), e)
    p = sim.p
    s = np.zeros(brake2dof.N_STATE)
    v_drive = v_lag * (1.0 + e[E.VB_RIPPLE] * math.sin(2.0 * math.pi / e[E.VB_WAVELEN] * pos))
    s[:4] = 1e-3, v_rel + v_drive, 2e-3, 0.01
    s[brake2dof.N_MECH:brake2dof.N_MECH + 5] = ts, q, temp, v_lag, pos
    ds, aux = np.empty(brake2dof.N_STATE), np.empty(N_AUX)
    brake2dof.rhs(t, s, p, e, np.array([0.0, 10.0]), np.array([V_CMD, V_CMD]), ds, aux)
    P = brake2dof.P

    def law(v, sf):
        return friction.mu_brake(v, p[P.mu0], p[P.gamma], p[P.alpha], p[P.beta] * sf)

    load_rate = (p[P.k1] + p[P.k2]) * s[1] + p[P.k2] * s[3]
    ref = _reference(e, t, v_rel, ts, q, temp, v_lag, pos, law, aux[AUX.N_INST], p[P.N_NOM], load_rate)
    return aux, ds[brake2dof.N_MECH:brake2dof.N_MECH + 5], ref, law(v_rel, 1.0)


def _drum(e, t, v_rel, ts, q, temp, v_lag, pos):
    sim = make_sim(load_rig("drum-pendulum"), e)
    p = sim.p
    P = drum.P
    s = np.zeros(drum.N_STATE)
    v_drive = v_lag * (1.0 + e[E.VB_RIPPLE] * math.sin(2.0 * math.pi / e[E.VB_WAVELEN] * pos))
    s[:2] = 0.05, (v_rel + v_drive) / p[P.R]
    s[drum.N_MECH:drum.N_MECH + 5] = ts, q, temp, v_lag, pos
    ds, aux = np.empty(drum.N_STATE), np.empty(N_AUX)
    drum.rhs(t, s, p, e, np.array([0.0, 10.0]), np.array([V_CMD, V_CMD]), ds, aux)

    def law(v, sf):
        return friction.mu_drum(v, p[P.A], p[P.B], p[P.C], p[P.E0], p[P.EPS], sf)

    load_rate = p[P.k] * p[P.Rs] ** 2 * math.cos(2.0 * s[0]) * s[1] / p[P.R]
    ref = _reference(e, t, v_rel, ts, q, temp, v_lag, pos, law, aux[AUX.N_INST], p[P.P], load_rate)
    return aux, ds[drum.N_MECH:drum.N_MECH + 5], ref, law(v_rel, 1.0)


RIGS = {"brake-2dof": _brake, "drum-pendulum": _drum}


@pytest.mark.parametrize("dc", [0.0, 1e-4])
@pytest.mark.parametrize("rig", list(RIGS))
def test_each_smooth_rig_applies_the_one_chain(rig, dc):
    """mu, N, F and the contact tail's rates of the rig's rhs are the chain's, effect by effect."""
    e = _vector(rig, {E.ST_DC: dc})
    for contact in CONTACTS:
        aux, rates, (mu, n, f, ref_rates), _ = RIGS[rig](e, 1.7, *contact)
        np.testing.assert_allclose([aux[AUX.MU], aux[AUX.N], aux[AUX.F]], [mu, n, f], rtol=1e-12, atol=1e-15,
                                   err_msg=f"{rig} {contact}")
        np.testing.assert_allclose(rates, ref_rates, rtol=1e-12, atol=1e-15, err_msg=f"{rig} {contact}")


def test_brake_and_drum_see_the_same_chain_at_the_same_contact():
    """Same contact state, same effect vector: the same multiplier and added term on each rig's own law, the
    same stick clock, drive lag and travel rates (the load rate and friction power are each rig's own)."""
    e = _vector("brake-2dof")
    for contact in CONTACTS:
        v_rel = contact[0]
        out = {}
        for rig, fn in RIGS.items():
            aux, rates, _, _ = fn(e, 1.7, *contact)
            # the law's value at the contact with the peak factor applied: from the rig with temperature and
            # velocity strengthening at neutral (their slots only)
            e_peak = e.copy()
            e_peak[E.TEMP_COEF] = e_peak[E.TEMP_ARR] = e_peak[E.VS_D] = 0.0
            law_peak = fn(e_peak, 1.7, *contact)[0][AUX.MU]
            out[rig] = ((aux[AUX.MU] - e[E.VS_D] * v_rel) / law_peak, rates[0], rates[3], rates[4])
        np.testing.assert_allclose(out["brake-2dof"], out["drum-pendulum"], rtol=1e-12, err_msg=str(contact))


def _accel_sign_cases(rig, amp_key):
    """Over a sweep of states: (w, sign(v_rel) x the body's acceleration at the contact) with accel-sign on."""
    e_on = _vector(rig, {amp_key: 0.2, E.VB_TAU: 0.0, E.VB_RIPPLE: 0.0, E.AS_BODY_A0: 2.0})
    e_off = e_on.copy()
    e_off[amp_key] = 0.0
    out = []
    for v_rel in (-0.3, -0.02, -0.001, 0.0007, 0.01, 0.2):
        for shift in np.linspace(-3e-3, 3e-3, 13):
            auxs = []
            for e in (e_on, e_off):
                sim = make_sim(load_rig(rig), e)
                if rig == "brake-2dof":
                    s = np.zeros(brake2dof.N_STATE)
                    s[:4] = shift, v_rel + V_CMD, -0.5 * shift, 0.0
                    s[brake2dof.N_MECH + TAIL.TEMP] = 22.0
                    fn = brake2dof.rhs
                else:
                    s = np.zeros(drum.N_STATE)
                    s[:2] = 20.0 * shift, (v_rel + V_CMD) / sim.p[drum.P.R]
                    s[drum.N_MECH + TAIL.TEMP] = 22.0
                    fn = drum.rhs
                aux = np.empty(N_AUX)
                fn(0.0, s, sim.p, e, np.array([0.0, 10.0]), np.array([V_CMD, V_CMD]), np.empty(s.size), aux)
                auxs.append(aux)
            out.append((auxs[0][AUX.F] / auxs[1][AUX.F], math.copysign(1.0, v_rel) * auxs[0][AUX.ACC],
                        abs(auxs[1][AUX.ACC]), auxs[0][AUX.ACC]))
    return out


@pytest.mark.parametrize("rig", list(RIGS))
def test_accel_sign_acts_on_each_rigs_own_acceleration(rig):
    """Relative form: the branch chosen is self-consistent with the acceleration the rig then has (growing
    |v_rel| on the growing branch, shrinking on the other, held in between); a rig that handed the chain
    another force or mass would break it. Body form: the factor is 1 + amp tanh(a / a0) of the body's
    acceleration a that this very friction causes."""
    amp = 0.2
    kinds = set()
    for factor, trend, scale, _ in _accel_sign_cases(rig, E.AS_AMP):
        w = (factor - 1.0) / amp
        if w > 1.0 - 1e-12:
            assert trend > 0.0
            kinds.add("grow")
        elif w < -1.0 + 1e-12:
            assert trend < 0.0
            kinds.add("shrink")
        else:
            assert abs(trend) <= 1e-9 * scale, (w, trend, scale)
            kinds.add("held")
    assert kinds == {"grow", "shrink", "held"}
    for factor, _, _, acc in _accel_sign_cases(rig, E.AS_BODY_AMP):
        assert factor == pytest.approx(1.0 + amp * math.tanh(acc / 2.0), abs=1e-6)


def test_belt_reads_the_same_peak_and_mu_factors():
    """belt-ndof's static limit is F_S0 times the chain's peak factor, and a slipping mass's friction is its
    law through the chain's multiplier and speed term."""
    cfg = load_rig("belt-ndof")
    e = _vector("belt-ndof", {E.VS_D: 0.03})
    sim = make_sim(cfg, e)
    p = sim.p
    n = int(p[beltndof.P.N])
    for ts, q, temp in ((0.0, 0.0, 22.0), (0.7, 4.0, 40.0), (3.0, -2.0, 15.0)):
        ref_sf = (1.0 + e[E.ST_GAIN] * (1.0 - math.exp(-ts / e[E.ST_TAU]))
                  + e[E.FR_GAIN] * math.log1p(abs(q) / e[E.FR_Q0]) + e[E.ST_LOG_GAIN] * math.log1p(ts / e[E.ST_TAU]))
        assert beltndof._static_limit(ts, q, p, e) == pytest.approx(p[beltndof.P.F_S0] * ref_sf, rel=1e-13)
        s = np.zeros(beltndof.n_state(n))
        s[2 * n + TAIL.TEMP] = temp
        s[2 * n + TAIL.VLAG] = V_CMD
        s[n] = 0.5 * V_CMD  # mass 1 lags the belt: slipping with w > 0
        hs = beltndof.new_hybrid(n, p[beltndof.P.F_S0], 1.0)
        hs[beltndof.H.DROP] = 0.0
        fric = np.empty(n)
        rt, rv = np.array([0.0, 10.0]), np.array([V_CMD, V_CMD])
        _, vb, _ = beltndof.rhs(0.0, s, hs, p, e, rt, rv, np.empty(s.size), fric, np.zeros(n, dtype=np.int64))
        vu = p[beltndof.P.F0] / math.sqrt(p[beltndof.P.K] * p[beltndof.P.M])
        w = (vb - s[n]) / vu
        tf = ((1.0 + e[E.TEMP_COEF] * (temp - e[E.TEMP_REF]))
              * math.exp(e[E.TEMP_ARR] * (1.0 / (temp + 273.15) - 1.0 / (e[E.TEMP_REF] + 273.15))))
        P = beltndof.P
        law = friction.f_pwl_piece(w, -1.0, -math.inf, p[P.ALPHA_DROP], p[P.F_K0], p[P.K_FALL], p[P.W_MIN],
                                   p[P.K_RISE], e[E.AS_AMP])
        assert fric[0] / p[P.F0] == pytest.approx(law * tf + e[E.VS_D] * w, rel=1e-12)


def test_the_chain_at_neutral_is_the_law_alone():
    """Every step of the chain is the identity with every effect at its neutral value (the environment
    slots at working values): the rig's own law and load go through untouched."""
    e = neutral_vector()
    e[E.V_STICK], e[E.FR_TAU], e[E.ST_RESET] = 0.01, 0.02, 0.01
    for ts, q, temp, v in ((0.0, 0.0, 22.0, 0.1), (5.0, 3.0, 80.0, -0.02), (0.3, -1.0, -10.0, 0.0)):
        assert peak_factor(ts, q, e) == 1.0
        assert mu_factor(temp, e) == 1.0
        assert with_speed_terms(0.37, 1.0, v, e) == 0.37
        assert friction_force(0.37, 1.0, 12.0, 10.0, v, 1.0, e) == (0.37 * 10.0, 0.37, 10.0)
        assert stick_clock_rates(v, 5.0, ts, q, e) == (0.0, 0.0)
