"""Every effect in every form, on every rig it applies to: exactly the base model at its neutral value,
and close to it nearby (the departure shrinks with the strength, on both sides where the physics has two).

Why this matters to a diagnosis: a fit of a model with an effect added starts from the model without
it (the effect at neutral) and can only move continuously from there; an effect that were not the base
model at neutral, or that jumped as its strength left neutral, would make "add it and refit" end worse
than the model it extends.
"""

from __future__ import annotations

import numpy as np
import pytest

from daq.config import load_rig
from daq.physics.effects import CATALOG
from daq.sim.effectset import EffectRequest
from daq.sim.run import simulate

DURATION = 1.5  # short: stick-slip is chaotic enough that long runs amplify any change
MAIN = {"brake-2dof": "true_x1", "drum-pendulum": "true_phi", "belt-ndof": "true_x1"}
FORMS = [(rig, name, form or None) for name, spec in CATALOG.items() for rig in spec.rigs
         for form in spec.form_names() if spec.form_applies(rig, form or None) and spec.params_for(rig, form or None)]
# a secondary parameter (a time constant, a reference) at a working value, so the strength acts
SECONDARY = {"tau": 0.3, "q0": 2.0, "wavelength": 0.9, "ref": 22.0, "dc": 1e-4}


def _run(rig: str, name: str, form: str | None, values: dict[str, float]):
    cfg = load_rig(rig)
    # the rig's seed with this effect's own seed entry (if any) replaced: the strength alone differs
    requests = [EffectRequest(name, values, form)]
    return simulate(cfg, effects=requests, duration=DURATION, noise=False)


# the parameter probed: the strength (the first), but the ripple of a lagged drive (a lag alone is inert
# on the constant-speed programmes of the drum and belt rigs)
PROBED = {("belt-speed", "lag-ripple"): "ripple"}


def _strength(rig: str, name: str, form: str | None):
    plist = CATALOG[name].params_for(rig, form)
    key = PROBED.get((name, form), plist[0].key)
    return next(ps for ps in plist if ps.key == key)


def _values(rig: str, name: str, form: str | None, strength: float) -> dict[str, float]:
    plist = CATALOG[name].params_for(rig, form)
    probed = _strength(rig, name, form).key
    out = {ps.key: SECONDARY.get(ps.key, ps.neutral) for ps in plist if ps.key != probed}
    out[probed] = strength
    if name == "viscous-damping":  # two strengths: both move together
        out = {ps.key: strength for ps in plist}
    return out


def _neutral(rig: str, name: str, form: str | None) -> float:
    return _strength(rig, name, form).neutral


def _step(rig: str, name: str, form: str | None) -> float:
    """A twentieth of the magnitude the rig config chooses for the effect (a small departure from neutral),
    else 0.2 % of the catalog's range."""
    ps = _strength(rig, name, form)
    chosen = load_rig(rig).effects.get(name, {}).get(ps.key)
    if chosen is not None and chosen != ps.neutral:
        return 0.05 * abs(chosen - ps.neutral)
    return 0.002 * (ps.hi - ps.lo)


# a seed effect is part of the base model: its neutral value is not "the model without it" (the nearby test
# below covers it)
NON_SEED = [(rig, name, form) for rig, name, form in FORMS if name not in load_rig(rig).seed_effects]


@pytest.mark.parametrize("rig,name,form", NON_SEED)
def test_neutral_is_the_model_without_the_effect(rig, name, form):
    cfg = load_rig(rig)
    base = simulate(cfg, duration=DURATION, noise=False)
    r = _run(rig, name, form, {ps.key: ps.neutral for ps in CATALOG[name].params_for(rig, form)})
    for k in base.truth:
        np.testing.assert_array_equal(r.truth[k], base.truth[k], err_msg=f"{rig} {name} ({form}) {k}")


@pytest.mark.parametrize("rig,name,form", FORMS)
def test_nearby_strengths_stay_close_and_shrink_with_the_strength(rig, name, form):
    ps = _strength(rig, name, form)
    n0 = ps.neutral
    at_neutral = _run(rig, name, form, _values(rig, name, form, n0)).truth[MAIN[rig]]
    scale = float(np.ptp(at_neutral))
    signs = [s for s in (+1, -1) if ps.lo <= n0 + s * _step(rig, name, form) <= ps.hi]
    assert signs, "an effect must be able to leave its neutral value"
    for sign in signs:
        d = sign * _step(rig, name, form)
        dev = [float(np.max(np.abs(_run(rig, name, form, _values(rig, name, form, n0 + d * f)).truth[MAIN[rig]]
                                   - at_neutral))) for f in (1.0, 0.25)]
        assert dev[0] > 1e-6 * scale, f"{name} ({form}) at {n0 + d:g} does nothing on {rig}"
        assert dev[0] < 0.5 * scale, f"{name} ({form}) at {n0 + d:g} is not close to the model without it"
        assert dev[1] <= 0.6 * dev[0] + 1e-9 * scale, (name, form, sign, dev)  # continuous: shrinks with it
