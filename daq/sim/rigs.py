"""Simulated rigs: the shared physics plus the rig's instruments (what each channel reads).

One adapter per rig maps a validated config and an effect vector to the compiled
equations, integrates a chunk, and says what each interchange channel would read.

Decision record: docs/decisions/0001-physics-in-one-place.md.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from daq.config import BeltRig, BrakeRig, DrumRig, RigConfig
from daq.errors import InputError
from daq.physics import beltndof, brake2dof, drum
from daq.physics.contact import AUX
from daq.physics.effects import TAIL, E

from .integrate import make_rk4

_rk4_cache: dict[str, object] = {}


def _rk4(module):
    """One compiled integrator per rig module per process."""
    if module.RIG_ID not in _rk4_cache:
        _rk4_cache[module.RIG_ID] = make_rk4(module.rhs, module.RIG_ID.replace("-", "_"))
    return _rk4_cache[module.RIG_ID]


@dataclass
class Chunk:
    states: np.ndarray  # (n, n_state)
    aux: np.ndarray  # (n, N_AUX)
    extra: dict[str, np.ndarray]


class SimRig(ABC):
    """A rig's physics bound to parameters: integrate, and read channels off the truth."""

    rig_id: str
    n_mech: int

    def __init__(self, cfg: RigConfig, e: np.ndarray) -> None:
        self.cfg = cfg
        self.e = np.asarray(e, dtype=float)
        self.p = self.params()
        self.rk4 = None  # the compiled integrator; a model with a user effect puts its own here

    @abstractmethod
    def params(self) -> np.ndarray: ...

    @abstractmethod
    def initial_state(self, v_drive: float) -> np.ndarray: ...

    @abstractmethod
    def advance(self, s0: np.ndarray, t0: float, dt: float, n_sub: int, n_out: int,
                rt: np.ndarray, rv: np.ndarray) -> Chunk: ...

    @abstractmethod
    def channels(self, t: np.ndarray, c: Chunk) -> dict[str, np.ndarray]:
        """True values of the interchange channels this rig has."""

    @abstractmethod
    def modes_hz(self) -> dict[str, list[float]]:
        """Linearised eigenfrequencies [Hz] (what `daq rig show` prints)."""

    def tail(self, s: np.ndarray) -> None:
        s[self.n_mech + TAIL.TEMP] = self.e[E.T_AMB]

    def rest_state(self, n_state: int, v_drive: float) -> np.ndarray:
        """A state of ``n_state`` zeros but for the drive already at ``v_drive`` and the contact at ambient."""
        s = np.zeros(n_state)
        s[self.n_mech + TAIL.VLAG] = v_drive
        self.tail(s)
        return s

    def truth(self, c: Chunk) -> dict[str, np.ndarray]:
        """Ground truth the instruments cannot see (friction force, normal load, mu, ...)."""
        a = c.aux
        tail = c.states[:, self.n_mech:]
        return {
            "friction_force": a[:, AUX.F],
            "normal_load": a[:, AUX.N],
            "mu": a[:, AUX.MU],
            "v_rel": a[:, AUX.V_REL],
            "v_drive": a[:, AUX.V_DRIVE],
            "stick_clock": tail[:, TAIL.TS],
            "temperature": tail[:, TAIL.TEMP],
            "drive_travel": tail[:, TAIL.POS],
        }


class CompiledSim(SimRig):
    """A rig integrated by the compiled RK4 of its physics module (``physics``): no extra outputs."""

    physics: ModuleType

    def advance(self, s0, t0, dt, n_sub, n_out, rt, rv) -> Chunk:
        st, ax = (self.rk4 or _rk4(self.physics))(s0, t0, dt, n_sub, n_out, self.p, self.e, rt, rv)
        return Chunk(st, ax, {})


