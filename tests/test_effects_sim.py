"""Every catalog effect on every rig it applies to: it simulates, it matters, its neutral value is a no-op,
and where its signature can be derived, the simulation shows exactly that signature."""

from __future__ import annotations

import numpy as np
import pytest

from daq.config import load_rig
from daq.errors import InputError
from daq.physics import friction
from daq.physics.effects import CATALOG
from daq.sim.effectset import EffectRequest, effect_vector
from daq.sim.run import simulate

DURATION = {"brake-2dof": 4.0, "drum-pendulum": 4.0, "belt-ndof": 4.0}
MAIN = {"brake-2dof": "x1", "drum-pendulum": "phi", "belt-ndof": "x1"}
PAIRS = [(rig, name) for name, spec in CATALOG.items() for rig in spec.rigs]


def run(rig, effects=(), **kw):
    cfg = load_rig(rig)
    return simulate(cfg, effects=[EffectRequest(n, v) for n, v in effects], duration=DURATION[rig],
                    noise=False, **kw)


_baseline: dict[str, object] = {}


def baseline(rig):
    if rig not in _baseline:
        _baseline[rig] = run(rig)
    return _baseline[rig]


@pytest.mark.parametrize("rig,name", PAIRS)
def test_effect_simulates_and_matters(rig, name):
    cfg = load_rig(rig)
    spec = CATALOG[name]
    base = baseline(rig)
    if name in cfg.seed_effects:
        # a seed effect is already on: switching it to neutral must change the run
        vals = {ps.key: ps.neutral for ps in spec.params_for(rig)}
    else:
        vals = dict(cfg.effects[name])
    r = run(rig, [(name, vals)])
    key = MAIN[rig]
    assert all(np.all(np.isfinite(x)) for x in r.channels.values())
    diff = np.max(np.abs(r.truth[f"true_{key}"] - base.truth[f"true_{key}"]))
    scale = np.ptp(base.truth[f"true_{key}"])
    assert diff > 1e-3 * scale, (rig, name, diff, scale)


@pytest.mark.parametrize("rig,name", [(r, n) for r, n in PAIRS if n not in load_rig(r).seed_effects])
def test_neutral_value_is_an_exact_no_op(rig, name):
    spec = CATALOG[name]
    # the first form with parameters (belt-speed's default form, the measured drive, has none)
    form = next(f or None for f in spec.form_names() if spec.params_for(rig, f or None))
    vals = {ps.key: ps.neutral for ps in spec.params_for(rig, form)}
    cfg = load_rig(rig)
    r = simulate(cfg, effects=[EffectRequest(name, vals, form)], duration=DURATION[rig], noise=False)
    base = baseline(rig)
    for k in base.truth:
        np.testing.assert_array_equal(r.truth[k], base.truth[k], err_msg=f"{rig} {name} {k}")


def test_effect_that_does_not_apply_is_refused():
    for rig, name in [("belt-ndof", "normal-load"), ("belt-ndof", "bearing-friction"), ("drum-pendulum", "geometric")]:
        with pytest.raises(InputError, match=f"{name}: does not apply to {rig}"):
            effect_vector(load_rig(rig), [EffectRequest(name, {})])


def test_out_of_bounds_value_is_refused():
    with pytest.raises(InputError, match=r"accel-sign\.amp: 0\.9 outside"):
        effect_vector(load_rig("brake-2dof"), [EffectRequest("accel-sign", {"amp": 0.9})])


# --------------------------------------------------------------------------- derived signatures


def test_belt_speed_lag_offset_on_the_seed_ramp():
    """First-order lag tau on a ramp of slope a, starting on the command: v - v_cmd = -tau a (1 - e^(-t/tau))."""
    tau = 0.4
    r = run("brake-2dof", [("belt-speed", {"tau": tau, "ripple": 0.0})])
    lag = r.truth["v_drive"] - r.truth["true_vb_set"]
    slope = -0.17 / 45.0
    np.testing.assert_allclose(lag, -tau * slope * (1 - np.exp(-r.t / tau)), rtol=1e-6, atol=1e-12)


def brake_with_law(effect: str, params: dict):
    """The brake run with one effect, its relative velocity, and the config's friction law mu at that velocity."""
    r = run("brake-2dof", [(effect, params)])
    cfg = load_rig("brake-2dof").friction
    v = r.truth["v_rel"]
    return r, v, friction.mu_brake(v, cfg.mu0, cfg.gamma_s_per_m, cfg.alpha_s_per_m, cfg.beta)


def test_velocity_strengthening_adds_D_v_to_mu():
    D = 0.8
    r, v, base_mu = brake_with_law("velocity-strengthening", {"D": D})
    np.testing.assert_allclose(r.truth["mu"] - base_mu, D * v, atol=1e-12)


def test_accel_sign_branches_follow_the_relative_acceleration():
    """mu = mu_law (1 + amp w), w = +1 while |v_rel| grows, -1 while it shrinks (Filippov in between)."""
    amp = 0.15
    r, v, law = brake_with_law("accel-sign", {"amp": amp})
    sliding = np.abs(v) > 0.02
    w = (r.truth["mu"][sliding] / law[sliding] - 1.0) / amp
    assert np.all(np.abs(w) <= 1 + 1e-9)
    d_abs_v = np.gradient(np.abs(v), r.t)[sliding]
    clear = np.abs(d_abs_v) > 1.0  # well away from the switching instants
    np.testing.assert_allclose(w[clear & (d_abs_v > 0)], 1.0, atol=1e-9)
    np.testing.assert_allclose(w[clear & (d_abs_v < 0)], -1.0, atol=1e-9)


def test_drum_normal_load_follows_the_thrust_gauge_only_with_the_effect():
    r = baseline("drum-pendulum")  # seed: normal-load weight 1
    np.testing.assert_allclose(r.truth["normal_load"], r.truth["normal_load"] * 0 + r.channels["thrust"],
                               atol=0.2)  # the gauge reads the same load, plus noise-free quantisation
    off = run("drum-pendulum", [("normal-load", {"weight": 0.0})])
    assert np.ptp(off.truth["normal_load"]) == 0.0
    assert np.ptp(off.channels["thrust"]) > 0.1  # the load still varies; friction just ignores it


def test_temperature_rises_with_friction_power_and_scales_mu():
    coef = -0.02
    r = run("drum-pendulum", [("temperature", {"coef": coef, "ref": 22.0})])
    temp = r.truth["temperature"]
    assert temp[-1] > temp[0] + 1.0
    base = baseline("drum-pendulum")
    # same contact state at t = 0 (no heating yet): identical friction coefficient
    assert r.truth["mu"][0] == pytest.approx(base.truth["mu"][0], rel=1e-12)


def test_stick_time_clock_runs_only_when_read():
    r = run("brake-2dof", [("stick-time", {"gain": 0.6, "tau": 0.3})])
    clock = r.truth["stick_clock"]
    assert clock.max() > 0.03  # creep phases of tens of ms are counted
    assert np.all(baseline("brake-2dof").truth["stick_clock"] == 0.0)


def test_geometric_weight_zero_removes_gravity_offset():
    r = run("brake-2dof", [("geometric", {"weight": 0.0})])
    base = baseline("brake-2dof")
    # with the angular body's weight the equilibrium angle is ~ -0.09 rad; without it ~ 0
    assert np.mean(base.truth["true_phi"]) < -0.05
    assert abs(np.mean(r.truth["true_phi"])) < 0.03
