"""Where a fit starts: the models a fit passes through when `model add` left effects at neutral, the generic starts of
an added effect's strength and scale parameters, and the key that says what a fit depends on. Session.fit's starts
(session.py) are made of these; why each start exists is said where it is used.
"""

from __future__ import annotations

import numpy as np

from daq.config import RigConfig
from daq.physics.effects import CATALOG

from ..spec import SECOND_START, STRENGTH_START, Model, form_key, strength_key


def fit_key(model: Model, cfg: RigConfig) -> str:
    """What a fit of ``model`` depends on: structure, values, what is free and its bounds; not its title, provenance,
    stds, nor a fixed mechanics entry that only repeats the config's value (added_chain's first link keeps one)."""
    params = {k: (p.value, p.free, p.lo, p.hi) if p.free else (p.value,) for k, p in model.params().items()
              if p.free or not (k.startswith("mechanics.") and p.value == getattr(cfg.mechanics, k[10:], None))}
    effects = [(n, e.form, e.path) for n, e in model.effects.items()]
    return repr((model.rig, model.law, model.rig_config, sorted(params.items()), effects))


def added_chain(model: Model, cfg: RigConfig) -> list[Model]:
    """The models a fit of ``model`` passes through when `model add` left things at neutral: the model without
    them, then with one more each time, in the file's order (mechanics first), ending before ``model`` itself.
    Empty when nothing sits at neutral (a fitted model file, a seed model)."""
    held_effects = [name for name, eff in model.effects.items()
                    if eff.path is None and name not in cfg.seed_effects and name in CATALOG
                    and (not CATALOG[name].params_for(model.rig, eff.form)
                         or f"effects.{name}.{strength_key(model.rig, name, eff.form)}" in neutral_strengths(model))]
    held_mech = [k for k, par in model.mechanics.items()
                 if par.free and par.value == float(getattr(cfg.mechanics, k, float("nan")))]
    if not held_effects and not held_mech:
        return []
    steps = [("mechanics", k) for k in held_mech] + [("effect", n) for n in held_effects]
    out = []
    for upto in range(len(steps)):  # steps[:upto] are in; the rest held out
        m = model.model_copy(deep=True)
        for kind, name in steps[upto:]:
            if kind == "effect":
                del m.effects[name]
            else:
                m.mechanics[name].free = False
        out.append(m)
    return out


def free_strengths(model: Model, values: dict[str, float]) -> list[tuple[str, str, float]]:
    """(effect name, strength's full name, its neutral value) of every catalog effect whose strength is free."""
    out = []
    params = model.params()
    for name, eff in model.effects.items():
        if name not in CATALOG or eff.path is not None:
            continue
        key = strength_key(model.rig, name, eff.form)
        full = f"effects.{name}.{key}"
        if key is not None and full in values and params[full].free:
            out.append((name, full, CATALOG[name].params_for(model.rig, eff.form)[0].neutral))
    return out


def second_starts(model: Model, moved: dict[str, float], bounds: dict) -> dict[str, float]:
    """SECOND_START's values for the effects whose strength ``moved`` starts away from neutral (free parameters
    only, clipped to their bounds)."""
    out = {}
    for name, eff in model.effects.items():
        key = strength_key(model.rig, name, eff.form) if name in CATALOG and eff.path is None else None
        if key is None or f"effects.{name}.{key}" not in moved:
            continue
        for k, v in SECOND_START.get(form_key(name, eff.form), {}).items():
            full = f"effects.{name}.{k}"
            if full in bounds:
                out[full] = float(np.clip(v, *bounds[full]))
    return out


def neutral_strengths(model: Model) -> list[str]:
    """Free catalog-effect strengths that sit at their neutral value: an effect just added by `model add`."""
    values = {k: p.value for k, p in model.params().items()}
    return [full for _, full, neutral in free_strengths(model, values) if values[full] == neutral]


def strength_starts(model: Model, values: dict[str, float]) -> dict[str, float]:
    """Generic non-zero starts for every free catalog-effect strength that sits at its neutral value."""
    out = {}
    params = model.params()
    for name, full, neutral in free_strengths(model, values):
        start = STRENGTH_START.get(form_key(name, model.effects[name].form))
        if start is not None and values[full] == neutral:
            p = params[full]
            out[full] = float(np.clip(start, p.lo if p.lo is not None else -np.inf, p.hi if p.hi is not None else np.inf))
    return out
