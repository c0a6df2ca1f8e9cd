"""Per-rig inverse dynamics: friction = mass x (acceleration without friction - measured acceleration).

Why here and not re-typed: the non-friction forces come from evaluating the rig's own
compiled right-hand side (daq/physics/<rig>.rhs) with the friction switched off (a copy
of the parameter vector with the law's values zeroed, and the velocity-strengthening
slot of the effect vector zeroed). The rig's equation of motion along the sliding
direction is  mass * a = G(state) - F,  so F = mass * (a_without_friction - a), in the
common convention of daq/physics/contact.py (F = mu(v_rel) N, v_rel = body - drive).
The kernels loop over samples inside numba; they belong in daq/physics next to each
rhs once the physics owners adopt them (see the estimator report).

Decision record: docs/decisions/0001-physics-in-one-place.md.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from daq.config import RigConfig
from daq.physics import beltndof, brake2dof, drum
from daq.physics.contact import AUX, N_AUX
from daq.physics.effects import TAIL, E
from daq.physics.jit import kernel
from daq.sim.effectset import effect_vector
from daq.sim.rigs import make_sim

from .laws import LawDef, law_for


@kernel
def brake_free_accel(x1, x1d, y1, y1d, p, e, acc0, n_load):
    """brake-2dof: block acceleration with friction off (eq. 5a without F) and eq. (6) normal load."""
    s = np.zeros(brake2dof.N_STATE)
    ds = np.empty(brake2dof.N_STATE)
    aux = np.empty(N_AUX)
    rt = np.array([0.0, 1.0])
    rv = np.zeros(2)
    for k in range(x1.size):
        s[0] = x1[k]
        s[1] = x1d[k]
        s[2] = y1[k]
        s[3] = y1d[k]
        brake2dof.rhs(0.0, s, p, e, rt, rv, ds, aux)
        acc0[k] = ds[1]
        n_load[k] = aux[AUX.N]


@kernel
def drum_free_accel(phi, w, thrust, p, e, acc0, n_load):
    """drum-pendulum: tangential acceleration at R with friction off, and the normal load.

    The rhs reads the thrust as P (1 + runout sin(drum angle)); setting the drum angle to
    pi/2 and runout = thrust/P - 1 per sample makes it read the measured thrust, so the
    normal-load blend and the bearing thrust Z come from the physics, not a copy of it.
    """
    pp = p.copy()
    s = np.zeros(drum.N_STATE)
    ds = np.empty(drum.N_STATE)
    aux = np.empty(N_AUX)
    rt = np.array([0.0, 1.0])
    rv = np.zeros(2)
    s[drum.N_MECH + TAIL.POS] = p[drum.P.R] * 0.5 * math.pi
    for k in range(phi.size):
        s[0] = phi[k]
        s[1] = w[k]
        pp[drum.P.RUNOUT] = thrust[k] / p[drum.P.P] - 1.0
        drum.rhs(0.0, s, pp, e, rt, rv, ds, aux)
        acc0[k] = aux[AUX.ACC]
        n_load[k] = aux[AUX.N]


@kernel
def belt_free_accel(x, v, p, e, n_state, acc0):
    """belt-ndof: every mass's acceleration with friction off (all masses in slip mode, law zeroed)."""
    n = int(p[beltndof.P.N])
    s = np.zeros(n_state)
    ds = np.empty(s.size)
    hs = np.zeros((beltndof.N_H, n))
    hs[beltndof.H.SLIP_DIR] = 1.0
    fric = np.empty(n)
    region = np.zeros(n, dtype=np.int64)
    rt = np.array([0.0, 1.0])
    rv = np.zeros(2)
    for k in range(x.shape[1]):
        for i in range(n):
            s[i] = x[i, k]
            s[n + i] = v[i, k]
        beltndof.rhs(0.0, s, hs, p, e, rt, rv, ds, fric, region)
        for i in range(n):
            acc0[i, k] = ds[n + i]


@dataclass(frozen=True)
class FilterSpec:
    """One causal filter output: derivative ``deriv`` of ``channel`` from a local polynomial fit.

    ``degree`` None = the estimator's kinematic degree (configurable); drive speeds use 1.
    """

    key: str
    channel: str
    deriv: int
    degree: int | None = None


