"""drum-pendulum reference model (paper 002), written from the paper's eq. (1) as printed.

Paper 002 eq. (1), third row (moments about the drum axis), with delta = 0:

    I0 phi'' = -S Rs cos(phi) + N mu R sgn(v_wz) - Z mu1 r0 sgn(phi') [- c phi']

S = k Rs sin(phi) the spring force, v_wz = (omega - phi') R the slide velocity (drum
minus pendulum, the paper's sign), N the thrust of the friction element, Z the bearing
thrust from the first row: Z = N + S sin(phi) - m Rc phi'^2 (delta = 0). The viscous
term c phi' is the rig config's seed damping (paper 002 has none; the seed model of
this project carries it, so the null case must too).

Friction, law (3) as printed, evaluated at |v_wz| and given the sign of v_wz:

    mu = [A (1 - exp(-B |v|)) exp(-C |v|) + D |v| + E] sgn(v_wz)

with sgn regularised as tanh(v_wz / eps) (the config's eps: the regularisation is
numerical, not physics, and the null case must agree). The hump A is the static/peak
part that stick-log and force-rate-pow scale. The thrust gauge reads
N = P (1 + runout sin(theta_d)), theta_d the drum angle (a drum out of round by the
config's few per cent).

State: phi, phi', T [K], theta_s [s], q [N/s], a_f [m/s^2], v_lag, v_lag', s (drum
surface travel) [m].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import effects as fx
from .brake import ReferenceRig, Trajectory

RIG = "drum-pendulum"
STATE = ("phi", "phi_dot", "temp_K", "theta_s", "q", "acc_f", "v_lag", "v_lag_dot", "travel")
N_STATE = len(STATE)
ATOL = np.array([1e-9, 1e-7, 1e-6, 1e-6, 1e-3, 1e-4, 1e-8, 1e-6, 1e-8])


@dataclass
class DrumParams:
    I0: float
    k: float
    Rs: float
    R: float
    r0: float
    m: float
    Rc: float
    P: float
    runout: float
    A: float
    B: float
    C: float
    D: float
    E: float
    eps: float
    c: float
    T_amb_K: float
    drift: float
    r_thermal: float
    tau_thermal: float
    v_stick: float
    eta: float = 0.5


def params_from_config(cfg: dict) -> DrumParams:
    mech, fr, ct = cfg["mechanics"], cfg["friction"], cfg["contact"]
    seed = cfg.get("seed_effects", {})
    return DrumParams(
        I0=mech["I0_kg_m2"], k=mech["k_N_per_m"], Rs=mech["Rs_m"], R=mech["R_m"], r0=mech["r0_m"], m=mech["m_kg"],
        Rc=mech["Rc_m"], P=mech["thrust_N"], runout=mech.get("runout", 0.0),
        A=fr["A"], B=fr["B_s_per_m"], C=fr["C_s_per_m"], E=fr["E"], eps=fr["sgn_eps_m_per_s"],
        D=float(seed.get("velocity-strengthening", {}).get("D", 0.0)),
        c=float(seed.get("viscous-damping", {}).get("c", 0.0)),
        T_amb_K=ct["t_ambient_C"] + fx.KELVIN, drift=ct.get("ambient_drift_K_per_s", 0.0),
        r_thermal=ct["r_thermal_K_per_W"], tau_thermal=ct["tau_thermal_s"], v_stick=ct["v_stick_m_per_s"],
    )


class DrumRig(ReferenceRig):
    """The drum-pendulum rig with hidden effects, driven by a :class:`effects.Drive` (drum surface speed)."""

    atol, rig, params_from_config = ATOL, RIG, staticmethod(params_from_config)

    def _bind(self) -> None:
        p, e = self.p, self.fx
        self.k = p.k * (1.0 + e.get("stiffness")["k"])
        self.mu1 = e.get("bearing")["mu1"]

    def mu_law3(self, v_wz: float, peak: float = 1.0) -> float:
        """Law (3) at |v_wz| with the sign of v_wz (regularised); ``peak`` scales the hump A."""
        p = self.p
        av = abs(v_wz)
        mag = p.A * peak * (1.0 - math.exp(-p.B * av)) * math.exp(-p.C * av) + p.D * av + p.E
        return math.tanh(v_wz / p.eps) * mag

    def energy(self, y: np.ndarray) -> np.ndarray:
        """I0 phi'^2/2 + potential of the spring torque k Rs^2 sin cos, i.e. k Rs^2 sin^2(phi)/2."""
        phi, w = y[..., 0], y[..., 1]
        return 0.5 * self.p.I0 * w ** 2 + 0.5 * self.k * self.p.Rs ** 2 * np.sin(phi) ** 2

    def linear_modes(self) -> np.ndarray:
        return np.array([math.sqrt(self.k * self.p.Rs ** 2 / self.p.I0) / (2 * math.pi)])

    def _eval(self, t: float, s, full: bool = False):
        p = self.p
        phi, w, T, th, q, af, vl, vld, trav = s
        v_cmd, v_base, d_vl, d_vld = self._drive_base(t, vl, vld)
        bd = self.bd
        theta_d = trav / p.R  # drum angle
        # ripple periodic in drum angle (wavelength in rad, as the catalog's drum convention)
        vd = v_base * fx.belt_ripple(theta_d, bd["ripple"], bd["wavelength"], bd["h2"])
        v_wz = vd - p.R * w

        n = p.P * (1.0 + p.runout * math.sin(theta_d))
        sphi, cphi = math.sin(phi), math.cos(phi)
        spring = self.k * p.Rs * sphi  # S
        peak = self.aging(th) \
            * fx.power_rate_factor(q, self.fr["g"], self.fr["q0"], self.fr["n"])
        mu = self.mu_law3(v_wz, peak)
        mu = mu * fx.arrhenius_factor(T, self.ar_E, self.ar_Tref)
        mu = mu * (1.0 + self.wv["w"] * math.sin(2.0 * math.pi * trav / self.wv["wavelength"]))
        mu = mu + self.vs_D * v_wz
        mu = mu * (1.0 + self.ab["amp"] * math.tanh(af / self.ab["a0"]))
        f = mu * n  # friction force on the pendulum, along the drum's motion

        z = n + spring * sphi - p.m * p.Rc * w * w  # eq. (1) row 1, delta = 0
        torque = -spring * p.Rs * cphi + f * p.R - p.c * w
        torque -= self.mu1 * z * p.r0 * fx.smooth_sgn_atan(w, self.br_eps)
        acc = torque / p.I0

        T_amb = p.T_amb_K + p.drift * t
        d_T = (p.eta * abs(f * v_wz) - (T - T_amb) / p.r_thermal) / self.C_th
        d_th = self.clock_rate(th, v_wz)
        load_rate = self.k * p.Rs ** 2 * math.cos(2.0 * phi) * w / p.R  # d/dt (spring torque / R)
        d_q = fx.lorentz_stuck(v_wz, p.v_stick) * (load_rate - q) / self.fr["tau_q"]
        d_af = (p.R * acc - af) / self.ab["tau_a"]
        ds = (w, acc, d_T, d_th, d_q, d_af, d_vl, d_vld, vd)
        if not full:
            return ds
        return ds, {"friction_force": f, "normal_load": n, "mu": mu, "v_wz": v_wz, "drum_surface_speed": vd,
                    "drum_surface_speed_set": v_cmd, "acc": acc, "bearing_thrust": z, "spring_force": spring}

    def rhs(self, t: float, s) -> tuple:
        return self._eval(t, s)

    def initial_state(self) -> np.ndarray:
        """Pendulum at rest at phi = 0; drum at its command."""
        v0 = self.drive.command(0.0)
        s = np.zeros(N_STATE)
        s[2] = self.p.T_amb_K
        s[3] = self.clock_start(v0)
        s[6] = v0
        return s

    def true_channels(self, tr: Trajectory) -> dict[str, np.ndarray]:
        p = self.p
        phi = tr.y[:, 0]
        return {
            "phi": phi,
            "force_a": self.k * p.Rs * np.sin(phi),
            "thrust": tr.aux["normal_load"],
            "accel": p.R * tr.aux["acc"],
            "vel": p.R * tr.y[:, 1],
            "drum_speed": tr.aux["drum_surface_speed"] / p.R,
            "drum_rev": np.floor(tr.y[:, 8] / (2 * math.pi * p.R)),
            "temp": tr.y[:, 2] - fx.KELVIN,
        }

    def truth(self, tr: Trajectory) -> dict[str, np.ndarray]:
        return {"phi_dot": tr.y[:, 1], "friction_force": tr.aux["friction_force"], "mu": tr.aux["mu"],
                "v_wz": tr.aux["v_wz"], "bearing_thrust": tr.aux["bearing_thrust"], "theta_s": tr.y[:, 3],
                "drum_travel": tr.y[:, 8]}
