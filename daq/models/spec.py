"""Model files: a rig's mechanics, a friction law and a list of named effects, each parameter fixed or free.

Why a file: a researcher revises a model many times (add an effect, free a
parameter, refit) and wants each revision on disk, diffable, and reloadable.
The file names parameters the way the rig config does; anything not named is
taken from the rig config, so a model file holds only what the model decides.

    rig = "brake-2dof"
    law = "brake-eq7"
    [friction]
    mu0 = { value = 0.5, free = true, lo = 0.05, hi = 2.0 }
    alpha_s_per_m = 200.0                      # a bare number is fixed
    [effects.normal-load]
    weight = 1.0
    [effects.my-wear]                          # a user effect, from a Python file
    path = "my_wear.py"
    k = { value = 0.0, free = true, lo = -1.0, hi = 1.0 }
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from daq.config import RigConfig, load_rig, user_rig_file
from daq.errors import InputError, parse_toml, read_text
from daq.io.files import atomic_path
from daq.physics.catalog import CATALOG
from daq.strict import Closed


SECTIONS = ("friction", "mechanics")


class Param(Closed):
    """One model parameter. ``std`` is written by ``daq fit`` (1-sigma, from the fit's Jacobian)."""

    value: float
    free: bool = False
    lo: float | None = None
    hi: float | None = None
    std: float | None = None

    @model_validator(mode="after")
    def _bounds(self) -> "Param":
        if self.lo is not None and self.hi is not None and not self.lo < self.hi:
            raise ValueError(f"lo ({self.lo:g}) must be below hi ({self.hi:g})")
        if self.lo is not None and self.value < self.lo or self.hi is not None and self.value > self.hi:
            raise ValueError(f"value {self.value:g} outside [{self.lo}, {self.hi}]")
        return self


class Effect(Closed):
    """An effect in the model: catalog name (or a user effect with ``path``), its form and its parameters."""

    path: str | None = None
    form: str | None = None  # one of the catalog effect's forms; None = its default form
    params: dict[str, Param] = Field(default_factory=dict)


class FitInfo(BaseModel):
    """What the last fit saw (written by ``daq fit``)."""

    model_config = ConfigDict(extra="allow")
    data: str = ""
    error: float | None = None
    error_unit: str = ""
    cost: float | None = None


class Model(Closed):
    rig: str
    law: str
    title: str = ""
    rig_config: str | None = Field(None, description="path to a rig TOML (default: the built-in rig)")
    friction: dict[str, Param] = Field(default_factory=dict)
    mechanics: dict[str, Param] = Field(default_factory=dict)
    effects: dict[str, Effect] = Field(default_factory=dict)
    fit: FitInfo | None = None

    def params(self) -> dict[str, Param]:
        """Every parameter by its full name: ``friction.mu0``, ``effects.stick-time.gain``."""
        out = {f"friction.{k}": v for k, v in self.friction.items()}
        out.update({f"mechanics.{k}": v for k, v in self.mechanics.items()})
        for name, eff in self.effects.items():
            out.update({f"effects.{name}.{k}": v for k, v in eff.params.items()})
        return out

    def free_names(self) -> list[str]:
        return [k for k, v in self.params().items() if v.free]

    def with_values(self, values: dict[str, float], stds: dict[str, float] | None = None) -> "Model":
        """A copy with parameter values (and optionally their uncertainties) replaced."""
        m = self.model_copy(deep=True)
        allp = m.params()
        for k, v in values.items():
            allp[k].value = float(v)
            if stds is not None and k in stds:
                allp[k].std = float(stds[k])
        return m

    def with_fixed(self) -> "Model":
        """A copy with every parameter fixed at its value: the model as its file states it (`compare --predict`)."""
        m = self.model_copy(deep=True)
        for par in m.params().values():
            par.free = False
        return m

    def digest(self) -> str:
        """Short hash of the model's structure and values (identifies a revision in the history)."""
        return hashlib.sha256(dumps(self).encode()).hexdigest()[:10]

    def describe(self) -> str:
        return f"{self.rig} / {self.law} + " + (", ".join(effect_label(n, e.form) for n, e in self.effects.items())
                                                 or "no effects")


def effect_label(name: str, form: str | None) -> str:
    """``name`` or ``name (form)``: how a report names an effect in one of its other forms."""
    return f"{name} ({form})" if form else name


# ----------------------------------------------------------------------------- TOML in and out


def _param(raw: Any, where: str, source: str) -> Param:
    try:
        if isinstance(raw, (int, float)) and not isinstance(raw, bool):
            return Param(value=float(raw))
        if isinstance(raw, dict):
            return Param.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(x) for x in err["loc"])
        raise InputError(source, f"{where}{'.' + loc if loc else ''}", err["msg"].removeprefix("Value error, ")) \
            from None
    raise InputError(source, where, "expected a number or { value = ..., free = ..., lo = ..., hi = ... }")


