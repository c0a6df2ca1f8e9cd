"""Rig parameters, the drive programme, and the hidden effects in *other* published forms.

Nothing here comes from ``daq``: the rig config TOML files are read as plain data
with :mod:`tomllib`, and every effect is written in a form that differs from the
catalog's (``daq/physics/effects.py``) on purpose, so that a diagnosis tuned to the
catalog's own forms is tested on data it was not written for.

Effect specs are strings ``name[:key=value,...]`` (as on ``make.py``'s command
line). Every effect has one or more *magnitude* keys; with all of them at 0 the
right-hand side is exactly (bit for bit) the base model, because each term is a
factor ``1 + 0*x`` or an addend ``0*x`` (the tests check it). The effects' own
states (Dieterich state, load-rate memory, filtered acceleration, drive states,
belt travel, contact temperature) are integrated always, whether an effect reads
them or not, so that the adaptive step sequence does not depend on which effects
are listed.

Forms (brake-2dof / drum-pendulum; belt-ndof has stick-log, accel-body and force-rate-pow, written for
its hybrid chain in belt.py), with what our catalog uses instead:

``stick-log`` (phenomenon stick-time)
    Dieterich's logarithmic aging: static peak x (1 + b ln(1 + theta_s/theta)), where
    theta_s is Dieterich's state variable with the *aging law*
    d theta_s/dt = 1 - |V_rel| theta_s / Dc: it grows like the time in contact while
    the contact creeps and is wiped out by a slip of a few Dc. Keys: b (magnitude),
    theta [s], Dc [m]. Catalog: saturating 1 + g(1 - exp(-t/tau)) of a stick clock.
``stick-creep`` (phenomenon stick-time)
    the same logarithmic growth of the static peak, 1 + b ln(1 + t_c/theta), on a *creep clock*
    t_c: it runs while the contact creeps, at the rate of a Lorentzian creep indicator
    phi = 1/(1 + (V/v_c)^2), and is wiped out over a slip distance L_r once the contact slides,
    d t_c/dt = phi - (1 - phi) |V| t_c / L_r. The clock shares the Dieterich state's slot (one
    stick-time form at a time: stick-log and stick-creep together are refused). Keys: b
    (magnitude), theta [s], v_c [m/s], L_r [m]. Catalog: a Gaussian stick clock that decays in
    time (saturating or log growth), or Dieterich's state (log).
``accel-body`` (accel-sign)
    kinetic friction higher while the *body* accelerates (paper 000's wording):
    mu x (1 + amp tanh(a_f/a0)), a_f the body's acceleration along the sliding
    direction (brake: x1'', drum: R phi''), either sign of amp. The algebraic loop
    (friction depends on the acceleration it causes) is cut by a first-order filter
    tau_a a_f' = a - a_f (a sensor-like 2 ms lag; documented choice). Keys: amp
    (magnitude), a0 [m/s^2], tau_a [s]. Catalog: keyed to d|V_rel|/dt, Filippov branch.
``arrhenius`` (temperature)
    mu x exp(E (1/T - 1/T_ref)), T in kelvin, E an activation temperature [K]; the
    contact temperature follows our own thermal model (below) and is the ``temp``
    channel. Keys: E (magnitude), T_ref_C (default: ambient). Catalog: 1 + c (T - T_ref).
``belt-drive`` (belt-speed)
    the drive follows the command through a *second-order* lag (speed regulator,
    natural period 2 pi tau, damping zeta) and carries a ripple periodic in belt
    travel, relative to the speed, with a second harmonic:
    v = v_lag (1 + ripple (sin(2 pi s/lam) + h2 sin(4 pi s/lam + 1))).
    Keys: tau [s], ripple (magnitudes), wavelength [m] (drum: drum angle [rad]),
    zeta, h2. Catalog: first-order lag, pure sine.
``force-rate-pow`` (force-rate)
    static peak x (1 + g (|q|/q0)^n), q the rate of the tangential spring load on the
    contact remembered during stick (tracked while stuck, Lorentzian stuck indicator
    1/(1 + (V/v_c)^2), held while slipping). Keys: g (magnitude), q0 [N/s], n, tau_q [s].
    Catalog: 1 + g ln(1 + |q|/q0), Gaussian indicator.
``vel-strength`` (velocity-strengthening): mu += D V_rel. Key: D [s/m].
``bearing`` (bearing-friction): Coulomb torque at the pivot (brake: torque [N m]) or in
    the drum bearing (drum: mu1, on the bearing thrust Z of paper 002 eq. 1 row 1),
    smoothed as (2/pi) arctan(phi'/eps) (catalog: tanh). Keys: torque | mu1, eps [rad/s].
``waviness`` (OFF-CATALOG): surface waviness periodic in belt travel,
    mu x (1 + w sin(2 pi s/wavelength)). Keys: w (magnitude), wavelength [m].
``stiffness`` (a rig that is not its config): relative offsets of the springs,
    brake: k1, k2, k3; drum: k (e.g. ``stiffness:k1=0.04`` = k1 4 % stiffer).

Thermal model (ours, not the catalog's): a lumped contact node of heat capacity
C = tau_thermal / r_thermal takes the share ``eta`` (Blok partition, 0.5) of the
frictional power |F V_rel| and loses heat to ambient through r_thermal:
C dT/dt = eta |F V_rel| - (T - T_amb)/r_thermal, T in kelvin.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RIG_DIR = ROOT / "rig_configs"
KELVIN = 273.15

# What each reference effect is an instance of (for the recovery table): a catalog
# phenomenon, a mechanics parameter, or None (nothing in the catalog: must not be claimed).
PHENOMENON = {
    "stick-log": "stick-time",
    "stick-creep": "stick-time",
    "accel-body": "accel-sign",
    "arrhenius": "temperature",
    "belt-drive": "belt-speed",
    "force-rate-pow": "force-rate",
    "vel-strength": "velocity-strengthening",
    "bearing": "bearing-friction",
    "waviness": None,
    "stiffness": "mechanics",  # mechanics.k1_N_per_m etc., see EffectSet.expected
}


class SpecError(ValueError):
    """A bad effect spec or parameter (make.py reports it as one line, exit status 2)."""


# ---------------------------------------------------------------------------
# Rig config (data only)
# ---------------------------------------------------------------------------


def load_config(rig: str | Path) -> dict:
    """The rig config TOML as a plain dict (a rig name from rig_configs/ or a path)."""
    path = Path(rig)
    if not path.suffix:
        path = RIG_DIR / f"{rig}.toml"
    with open(path, "rb") as fh:
        cfg = tomllib.load(fh)
    cfg.setdefault("_path", str(path))
    return cfg


# ---------------------------------------------------------------------------
# Drive programme: paper 001 eq. (11) with an optional lead-in from rest
# ---------------------------------------------------------------------------


@dataclass
class Drive:
    """Commanded belt (or drum surface) speed.

    kind "seed": v = V0 (1 - t/Tmax) (paper 001 eq. 11), 0 after Tmax; kind "constant": V0.
    With ``lead_in`` the drive starts from rest and the command is
    min(a_max t, programme(t)): a real drive saturated at its maximum acceleration
    until it meets the programme (for V0 = 0.2 m/s and 0.5 m/s^2: 0.4 s).
    """

    V0: float
    Tmax: float | None = None
    kind: str = "seed"
    lead_in: bool = False
    a_max: float = 0.5

    def programme(self, t: float) -> float:
        if self.kind == "constant" or not self.Tmax:
            return self.V0
        return self.V0 * max(0.0, 1.0 - t / self.Tmax)

    def command(self, t: float) -> float:
        v = self.programme(t)
        if self.lead_in:
            v = min(v, self.a_max * max(t, 0.0))
        return v

    def kinks(self, t_end: float) -> list[float]:
        """Times where the command's slope jumps (the integrator restarts there)."""
        out = []
        if self.lead_in:
            # a_max t = V0 (1 - t/Tmax)
            if self.kind == "constant" or not self.Tmax:
                out.append(self.V0 / self.a_max)
            else:
                out.append(self.V0 / (self.a_max + self.V0 / self.Tmax))
        if self.kind == "seed" and self.Tmax:
            out.append(self.Tmax)
        return [t for t in out if 0.0 < t < t_end]

    def describe(self) -> dict:
        return {"kind": self.kind, "V0_m_per_s": self.V0, "Tmax_s": self.Tmax, "lead_in": self.lead_in,
                "a_max_m_per_s2": self.a_max}


