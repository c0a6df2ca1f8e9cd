"""Turning a rig config plus ``--effect NAME[:key=val,...]`` requests into the effect vector."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from daq.config import RigConfig
from daq.errors import InputError
from daq.physics.catalog import CATALOG, ENVIRONMENT_SLOTS, E, neutral_vector


@dataclass(frozen=True)
class EffectRequest:
    name: str
    values: dict[str, float] = field(default_factory=dict)
    form: str | None = None  # one of the effect's forms; None = the default form

    def label(self) -> str:
        kv = ",".join([f"form={self.form}"] * bool(self.form) + [f"{k}={v:g}" for k, v in self.values.items()])
        return f"{self.name}:{kv}" if kv else self.name


def parse_effect(text: str, source: str = "--effect") -> EffectRequest:
    """Parse ``NAME[:form=FORM,key=val,...]``; unknown names, forms and malformed values are InputErrors."""
    name, _, rest = text.partition(":")
    name = name.strip()
    if name not in CATALOG:
        raise InputError(source, name or "(name)", f"unknown effect (catalog: {', '.join(CATALOG)})")
    values: dict[str, float] = {}
    form = None
    if rest.strip():
        for item in rest.split(","):
            key, eq, val = item.partition("=")
            key = key.strip()
            if not eq:
                raise InputError(source, f"{name}.{key}", "expected key=value")
            if key == "form":
                form = check_form(name, val.strip(), source)
                continue
            try:
                values[key] = float(val)
            except ValueError:
                raise InputError(source, f"{name}.{key}", f"not a number: {val!r}") from None
    return EffectRequest(name, values, form)


def infer_form(name: str, keys: set[str], source: str) -> str | None:
    """The form whose parameters the keys name: the default if it has them all, else the one other form that does."""
    spec = CATALOG[name]
    if not keys or keys <= {ps.key for plist in spec.params.values() for ps in plist}:
        return None
    fits = [f for f, fs in spec.forms.items() if keys <= {ps.key for plist in fs.params.values() for ps in plist}]
    return fits[0] if len(fits) == 1 else None


def check_form(name: str, form: str | None, source: str) -> str | None:
    """The form name if the effect has it (None or the default form: None); else an InputError."""
    spec = CATALOG[name]
    if not form or form == spec.default_form:
        return None
    if form not in spec.forms:
        have = ", ".join(f for f in spec.form_names() if f) or "only its default form"
        raise InputError(source, f"{name}.form", f"unknown form {form!r} (has {have})")
    return form


def environment_vector(cfg: RigConfig) -> np.ndarray:
    """Neutral effects plus the rig's contact environment."""
    e = neutral_vector()
    c = cfg.contact
    env = {
        "v_stick": c.v_stick_m_per_s,
        "t_ambient": c.t_ambient_C,
        "r_thermal": c.r_thermal_K_per_W,
        "tau_thermal": c.tau_thermal_s,
        "ambient_drift": c.ambient_drift_K_per_s,
        "force_rate_tau": c.force_rate_tau_s,
        "stick_reset_tau": c.stick_reset_tau_s,
    }
    for key, slot in ENVIRONMENT_SLOTS.items():
        e[slot] = env[key]
    # the temperature effect's reference defaults to the rig's ambient temperature
    e[E.TEMP_REF] = c.t_ambient_C
    return e


def apply_effect(e: np.ndarray, rig: str, name: str, values: dict[str, float], source: str,
                 form: str | None = None) -> None:
    spec = CATALOG[name]
    if rig not in spec.rigs:
        raise InputError(source, name, f"does not apply to {rig} (applies to {', '.join(spec.rigs)})")
    if form is None:
        form = infer_form(name, set(values), source)
    params = {ps.key: ps for ps in spec.params_for(rig, form)}
    for key, val in values.items():
        ps = params.get(key)
        if ps is None:
            raise InputError(source, f"{name}.{key}", f"unknown parameter (has {', '.join(params)})")
        if not (ps.lo <= val <= ps.hi):
            raise InputError(source, f"{name}.{key}", f"{val:g} outside [{ps.lo:g}, {ps.hi:g}] {ps.unit}")
        e[ps.slot] = val


def effect_vector(cfg: RigConfig, requests: list[EffectRequest] = (), seed: bool = True,
                  source: str = "--effect") -> tuple[np.ndarray, dict[str, dict[str, float]]]:
    """The rig's seed effects (if ``seed``) plus the requested ones; returns (e, active effects).

    A request without keys takes the rig config's ``[effects]`` (or ``[seed_effects]``) magnitudes.
    """
    e = environment_vector(cfg)
    active: dict[str, dict[str, float]] = {}
    if seed:
        for name, vals in cfg.seed_effects.items():
            apply_effect(e, cfg.rig, name, vals, f"rig config {cfg.rig}")
            active[name] = dict(vals)
    for req in requests:
        spec = CATALOG[req.name]
        if cfg.rig not in spec.rigs:
            raise InputError(source, req.name, f"does not apply to {cfg.rig} (applies to {', '.join(spec.rigs)})")
        vals = dict(req.values)
        if not vals and req.form is None:
            vals = dict(cfg.effects.get(req.name) or cfg.seed_effects.get(req.name) or {})
        if not vals and (req.form is not None or not spec.forms) and spec.params_for(cfg.rig, req.form):
            raise InputError(source, req.name, f"no default magnitude on {cfg.rig}; give key=value")
        form = req.form if req.form is not None else infer_form(req.name, set(vals), source)
        apply_effect(e, cfg.rig, req.name, vals, source, form)
        active[req.name] = {**active.get(req.name, {}), **vals, **({"form": form} if form else {})}
    return e, active