def parse_model(data: dict[str, Any], source: str) -> Model:
    """Validate a model mapping; one InputError naming the file and the first bad field."""
    for key in ("rig", "law"):
        if not isinstance(data.get(key), str):
            raise InputError(source, key, "required (a string)")
    known = {"rig", "law", "title", "rig_config", "friction", "mechanics", "effects", "fit"}
    for key in data:
        if key not in known:
            raise InputError(source, key, f"unknown key (expected {', '.join(sorted(known))})")
    out: dict[str, Any] = {k: data[k] for k in ("rig", "law", "title", "rig_config") if k in data}
    for sec in SECTIONS:
        raw = data.get(sec, {})
        if not isinstance(raw, dict):
            raise InputError(source, sec, "must be a table")
        out[sec] = {k: _param(v, f"{sec}.{k}", source) for k, v in raw.items()}
    effects: dict[str, Effect] = {}
    raw_eff = data.get("effects", {})
    if not isinstance(raw_eff, dict):
        raise InputError(source, "effects", "must be a table of effects")
    for name, body in raw_eff.items():
        if not isinstance(body, dict):
            raise InputError(source, f"effects.{name}", "must be a table (parameters, optional path)")
        path = body.get("path")
        if path is not None and not isinstance(path, str):
            raise InputError(source, f"effects.{name}.path", "must be a string")
        form = body.get("form")
        if form is not None and not isinstance(form, str):
            raise InputError(source, f"effects.{name}.form", "must be a string (one of the effect's forms)")
        params = {k: _param(v, f"effects.{name}.{k}", source) for k, v in body.items() if k not in ("path", "form")}
        effects[name] = Effect(path=path, form=form, params=params)
    out["effects"] = effects
    if "fit" in data:
        out["fit"] = FitInfo.model_validate(data["fit"])
    model = Model.model_validate(out)
    check_model(model, source)
    return model


def check_model(model: Model, source: str) -> None:
    """Names must exist: the rig's config fields, catalog effects and their parameters."""
    cfg = rig_config_for(model, source)
    if model.law != cfg.friction.law:
        raise InputError(source, "law", f"the {model.rig} rig has law {cfg.friction.law!r}, not {model.law!r}")
    for sec in SECTIONS:
        fields = getattr(cfg, sec).model_dump()
        for k in getattr(model, sec):
            if k not in fields or k == "law" or not isinstance(fields[k], (int, float)):
                raise InputError(source, f"{sec}.{k}", f"not a numeric {sec} parameter of {model.rig} "
                                 f"(has {', '.join(n for n, v in fields.items() if isinstance(v, (int, float)))})")
    for name, eff in model.effects.items():
        if eff.path is not None:
            continue  # a user effect: checked when its file is loaded
        spec = CATALOG.get(name)
        if spec is None:
            raise InputError(source, f"effects.{name}", f"unknown effect (catalog: {', '.join(CATALOG)}; "
                             "a user effect needs path = \"file.py\")")
        if model.rig not in spec.rigs:
            raise InputError(source, f"effects.{name}", f"does not apply to {model.rig}")
        if eff.form is not None and eff.form != spec.default_form and eff.form not in spec.forms:
            have = ", ".join(f for f in spec.form_names() if f) or "only its default form"
            raise InputError(source, f"effects.{name}.form", f"unknown form {eff.form!r} (has {have})")
        keys = {ps.key for ps in spec.params_for(model.rig, eff.form)}
        for k in eff.params:
            if k not in keys:
                raise InputError(source, f"effects.{name}.{k}", f"unknown parameter (has {', '.join(sorted(keys))})")


def rig_config_for(model: Model, source: str = "model") -> RigConfig:
    """The config of the model's rig (its ``rig_config`` file, else the built-in rig); an unknown rig or an
    unreadable/invalid rig file is one InputError naming the model file first, then the rig's problem."""
    name = model.rig_config or model.rig
    try:
        cfg = load_rig(name)
    except InputError as exc:
        field = "rig_config" if model.rig_config else "rig"
        said = f"{name!r}: {exc.message}" if exc.source == str(name) and exc.field in ("rig", "(file)") else str(exc)
        raise InputError(source, field, said) from None
    if cfg.rig != model.rig:
        raise InputError(source, "rig_config", f"is a {cfg.rig} config, the model is for {model.rig}")
    return cfg