def default_drive(cfg: dict, V0: float | None = None, Tmax: float | None = None, lead_in: bool = False) -> Drive:
    d = cfg["drive"]
    kind = d.get("ramp", "seed")
    if Tmax is not None:
        kind = "seed"
    return Drive(V0=float(V0 if V0 is not None else d["V0_m_per_s"]),
                 Tmax=float(Tmax if Tmax is not None else d.get("Tmax_s") or 0.0) or None,
                 kind=kind, lead_in=lead_in, a_max=float(d["max_accel_m_per_s2"]))


@dataclass
class StepDrive:
    """A velocity-stepping programme: speed ``segments[k][0]`` held for ``segments[k][1]`` seconds, then a ramp at
    the drive's maximum acceleration to the next speed (the ramp eats into the next segment). The belt runs at the
    first speed from t = 0 on (the record starts on a running belt). The last segment is held for ever.

    Why steps: at one constant speed every stick lasts as long as the last, so a static level that ages with the
    time in contact (or grows with the load rate) is a constant, absorbed in f_s0; a velocity-stepping experiment
    (the classic protocol of rate-and-state friction) makes the stick times and the load rates differ.
    """

    segments: list[tuple[float, float]]
    a_max: float = 1.0
    kind: str = "steps"

    def __post_init__(self) -> None:
        if not self.segments:
            raise SpecError("steps: at least one segment")
        for v, dur in self.segments:
            if not (math.isfinite(v) and dur > 0):
                raise SpecError(f"steps: bad segment {v}:{dur}")
        if not self.a_max > 0:
            raise SpecError("steps: the drive's acceleration must be > 0")
        # (t0, v0, t1, v1): ramp pieces between the segments
        self._ramps = []
        t = 0.0
        for (v0, dur), (v1, _) in zip(self.segments, self.segments[1:]):
            t += dur
            if v1 != v0:
                self._ramps.append((t, v0, t + abs(v1 - v0) / self.a_max, v1))

    @classmethod
    def parse(cls, text: str, a_max: float = 1.0) -> StepDrive:
        """``V1:T1,V2:T2,...`` [m/s : s]."""
        segs = []
        for item in filter(None, (s.strip() for s in text.split(","))):
            v, sep, dur = item.partition(":")
            try:
                segs.append((float(v), float(dur) if sep else math.inf))
            except ValueError:
                raise SpecError(f"--steps {text!r}: {item!r} is not SPEED:SECONDS") from None
        return cls(segs, a_max)

    @property
    def V0(self) -> float:
        return self.segments[0][0]

    def command(self, t: float) -> float:
        v = self.segments[0][0]
        for t0, v0, t1, v1 in self._ramps:
            if t < t0:
                return v
            if t < t1:
                return v0 + (v1 - v0) * (t - t0) / (t1 - t0)
            v = v1
        return v

    def slope(self, t: float) -> float:
        """d(command)/dt; inside a ramp +-a_max (at a kink: the slope of the piece that starts there)."""
        for t0, v0, t1, v1 in self._ramps:
            if t0 <= t < t1:
                return math.copysign(self.a_max, v1 - v0)
        return 0.0

    def kinks(self, t_end: float) -> list[float]:
        return sorted(k for r in self._ramps for k in (r[0], r[2]) if 0.0 < k < t_end)

    def describe(self) -> dict:
        return {"kind": self.kind, "segments_m_per_s_s": [[v, d] for v, d in self.segments],
                "a_max_m_per_s2": self.a_max}