@dataclass
class Estimate:
    """Per-sample results of the inverse dynamics (arrays of one length)."""

    F: np.ndarray  # friction force, common convention [N]
    N: np.ndarray  # normal load [N]
    mu: np.ndarray  # F / N
    v_rel: np.ndarray  # body - drive [m/s]
    a: np.ndarray  # body acceleration along the sliding direction [m/s^2]
    a_drive: np.ndarray  # drive acceleration [m/s^2] (for d|v_rel|/dt)
    extra: dict[str, np.ndarray]


class RigModel(ABC):
    """What the estimator needs to know about one rig: inputs, filters, inverse dynamics, law."""

    rig_id: str
    position: str  # channel whose stream sets the time base
    default_window_s: float  # differentiator window (see tests/test_estimator.py for the trade-off)
    default_degree: int = 2  # degree of the local polynomial for the body's kinematics

    def __init__(self, cfg: RigConfig, e: np.ndarray | None = None) -> None:
        self.cfg = cfg
        self.e = np.asarray(effect_vector(cfg)[0] if e is None else e, dtype=float)
        self.p = make_sim(cfg, self.e).p.copy()
        self.e_free = self.e.copy()
        self.e_free[E.VS_D] = 0.0  # velocity-strengthening adds D v_rel to mu: friction too
        self.v_stick = float(cfg.contact.v_stick_m_per_s)
        self.law: LawDef = law_for(cfg, self.e)

    @property
    @abstractmethod
    def inputs(self) -> tuple[str, ...]:
        """Channels the estimator reads (interchange names)."""

    @property
    @abstractmethod
    def filters(self) -> tuple[FilterSpec, ...]:
        """The causal filters the inference reads, all evaluated at the same lagged instant."""

    @property
    def extra_names(self) -> tuple[str, ...]:
        """Per-sample outputs beyond the common ones (e.g. the other masses of belt-ndof)."""
        return ()

    @abstractmethod
    def infer(self, f: dict[str, np.ndarray]) -> Estimate:
        """Friction, normal load and relative velocity from the filtered channels."""


def _smooth(ch: str, degree: int | None = None) -> FilterSpec:
    """The channel itself, smoothed and delayed like its derivatives (all taken at the same instant)."""
    return FilterSpec(ch, ch, 0, degree)


def _derivs(ch: str) -> tuple[FilterSpec, ...]:
    """Position, velocity and acceleration of one body coordinate."""
    return (_smooth(ch), FilterSpec(ch + "'", ch, 1), FilterSpec(ch + "''", ch, 2))


class BrakeModel(RigModel):
    """brake-2dof: eq. (5a) solved for F with x1, y1 = r phi and their derivatives; N from eq. (6)."""

    rig_id = "brake-2dof"
    position = "x1"
    default_window_s = 0.023
    default_degree = 4

    def __init__(self, cfg: RigConfig, e: np.ndarray | None = None) -> None:
        super().__init__(cfg, e)
        self.p_free = self.p.copy()
        self.p_free[brake2dof.P.mu0] = 0.0

    @property
    def inputs(self):
        return ("x1", "phi", "vb")

    @property
    def filters(self):
        # the drive speed is a slow ramp: a local line (a moving average at the centre) is unbiased
        return (*_derivs("x1"), _smooth("phi"), FilterSpec("phi'", "phi", 1), FilterSpec("vb'", "vb", 1, 1),
                _smooth("vb", 1))

    def infer(self, f):
        r = self.p[brake2dof.P.r]
        n = f["x1"].size
        acc0, n_load = np.empty(n), np.empty(n)
        brake_free_accel(f["x1"], f["x1'"], r * f["phi"], r * f["phi'"], self.p_free, self.e_free, acc0, n_load)
        force = self.p[brake2dof.P.m] * (acc0 - f["x1''"])
        return Estimate(force, n_load, force / n_load, f["x1'"] - f["vb"], f["x1''"], f["vb'"], {})