class BrakeSim(CompiledSim):
    rig_id = "brake-2dof"
    physics = brake2dof
    n_mech = brake2dof.N_MECH
    cfg: BrakeRig

    def params(self) -> np.ndarray:
        m, f = self.cfg.mechanics, self.cfg.friction
        P = brake2dof.P
        p = np.zeros(brake2dof.N_P)
        p[P.M], p[P.m], p[P.J], p[P.r] = m.M_kg, m.m_kg, m.J_kg_m2, m.r_m
        p[P.k1], p[P.k2], p[P.k3], p[P.g] = m.k1_N_per_m, m.k2_N_per_m, m.k3_N_per_m, m.g_m_per_s2
        # lambda_r prefactor sqrt(2) l / (2 r) with l = (3 sqrt 2 / 4) r  ->  3/4
        p[P.lam0] = math.sqrt(2) * (3 * math.sqrt(2) / 4 * m.r_m) / (2 * m.r_m)
        p[P.mu0], p[P.gamma], p[P.alpha], p[P.beta] = f.mu0, f.gamma_s_per_m, f.alpha_s_per_m, f.beta
        brake2dof.derive(p)
        p[P.N_NOM] = brake2dof.nominal_normal_load(p, self.e[E.GEO_WEIGHT])
        return p

    def initial_state(self, v_drive: float) -> np.ndarray:
        """At rest at the friction-free static equilibrium, on a belt already at speed."""
        s = self.rest_state(brake2dof.N_STATE, v_drive)
        s[0], s[2] = brake2dof.equilibrium(self.p, self.e[E.GEO_WEIGHT])
        return s

    def channels(self, t, c):
        r = self.p[brake2dof.P.r]
        return {"x1": c.states[:, 0], "phi": c.states[:, 2] / r, "vb": c.aux[:, AUX.V_DRIVE],
                "vb_set": c.aux[:, AUX.V_CMD], "temp": c.states[:, self.n_mech + TAIL.TEMP]}

    def truth(self, c):
        out = super().truth(c)
        out.update(x1_dot=c.states[:, 1], y1=c.states[:, 2], y1_dot=c.states[:, 3],
                   normal_load_instantaneous=c.aux[:, AUX.N_INST])
        return out

    def modes_hz(self):
        gw = self.e[E.GEO_WEIGHT]
        return {"about_equilibrium": brake2dof.linear_modes(self.p, gw, "equilibrium").tolist(),
                "about_y1_zero": brake2dof.linear_modes(self.p, gw, "origin").tolist(),
                "springs_only": brake2dof.linear_modes(self.p, 0.0, "origin").tolist()}


class DrumSim(CompiledSim):
    rig_id = "drum-pendulum"
    physics = drum
    n_mech = drum.N_MECH
    cfg: DrumRig

    def params(self) -> np.ndarray:
        m, f = self.cfg.mechanics, self.cfg.friction
        P = drum.P
        p = np.zeros(drum.N_P)
        p[P.I0], p[P.k], p[P.Rs], p[P.R], p[P.r0] = m.I0_kg_m2, m.k_N_per_m, m.Rs_m, m.R_m, m.r0_m
        p[P.m], p[P.Rc], p[P.P], p[P.RUNOUT] = m.m_kg, m.Rc_m, m.thrust_N, m.runout
        p[P.A], p[P.B], p[P.C], p[P.E0], p[P.EPS] = f.A, f.B_s_per_m, f.C_s_per_m, f.E, f.sgn_eps_m_per_s
        return p

    def initial_state(self, v_drive: float) -> np.ndarray:
        return self.rest_state(drum.N_STATE, v_drive)

    def channels(self, t, c):
        P = drum.P
        p = self.p
        phi, w = c.states[:, 0], c.states[:, 1]
        R = p[P.R]
        travel = c.states[:, self.n_mech + TAIL.POS]
        return {"phi": phi, "force_a": p[P.k] * p[P.Rs] * np.sin(phi), "thrust": c.aux[:, AUX.N_INST],
                "accel": c.aux[:, AUX.ACC], "vel": R * w, "drum_speed": c.aux[:, AUX.V_DRIVE] / R,
                "drum_rev": np.floor(travel / (2 * math.pi * R)),
                "temp": c.states[:, self.n_mech + TAIL.TEMP]}

    def truth(self, c):
        out = super().truth(c)
        out.update(phi_dot=c.states[:, 1])
        return out

    def modes_hz(self):
        return {"small_angle": drum.linear_modes(self.p).tolist()}