@dataclass
class TableDrive:
    """Any programme as a piecewise-linear table of (t [s], speed [m/s]) points, held at its last speed after its end:
    what a ramp file becomes (its segments evaluated by the caller; refsim reads no daq file format). Why: the next
    experiment ``daq propose`` writes is run here as the rig would run it, with whatever effect is hidden."""

    t: list[float]
    v: list[float]
    kind: str = "table"

    def __post_init__(self) -> None:
        self._t = np.asarray(self.t, dtype=float)
        self._v = np.asarray(self.v, dtype=float)
        if self._t.size < 2 or self._t.size != self._v.size or np.any(np.diff(self._t) < 0) or self._t[0] != 0.0:
            raise SpecError("table drive: need >= 2 points, the same number of times and speeds, t from 0 ascending")
        if not (np.all(np.isfinite(self._v)) and np.all(self._v >= 0.0)):
            raise SpecError("table drive: speeds must be finite and >= 0")

    @property
    def V0(self) -> float:
        return float(self._v[0])

    def command(self, t: float) -> float:
        return float(np.interp(t, self._t, self._v))

    def slope(self, t: float) -> float:
        """d(command)/dt on the piece that contains t (at a kink: the piece that starts there)."""
        i = int(np.searchsorted(self._t, t, side="right")) - 1
        if i < 0 or i >= self._t.size - 1 or self._t[i + 1] == self._t[i]:
            return 0.0
        return float((self._v[i + 1] - self._v[i]) / (self._t[i + 1] - self._t[i]))

    def kinks(self, t_end: float) -> list[float]:
        return sorted({float(k) for k in self._t if 0.0 < k < t_end})

    def describe(self) -> dict:
        return {"kind": self.kind, "points": int(self._t.size), "t_end_s": float(self._t[-1]),
                "v_min_m_per_s": float(self._v.min()), "v_max_m_per_s": float(self._v.max())}