class DrumModel(RigModel):
    """drum-pendulum: paper 002 eq. (2) via the rhs, from measured phi, vel, accel and thrust."""

    rig_id = "drum-pendulum"
    position = "phi"
    default_window_s = 0.005

    def __init__(self, cfg: RigConfig, e: np.ndarray | None = None) -> None:
        super().__init__(cfg, e)
        P = drum.P
        self.p_free = self.p.copy()
        self.p_free[P.A] = self.p_free[P.E0] = 0.0
        self.m_eff = self.p[P.I0] / self.p[P.R] ** 2  # I0 phi'' = ... - F R  ->  (I0/R^2) a_t = ... - F

    @property
    def inputs(self):
        return ("phi", "vel", "accel", "thrust", "drum_speed")

    @property
    def filters(self):
        return (_smooth("phi"), _smooth("vel"), _smooth("accel"), _smooth("thrust", 1), _smooth("drum_speed", 1),
                FilterSpec("drum_speed'", "drum_speed", 1, 1))

    def infer(self, f):
        R = self.p[drum.P.R]
        n = f["phi"].size
        acc0, n_load = np.empty(n), np.empty(n)
        drum_free_accel(f["phi"], f["vel"] / R, f["thrust"], self.p_free, self.e_free, acc0, n_load)
        force = self.m_eff * (acc0 - f["accel"])
        return Estimate(force, n_load, force / n_load, f["vel"] - R * f["drum_speed"], f["accel"],
                        R * f["drum_speed'"], {})


class BeltModel(RigModel):
    """belt-ndof: eq. (1) per mass via the hybrid rhs in slip mode with the law zeroed; N = F0. With a driven
    spring end (a spring-slider) the driver frame's acceleration V' is the estimated drive's derivative."""

    rig_id = "belt-ndof"
    position = "x1"
    default_window_s = 0.06

    def __init__(self, cfg: RigConfig, e: np.ndarray | None = None) -> None:
        super().__init__(cfg, e)
        P = beltndof.P
        self.n = int(self.p[P.N])
        self.p_free = self.p.copy()
        for slot in (P.F_S0, P.ALPHA_DROP, P.F_K0, P.K_FALL, P.K_RISE):
            self.p_free[slot] = 0.0

    @property
    def inputs(self):
        return (*(f"x{i + 1}" for i in range(self.n)), "vb")

    @property
    def filters(self):
        out: list[FilterSpec] = []
        for i in range(self.n):
            out += _derivs(f"x{i + 1}")
        return (*out, _smooth("vb", 1), FilterSpec("vb'", "vb", 1, 1))

    @property
    def extra_names(self):
        return tuple(f"{k}_{i + 1}" for i in range(1, self.n) for k in ("F_est", "v_rel"))

    def infer(self, f):
        names = [f"x{i + 1}" for i in range(self.n)]
        x = np.stack([f[c] for c in names])
        v = np.stack([f[c + "'"] for c in names])
        acc0 = np.empty_like(x)
        belt_free_accel(x, v, self.p_free, self.e_free, beltndof.n_state(self.n), acc0)
        if self.p[beltndof.P.SPRING_DRIVEN]:  # a spring-slider: the driver's frame accelerates, + V' on every mass
            acc0 += f["vb'"][None, :]  # (belt_free_accel runs at a constant drive: its frame term is 0)
        a = np.stack([f[c + "''"] for c in names])
        force = self.p[beltndof.P.M] * (acc0 - a)
        f0 = self.p[beltndof.P.F0]
        extra = {f"F_est_{i + 1}": force[i] for i in range(1, self.n)}
        extra.update({f"v_rel_{i + 1}": v[i] - f["vb"] for i in range(1, self.n)})
        return Estimate(force[0], np.full(x.shape[1], f0), force[0] / f0, v[0] - f["vb"], a[0], f["vb'"], extra)


MODELS: dict[str, type[RigModel]] = {"brake-2dof": BrakeModel, "drum-pendulum": DrumModel, "belt-ndof": BeltModel}


def rig_model(cfg: RigConfig, e: np.ndarray | None = None) -> RigModel:
    """The estimator's model of a rig: the seed effects unless an effect vector is given."""
    return MODELS[cfg.rig](cfg, e)