class BeltSim(SimRig):
    rig_id = "belt-ndof"
    cfg: BeltRig

    def __init__(self, cfg: RigConfig, e: np.ndarray) -> None:
        super().__init__(cfg, e)
        self.n = cfg.mechanics.n_masses
        self.n_mech = 2 * self.n
        self.hybrid = beltndof.new_hybrid(self.n, self.p[beltndof.P.F_S0], 1.0)
        self.n_events = 0
        if self.n > 1 and self.e[E.RS_DC] > 0.0:
            raise InputError(cfg.title, "mechanics.n_masses", f"{self.n}: rate-and-state is for one slider "
                                                              "(its contact state is one variable)")

    def params(self) -> np.ndarray:
        m, f = self.cfg.mechanics, self.cfg.friction
        P = beltndof.P
        p = np.zeros(beltndof.N_P)
        p[P.M], p[P.K], p[P.F0], p[P.N] = m.mass_kg, m.stiffness_N_per_m, m.normal_force_N, m.n_masses
        p[P.F_S0], p[P.ALPHA_DROP], p[P.F_K0] = f.f_s0, f.alpha_drop, f.f_k0
        p[P.K_FALL], p[P.W_MIN], p[P.K_RISE] = f.k_fall, f.w_min, f.k_rise
        p[P.SPRING_DRIVEN] = 1.0 if m.driven == "spring" else 0.0
        return p

    def initial_state(self, v_drive: float) -> np.ndarray:
        """Masses at rest at the unstretched position, slipping on a belt already at speed."""
        s = self.rest_state(beltndof.n_state(self.n), v_drive)
        self.hybrid = beltndof.new_hybrid(self.n, self.p[beltndof.P.F_S0], 1.0 if v_drive >= 0 else -1.0)
        if v_drive != 0.0 and self.e[E.RS_DC] > 0.0:  # rate-and-state: the state steady at the start's slip speed
            s[self.n_mech + TAIL.PSI] = math.log(self.e[E.RS_VREF] / abs(v_drive))
        return s

    def advance(self, s0, t0, dt, n_sub, n_out, rt, rv) -> Chunk:
        e = self.e
        if 0.0 < e[E.VB_TAU] < dt:
            # a belt lag shorter than the step is integrated as none: RK4 on it is unstable beyond tau < 0.36 dt,
            # and a fit's finite-difference step from tau = 0 (5e-7 s) made the belt speed flip sign every step
            e = e.copy()
            e[E.VB_TAU] = 0.0
        st, ax, fr, md, nev = beltndof.simulate(s0, t0, dt, n_sub, n_out, self.p, e, rt, rv, self.hybrid)
        self.n_events += int(nev)
        return Chunk(st, ax, {"friction_forces": fr, "modes": md})

    def channels(self, t, c):
        out = {f"x{i + 1}": c.states[:, i] for i in range(self.n)}
        out.update(vb=c.aux[:, AUX.V_DRIVE], vb_set=c.aux[:, AUX.V_CMD],
                   temp=c.states[:, self.n_mech + TAIL.TEMP])
        return out

    def truth(self, c):
        out = super().truth(c)
        fr = c.extra["friction_forces"]
        md = c.extra["modes"]
        for i in range(self.n):
            out[f"x{i + 1}_dot"] = c.states[:, self.n + i]
            out[f"friction_force_{i + 1}"] = -fr[:, i]  # common convention: force on body = -F
            out[f"stuck_{i + 1}"] = md[:, i]
        return out

    def modes_hz(self):
        return {"chain": beltndof.linear_modes(self.p).tolist()}


SIMS: dict[str, type[SimRig]] = {"brake-2dof": BrakeSim, "drum-pendulum": DrumSim, "belt-ndof": BeltSim}


def make_sim(cfg: RigConfig, e: np.ndarray) -> SimRig:
    return SIMS[cfg.rig](cfg, e)