def load_model(path: str | Path) -> Model:
    p = Path(path)
    model = parse_model(parse_toml(read_text(p), str(p)), str(p))
    # user effect paths are relative to the model file
    for eff in model.effects.values():
        if eff.path is not None and not Path(eff.path).is_absolute():
            eff.path = str((p.parent / eff.path).resolve())
    return model


def _scalar(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v))
    return json.dumps(str(v))  # a TOML basic string accepts JSON's escapes


def _param_toml(p: Param) -> str:
    if not p.free and p.lo is None and p.hi is None and p.std is None:
        return _scalar(p.value)
    parts = [f"value = {_scalar(p.value)}"]
    if p.free:
        parts.append("free = true")
    for k in ("lo", "hi", "std"):
        v = getattr(p, k)
        if v is not None:
            parts.append(f"{k} = {_scalar(v)}")
    return "{ " + ", ".join(parts) + " }"


def dumps(model: Model) -> str:
    """TOML with one line per parameter (inline tables), the way a person would write it."""
    lines = [f"rig = {_scalar(model.rig)}", f"law = {_scalar(model.law)}"]
    if model.title:
        lines.append(f"title = {_scalar(model.title)}")
    if model.rig_config:
        lines.append(f"rig_config = {_scalar(model.rig_config)}")
    for sec in SECTIONS:
        if getattr(model, sec):
            lines += ["", f"[{sec}]"] + [f"{k} = {_param_toml(v)}" for k, v in getattr(model, sec).items()]
    for name, eff in model.effects.items():
        lines += ["", f"[effects.{name}]"]
        if eff.path:
            lines.append(f"path = {_scalar(eff.path)}")
        if eff.form:
            lines.append(f"form = {_scalar(eff.form)}")
        lines += [f"{k} = {_param_toml(v)}" for k, v in eff.params.items()]
    if model.fit is not None:
        lines += ["", "[fit]"] + [f"{k} = {_scalar(v)}" for k, v in model.fit.model_dump(exclude_none=True).items()]
    return "\n".join(lines) + "\n"


def save_model(model: Model, path: str | Path) -> None:

    with atomic_path(path) as tmp:
        Path(tmp).write_text(dumps(model))


# ----------------------------------------------------------------------------- init / add / remove

# Which law parameters the seed models leave free, with bounds (the rest stay at the paper's values).
FREE_LAW: dict[str, dict[str, tuple[float, float]]] = {
    "brake-2dof": {"mu0": (0.05, 2.0), "gamma_s_per_m": (0.0, 30.0), "beta": (0.0, 0.98)},
    "drum-pendulum": {"A": (0.0, 2.0), "E": (0.0, 1.0)},
    "belt-ndof": {"f_s0": (0.05, 5.0), "f_k0": (0.05, 5.0), "k_fall": (0.0, 5.0)},
}

