"""A user effect: the friction coefficient falls as the belt wears (per metre of belt travel).

Use it from a model file without touching the package:

    daq model add model.toml docs/examples/belt_wear.py      # adds [effects.belt_wear] with path = ...
    daq diagnose run.h5 --model model.toml                   # fits k with the other free parameters
"""

from daq.models.user_effects import UserParam

PARAMS = {
    "k": UserParam(start=0.0, lo=-0.2, hi=0.2, unit="1/m",
                   doc="relative change of the friction coefficient per metre of belt travel"),
}


def mu_factor(v_rel, t, temp, travel, stick_clock, p0, p1, p2, p3):
    """Multiplies the friction coefficient; p0 is k (PARAMS in order)."""
    return 1.0 - p0 * travel