# ---------------------------------------------------------------------------
# Effects: parameters with magnitude keys
# ---------------------------------------------------------------------------

# name -> (magnitude keys, {key: default}) ; defaults give a clearly visible effect on the
# brake rig; the drum's own defaults are in DRUM_DEFAULTS.
EFFECTS: dict[str, tuple[tuple[str, ...], dict[str, float]]] = {
    "stick-log": (("b",), {"b": 0.1, "theta": 0.01, "Dc": 1e-3}),
    "stick-creep": (("b",), {"b": 0.1, "theta": 0.05, "v_c": 1e-3, "L_r": 1e-3}),
    "accel-body": (("amp",), {"amp": 0.1, "a0": 2.0, "tau_a": 2e-3}),
    "arrhenius": (("E",), {"E": 2000.0, "T_ref_C": float("nan")}),
    "belt-drive": (("tau", "ripple"), {"tau": 0.3, "ripple": 0.05, "wavelength": 0.9, "zeta": 0.7, "h2": 0.3}),
    "force-rate-pow": (("g",), {"g": 0.3, "q0": 50.0, "n": 0.5, "tau_q": 0.02}),
    "vel-strength": (("D",), {"D": 1.0}),
    "bearing": (("torque", "mu1"), {"torque": 0.003, "mu1": 0.0, "eps": 0.01}),
    "waviness": (("w",), {"w": 0.03, "wavelength": 0.05}),
    "stiffness": (("k1", "k2", "k3", "k"), {"k1": 0.04, "k2": 0.0, "k3": 0.0, "k": 0.0}),
}
DRUM_DEFAULTS: dict[str, dict[str, float]] = {
    "stick-log": {"Dc": 1e-4},
    "arrhenius": {"E": 1000.0},
    "belt-drive": {"tau": 0.3, "ripple": 0.08, "wavelength": 0.5},  # drum angle [rad]: ~4 s at 12 mm/s
    "bearing": {"torque": 0.0, "mu1": 0.05},
    "waviness": {"wavelength": 0.02},
    "stiffness": {"k1": 0.0, "k": 0.04},
}
# belt-ndof (paper 000): the static level is in units of F0, the load rate of one mass on a 0.2 m/s belt is
# K vb = 40 N/s, the body's acceleration over a slip a few m/s^2, a slip a few cm: Dc 1 mm
BELT_DEFAULTS: dict[str, dict[str, float]] = {
    "stick-log": {"b": 0.05, "theta": 0.05, "Dc": 1e-3},
    "accel-body": {"amp": 0.1, "a0": 2.0},
    "force-rate-pow": {"g": 0.1, "q0": 40.0},
}
RIG_DEFAULTS: dict[str, dict[str, dict[str, float]]] = {"drum-pendulum": DRUM_DEFAULTS, "belt-ndof": BELT_DEFAULTS}