# Start values of an added effect's free parameters other than its strength (the strength, the first
# parameter of every catalog effect, starts at its neutral value: the extended model starts exactly
# where the model without it is; see STRENGTH_START for the second start a fit also tries). Keyed by
# effect name, or "name/form" for another form. FIXED keys stay at the given value and are not fitted.
START: dict[str, dict[str, float]] = {
    "normal-load": {"weight": 1.0},
    "geometric": {"weight": 1.0},
    "stick-time": {"tau": 0.5},
    "stick-time/log": {"tau": 0.05, "dc": 1e-3},
    "accel-sign/body": {"a0": 1.0},
    "force-rate": {"q0": 1.0},
    "belt-speed/lag-ripple": {"ripple": 0.0},
    "rate-and-state": {"dc": 1e-4},  # a and b start at 0: the state there but without effect (decision 32)
    "rate-and-state/slip": {"dc": 1e-4},
}
# A second start for the strength (generic magnitudes, deliberately not the simulator's hidden ones):
# where an effect's error surface is flat at neutral (a symmetric term), the fit starts here too.
STRENGTH_START: dict[str, float] = {
    "accel-sign": 0.05, "accel-sign/body": 0.05, "stick-time": 0.2, "stick-time/log": 0.1, "force-rate": 0.1,
    "bearing-friction": 0.001, "temperature": -0.005, "temperature/arrhenius": 300.0, "velocity-strengthening": 0.1,
    "viscous-damping": 0.01, "belt-speed/lag-ripple": 0.1, "rate-and-state": 0.01, "rate-and-state/slip": 0.01,
}
# A second start of an added effect's scale parameter beside START's, tried with the moved strength (a fit's own
# starts, session._starts). Why: Dieterich's Dc spans decades and its cost has a second, shallower basin at small Dc
# (the stick clock reset by any slip): on a brake record whose static peak ages on a creep clock (100 Hz, refsim's
# stick-creep), the fit from Dc = 1 mm ended at 0.16 mm, 35 % of the excess, against 97 % from 5 mm (decision 50).
SECOND_START: dict[str, dict[str, float]] = {"stick-time/log": {"dc": 5e-3}}
FIXED: dict[str, set[str]] = {
    "normal-load": {"weight"},  # structural: the load is followed, or it is not
    "geometric": {"weight"},
    "temperature": {"ref"},  # degenerate with the law's own level; set to the rig's ambient
    "temperature/arrhenius": {"ref"},
    "force-rate": {"q0"},  # gain ln(1 + q/q0) ~ gain ln q - gain ln q0: q0 trades off against the peak
    "belt-speed/lag-ripple": {"ripple", "wavelength"},  # the lag is fitted; a ripple's wavelength is not found by LM
    "rate-and-state": {"v_ref"},  # a ln v_ref trades off against f_k0
    "rate-and-state/slip": {"v_ref"},
}


# A fit's lower bound above the catalog's where the catalog's bound switches the effect's structure off: Dc = 0 is
# "no contact state" (and RK4 instead of ROS2), which a fit must not step onto.
FIT_LO: dict[str, dict[str, float]] = {"rate-and-state": {"dc": 1e-7}, "rate-and-state/slip": {"dc": 1e-7}}


def form_key(name: str, form: str | None) -> str:
    return f"{name}/{form}" if form else name


def strength_key(rig: str, name: str, form: str | None = None) -> str | None:
    """The parameter that switches a catalog effect on (its first), or None (no parameters)."""
    plist = CATALOG[name].params_for(rig, form)
    return plist[0].key if plist else None


def effect_params(rig: str, name: str, cfg: RigConfig, form: str | None = None) -> dict[str, Param]:
    """The parameters an effect brings when added to a model: free within the catalog bounds, the strength
    at its neutral value (the model with the effect added is exactly the model without it)."""
    params: dict[str, Param] = {}
    key = form_key(name, form)
    for ps in CATALOG[name].params_for(rig, form):
        value = START.get(key, {}).get(ps.key, ps.neutral)
        if ps.key == "ref" and name == "temperature":
            value = cfg.contact.t_ambient_C
        if ps.key in FIXED.get(key, set()):
            params[ps.key] = Param(value=value)
        else:
            params[ps.key] = Param(value=value, free=True, lo=FIT_LO.get(key, {}).get(ps.key, ps.lo), hi=ps.hi)
    return params


def seed_model(rig: str) -> Model:
    """The seed model of a rig: its paper's equations (the rig config's seed effects), law partly free."""
    cfg = load_rig(rig)
    friction: dict[str, Param] = {}
    for k, v in cfg.friction.model_dump().items():
        if k == "law":
            continue
        if k in FREE_LAW.get(cfg.rig, {}):
            lo, hi = FREE_LAW[cfg.rig][k]
            friction[k] = Param(value=float(v), free=True, lo=lo, hi=hi)
        else:
            friction[k] = Param(value=float(v))
    effects: dict[str, Effect] = {}
    for name, vals in cfg.seed_effects.items():
        params = effect_params(cfg.rig, name, cfg)
        for k, v in vals.items():
            params[k] = params[k].model_copy(update={"value": float(v)})
        effects[name] = Effect(params=params)
    seeds = {"brake-2dof": "paper 001 eqs. 5-7", "drum-pendulum": "paper 002 eqs. 1-3",
             "belt-ndof": "paper 000 eqs. 1-5"}
    # a user's rig file (a path, not a built-in id) travels with the model: its masses and springs are the rig's
    return Model(rig=cfg.rig, law=cfg.friction.law, title=f"seed model of {cfg.rig} ({seeds.get(cfg.rig, '')})",
                 rig_config=user_rig_file(rig), friction=friction, effects=effects)


