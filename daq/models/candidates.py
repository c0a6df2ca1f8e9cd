"""What a diagnosis can add to a model: a catalog effect in one of its forms, or a mechanics parameter set free.

Why mechanics too: a rig is never exactly its config. A spring a few per cent stiffer than the
config shifts every stick-slip cycle, and some catalog effect would partly mimic it; offering
"free k1" beside the effects lets the data say which it is, and names it as such.

A candidate applied to a model gives the extended model at its *neutral* point: the effect's
strength at its neutral value, or the mechanics parameter at the config's value. The extended
model is then exactly the model it extends, so its fit can start there and only improve.

Decision record: docs/decisions/0015-diagnosis-forward-selection.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from daq.physics.catalog import CATALOG

from .spec import Model, Param, add_effect, effect_label, rig_config_for, strength_key

# mechanics parameters a diagnosis may set free, per rig: the stiffnesses and inertias that set the
# cycle (lengths and g are geometry a lab measures well); bounds +-MECH_SPAN around the config value
MECHANICS: dict[str, tuple[str, ...]] = {
    "brake-2dof": ("k1_N_per_m", "k2_N_per_m", "k3_N_per_m", "m_kg", "J_kg_m2"),
    "drum-pendulum": ("k_N_per_m", "I0_kg_m2"),
    "belt-ndof": (),
}
MECH_SPAN = 0.3


@dataclass(frozen=True)
class Candidate:
    """One thing a diagnosis may add: ``kind`` "effect" (``name``, ``form``) or "mechanics" (``name`` = field)."""

    kind: str
    name: str
    form: str | None = None

    @property
    def label(self) -> str:
        """How reports name it: ``stick-time (log)``, ``mechanics.k1_N_per_m``."""
        return f"mechanics.{self.name}" if self.kind == "mechanics" else effect_label(self.name, self.form)

    @property
    def phenomenon(self) -> str:
        """The effect's name (forms of one phenomenon share it) or the mechanics parameter's full name."""
        return f"mechanics.{self.name}" if self.kind == "mechanics" else self.name

    def apply(self, model: Model, source: str = "diagnose") -> Model:
        """The model extended by this candidate, at its neutral point."""
        if self.kind == "effect":
            return add_effect(model, self.name, source, form=self.form)
        return free_mechanics(model, self.name, source)

    def strength(self, model: Model) -> str | None:
        """Full name of the parameter that switches the candidate on (None: a structural switch)."""
        if self.kind == "mechanics":
            return f"mechanics.{self.name}"
        key = strength_key(model.rig, self.name, self.form)
        return f"effects.{self.name}.{key}" if key else None


def free_mechanics(model: Model, name: str, source: str = "model add") -> Model:
    """The model with one mechanics parameter free (starting at the config's value, +-MECH_SPAN)."""
    cfg = rig_config_for(model, source)
    value = float(getattr(cfg.mechanics, name))
    m = model.model_copy(deep=True)
    old = m.mechanics.get(name)
    start = old.value if old is not None else value
    m.mechanics[name] = Param(value=start, free=True, lo=value * (1.0 - MECH_SPAN), hi=value * (1.0 + MECH_SPAN))
    return m


def candidates_for(model: Model, mechanics: bool = True) -> list[Candidate]:
    """Every catalog effect (each form) that applies to the model's rig and is not in it, and every
    mechanics parameter of MECHANICS not yet free."""
    out = []
    for name, spec in CATALOG.items():
        if model.rig not in spec.rigs or name in model.effects:
            continue
        for form in spec.form_names():
            if spec.form_applies(model.rig, form or None):
                out.append(Candidate("effect", name, form or None))
    if mechanics:
        free = set(model.free_names())
        out += [Candidate("mechanics", k) for k in MECHANICS.get(model.rig, ()) if f"mechanics.{k}" not in free]
    return out


def add_command(c: Candidate) -> str:
    """The `daq model add` arguments that add a candidate."""
    if c.kind == "mechanics":
        return f"mechanics.{c.name}"
    return f"{c.name} --form {c.form}" if c.form else c.name


def parse_candidate(text: str) -> Candidate:
    """``mechanics.FIELD`` or ``EFFECT`` or ``EFFECT:FORM`` (as diagnose prints them for `daq model add`)."""
    if text.startswith("mechanics."):
        return Candidate("mechanics", text.split(".", 1)[1])
    name, _, form = text.partition(":")
    return Candidate("effect", name, form or None)