@dataclass
class Effect:
    name: str
    params: dict[str, float]

    @property
    def magnitude_keys(self) -> tuple[str, ...]:
        return EFFECTS[self.name][0]

    def is_neutral(self) -> bool:
        return all(self.params.get(k, 0.0) == 0.0 for k in self.magnitude_keys)

    def spec(self) -> str:
        return self.name + ":" + ",".join(f"{k}={v:g}" for k, v in self.params.items())


def parse_effect(text: str, rig: str = "brake-2dof") -> Effect:
    """``name[:key=value,...]`` -> Effect with the rig's defaults for the keys not given."""
    name, _, rest = text.strip().partition(":")
    name = name.strip()
    if name not in EFFECTS:
        raise SpecError(f"--effect {text!r}: unknown effect {name!r} (known: {', '.join(EFFECTS)})")
    defaults = dict(EFFECTS[name][1])
    defaults.update(RIG_DEFAULTS.get(rig, {}).get(name, {}))
    given: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        key = key.strip()
        if not eq or key not in defaults:
            raise SpecError(f"--effect {text!r}: bad key {key!r} (keys of {name}: {', '.join(defaults)})")
        try:
            given[key] = float(val)
        except ValueError:
            raise SpecError(f"--effect {text!r}: {key} is not a number: {val!r}") from None
        if not math.isfinite(given[key]):
            raise SpecError(f"--effect {text!r}: {key} must be finite")
    if name == "stiffness" and given:
        # only the springs named are off; the others keep the config's value
        defaults.update({k: 0.0 for k in EFFECTS[name][0]})
    if name == "bearing" and given and ("torque" in given) != ("mu1" in given):
        defaults.update({"torque": 0.0, "mu1": 0.0})
    defaults.update(given)
    p = defaults
    positive = {"theta", "Dc", "v_c", "L_r", "a0", "tau_a", "wavelength", "q0", "n", "tau_q", "eps", "zeta"}
    for k in positive & p.keys():
        if not p[k] > 0:
            raise SpecError(f"--effect {text!r}: {k} must be > 0")
    for k in ("tau",):
        if k in p and p[k] < 0:
            raise SpecError(f"--effect {text!r}: {k} must be >= 0")
    return Effect(name, p)


@dataclass
class EffectSet:
    """All effect parameters of one run; an absent effect is at its magnitude 0."""

    effects: list[Effect] = field(default_factory=list)
    rig: str = "brake-2dof"

    @classmethod
    def parse(cls, specs, rig: str = "brake-2dof") -> EffectSet:
        out = []
        for s in specs or ():
            e = s if isinstance(s, Effect) else parse_effect(s, rig)
            if any(o.name == e.name for o in out):
                raise SpecError(f"--effect {e.name}: given twice")
            out.append(e)
        if {"stick-log", "stick-creep"} <= {e.name for e in out if not e.is_neutral()}:
            raise SpecError("--effect stick-log and stick-creep: one stick-time clock at a time")
        return cls(out, rig)

    def get(self, name: str) -> dict[str, float]:
        """Parameters of ``name``: as given, or its defaults with the magnitudes at 0."""
        for e in self.effects:
            if e.name == name:
                return e.params
        d = dict(EFFECTS[name][1])
        d.update(RIG_DEFAULTS.get(self.rig, {}).get(name, {}))
        for k in EFFECTS[name][0]:
            d[k] = 0.0
        return d

    def expected(self) -> list[str]:
        """What a diagnosis should name: catalog phenomena, mechanics parameters, '(off-catalog)'."""
        out = set()
        for e in self.effects:
            if e.is_neutral():
                continue
            if e.name == "stiffness":
                out.update(f"mechanics.{k}_N_per_m" for k in e.magnitude_keys if e.params.get(k, 0.0) != 0.0)
            else:
                out.add(PHENOMENON[e.name] or "(off-catalog)")
        return sorted(out)

    def truth(self) -> list[dict]:
        """Effects as given, for the JSON sidecar (a default-to-ambient reference is null)."""
        return [{"effect": e.name, "phenomenon": PHENOMENON[e.name],
                 "params": {k: (v if math.isfinite(v) else None) for k, v in e.params.items()},
                 "neutral": e.is_neutral()} for e in self.effects]