def like_model(model: Model, rig: str, source: str = "model init --like") -> tuple[Model, list[str]]:
    """A model for another rig file of the same rig (``rig``: an id or a user's rig file) that keeps ``model``'s
    friction law, effects, forms and fitted values and takes the mechanics the new rig file states; where ``model``
    holds a mechanics value other than its own rig file's (a diagnosis found the rig is not its file), that value's
    ratio to its rig file's is carried onto the new file's, as a correction. Returns the model and one line per
    correction carried. One InputError for what cannot carry: another rig kind, a chain of other masses, a
    channel the model predicts that the new rig does not record.

    Why a ratio, not the value: what a lab changes between records is the spring or the drive; a mass or spring
    found off its file is off by the same factor in the next file of the same rig (a miscalibrated gauge, a slider
    heavier than weighed), not by the same newtons."""
    old_cfg, new_cfg = rig_config_for(model, source), load_rig(rig)
    if new_cfg.rig != model.rig:
        raise InputError(source, "rig", f"{rig} is a {new_cfg.rig} rig; the model is for {model.rig}: it cannot carry")
    for what in ("n_masses", "driven"):
        old, new = getattr(old_cfg.mechanics, what, None), getattr(new_cfg.mechanics, what, None)
        if old != new:
            raise InputError(source, f"mechanics.{what}", f"{rig} has {new}, the model's rig {old}: it cannot carry")
    missing = sorted(set(old_cfg.channels) - set(new_cfg.channels))
    if missing:
        raise InputError(source, "channels", f"{rig} records no {', '.join(missing)}, which the model reads")
    m = model.model_copy(deep=True)
    m.rig_config = user_rig_file(rig)
    m.fit = None
    said = []
    for k, par in model.mechanics.items():
        was = float(getattr(old_cfg.mechanics, k))
        now = float(getattr(new_cfg.mechanics, k))
        ratio = par.value / was if was else 1.0
        scale = now / was if was else 1.0
        m.mechanics[k] = par.model_copy(update={"value": ratio * now, "lo": None if par.lo is None else par.lo * scale,
                                                "hi": None if par.hi is None else par.hi * scale})
        if ratio != 1.0:
            said.append(f"mechanics.{k} = {ratio * now:.6g}: {ratio:.4g} x the rig file's {now:.6g}, as the model "
                        f"found on its own rig")
    m.title = f"{model.title or model.describe()}, carried to {Path(rig).name}"
    return m, said


def add_effect(model: Model, name: str, source: str = "model add", path: str | None = None,
               form: str | None = None) -> Model:
    """The model with one more effect (catalog name in one of its forms, or a user effect file)."""
    if name in model.effects:
        raise InputError(source, name, "the model already has this effect")
    m = model.model_copy(deep=True)
    if path is not None:
        # here, not at the top: loading a user's term compiles it (numba, scipy through the rigs), 1.6 s of CPU that
        # every `daq model init` and every model file read paid (python -X importtime, 2026-11-28)
        from .user_effects import load_user_effect

        ue = load_user_effect(path)
        m.effects[name] = Effect(path=str(path), params={k: Param(value=p.start, free=True, lo=p.lo, hi=p.hi)
                                                          for k, p in ue.params.items()})
        return m
    spec = CATALOG.get(name)
    if spec is None:
        raise InputError(source, name, f"unknown effect (catalog: {', '.join(CATALOG)})")
    if model.rig not in spec.rigs:
        raise InputError(source, name, f"does not apply to {model.rig} (applies to {', '.join(spec.rigs)})")
    if form is not None and form == spec.default_form:
        form = None
    if form is not None and form not in spec.forms:
        have = ", ".join(f for f in spec.form_names() if f) or "only its default form"
        raise InputError(source, f"{name} --form", f"unknown form {form!r} (has {have})")
    m.effects[name] = Effect(form=form, params=effect_params(model.rig, name, rig_config_for(model, source), form))
    return m


def remove_effect(model: Model, name: str, source: str = "model remove") -> Model:
    if name not in model.effects:
        raise InputError(source, name, f"the model has no such effect (has: {', '.join(model.effects) or 'none'})")
    m = model.model_copy(deep=True)
    del m.effects[name]
    return m


def drive_source(model: Model) -> Literal["command", "measured"]:
    """belt-speed in its default form means: drive the model with the measured belt speed, not the command."""
    eff = model.effects.get("belt-speed")
    return "measured" if eff is not None and eff.form is None and eff.path is None else "command"
