"""A model file's parameter values -> the compiled physics (the same SimRig the simulator uses).

Why through the simulator's rig adapters: a model *is* the rig's physics with a
chosen law and effects; building it from a rig config with overridden values and
an effect vector means the model and the simulated rig cannot drift apart.

Decision record: docs/decisions/0001-physics-in-one-place.md.
"""

from __future__ import annotations

import numpy as np

from daq.config import RigConfig
from daq.errors import InputError
from daq.physics.catalog import CATALOG
from daq.sim.effectset import environment_vector
from daq.sim.rigs import SimRig, make_sim

from ..spec import Model, rig_config_for
from ..user_effects import load_user_effect


class Builder:
    """Turns parameter values (by full name) into a SimRig, quickly enough to call in a fit loop."""

    def __init__(self, model: Model, source: str = "model") -> None:
        self.model = model
        self.source = source
        self.cfg: RigConfig = rig_config_for(model, source)
        self.names = list(model.params())
        self.base_values = {k: p.value for k, p in model.params().items()}
        self.user = None
        user = {n: eff for n, eff in model.effects.items() if eff.path is not None}
        if len(user) > 1:
            raise InputError(source, "effects", "at most one user effect per model (for now)")
        if user:

            name, eff = next(iter(user.items()))
            self.user = load_user_effect(eff.path, name)

    def config(self, values: dict[str, float]) -> RigConfig:
        """The rig config with the model's friction/mechanics values in place."""
        upd: dict[str, dict[str, float]] = {"friction": {}, "mechanics": {}}
        for k, v in values.items():
            sec, _, key = k.partition(".")
            if sec in upd:
                upd[sec][key] = float(v)
        cfg = self.cfg
        new = {}
        for sec, vals in upd.items():
            if vals:
                new[sec] = getattr(cfg, sec).model_copy(update=vals)
        return cfg.model_copy(update=new) if new else cfg

    def effect_vector(self, values: dict[str, float]) -> np.ndarray:
        e = environment_vector(self.cfg)
        for name, eff in self.model.effects.items():
            spec = CATALOG.get(name)
            if spec is None or eff.path is not None:
                continue  # user effect
            for ps in spec.params_for(self.cfg.rig, eff.form):
                key = f"effects.{name}.{ps.key}"
                if key in values:
                    e[ps.slot] = values[key]
        return e

    def sim(self, values: dict[str, float] | None = None) -> SimRig:
        vals = dict(self.base_values)
        if values:
            vals.update(values)
        cfg = self.config(vals)
        e = self.effect_vector(vals)
        sim = make_sim(cfg, e)
        if self.user is not None:
            self.user.bind(sim, vals)
        return sim