# ---------------------------------------------------------------------------
# Effect terms (scalar, math only: called in the right-hand side)
# ---------------------------------------------------------------------------


def dieterich_factor(theta_s: float, b: float, theta: float) -> float:
    """Static-peak factor of logarithmic aging: 1 + b ln(1 + theta_s/theta)."""
    return 1.0 + b * math.log1p(max(theta_s, 0.0) / theta)


def dieterich_rate(theta_s: float, v_rel: float, dc: float) -> float:
    """Dieterich's aging law: d theta/dt = 1 - |V| theta / Dc."""
    return 1.0 - abs(v_rel) * theta_s / dc


def creep_clock_rate(t_c: float, v_rel: float, v_c: float, l_r: float) -> float:
    """The creep clock: d t_c/dt = phi - (1 - phi) |V| t_c / L_r, phi = 1/(1 + (V/v_c)^2): it runs while the
    contact creeps and is wiped out over a slip of a few L_r."""
    phi = lorentz_stuck(v_rel, v_c)
    return phi - (1.0 - phi) * abs(v_rel) * t_c / l_r


def creep_clock_steady(v: float, v_c: float, l_r: float) -> float:
    """The creep clock in steady sliding at speed v (its rate 0): phi L_r / ((1 - phi) |v|)."""
    phi = lorentz_stuck(v, v_c)
    return phi * l_r / ((1.0 - phi) * abs(v))


def power_rate_factor(q: float, g: float, q0: float, n: float) -> float:
    """Static-peak factor of the power-law force-rate effect: 1 + g (|q|/q0)^n."""
    return 1.0 + g * (abs(q) / q0) ** n


def lorentz_stuck(v_rel: float, v_c: float) -> float:
    """Stuck indicator 1/(1 + (V/v_c)^2) (1 = stuck)."""
    u = v_rel / v_c
    return 1.0 / (1.0 + u * u)


def arrhenius_factor(temp_K: float, e_act: float, tref_K: float) -> float:
    """exp(E (1/T - 1/T_ref)), T in kelvin."""
    return math.exp(e_act * (1.0 / temp_K - 1.0 / tref_K))


def smooth_sgn_atan(w: float, eps: float) -> float:
    """(2/pi) arctan(w/eps): the bearing's regularised Coulomb sign."""
    return 0.6366197723675814 * math.atan(w / eps)


def belt_ripple(s: float, ripple: float, wavelength: float, h2: float) -> float:
    """Relative speed factor of the drive's ripple at belt travel s."""
    if ripple == 0.0:
        return 1.0
    ph = 2.0 * math.pi * s / wavelength
    return 1.0 + ripple * (math.sin(ph) + h2 * math.sin(2.0 * ph + 1.0))


def drive_rates(v_cmd: float, v: float, dv: float, tau: float, zeta: float):
    """Second-order drive: (dv/dt, d(dv)/dt). With tau = 0 the caller uses the command itself."""
    w = 1.0 / tau
    return dv, w * w * (v_cmd - v) - 2.0 * zeta * w * dv
