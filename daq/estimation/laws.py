"""Friction laws as fit targets: the laws of daq/physics/friction.py with named, bounded parameters.

Why a wrapper: the running fit needs each law as mu(v_rel; theta) over arrays with a
parameter vector, initial values from the rig config and bounds; the laws themselves
stay in daq/physics/friction.py. Everything here is module-level and picklable, so a
fit can run in another process.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from daq.config import RigConfig
from daq.physics.effects import E
from daq.physics.friction import f_pwl_piece, mu_brake, mu_drum


def _brake(th: dict[str, float], v: np.ndarray, growing: np.ndarray) -> np.ndarray:
    """Paper 001 eq. (7), plus the velocity-strengthening D v the physics adds to it."""
    return mu_brake(v, th["mu0"], th["gamma"], th["alpha"], th["beta"]) + th["D"] * v


def _drum(th: dict[str, float], v: np.ndarray, growing: np.ndarray) -> np.ndarray:
    """Paper 002 eq. (3) as mu(|v|) sgn(v) (sgn regularised by eps), plus D v."""
    return mu_drum(v, th["A"], th["B"], th["C"], th["E"], th["eps"], 1.0) + th["D"] * v


def _belt(th: dict[str, float], v: np.ndarray, growing: np.ndarray) -> np.ndarray:
    """Paper 000 kinetic branches (accel-sign amp), in mu = F/F0 of v_rel = body - belt.

    The force on the body is F0 f(w) with w = (v_b - v)/v_u, so mu(v_rel) = f(v_rel/v_u)
    (f is odd). ``growing`` is 1 while |v_rel| grows, 0 while it shrinks. The break-away
    drop from the static limit is not fitted (f_s changes from one stick to the next); the
    fit excludes the samples right after each break-away.
    """
    u = np.abs(v) / th["v_u"]
    mag = f_pwl_piece(u, 2.0 * growing - 1.0, 0.0, 0.0, th["f_k0"], th["k_fall"], th["w_min"], th["k_rise"], th["amp"])
    return np.sign(v) * mag + th["D"] * v / th["v_u"]


@dataclass(frozen=True)
class LawDef:
    """A rig's law: parameter names, nominal values and bounds, which ones the fit frees."""

    rig: str
    fn: Callable[[dict[str, float], np.ndarray, np.ndarray], np.ndarray]
    nominal: dict[str, float]
    bounds: dict[str, tuple[float, float]]
    free: tuple[str, ...]

    def mu(self, v: np.ndarray, growing: np.ndarray | None = None, **override: float) -> np.ndarray:
        """mu(v_rel) with the nominal parameters, optionally overridden."""
        g = np.ones_like(v) if growing is None else growing
        return self.fn({**self.nominal, **override}, np.asarray(v, dtype=float), g)


def law_for(cfg: RigConfig, e: np.ndarray) -> LawDef:
    """The rig's law with the config's values as nominal and start point of the fit."""
    f = cfg.friction
    d = float(e[E.VS_D])
    if cfg.rig == "brake-2dof":
        return LawDef(cfg.rig, _brake,
                      {"mu0": f.mu0, "gamma": f.gamma_s_per_m, "alpha": f.alpha_s_per_m, "beta": f.beta, "D": d},
                      {"mu0": (0.0, 5.0), "gamma": (0.0, 100.0), "alpha": (1.0, 1e4), "beta": (0.0, 0.99),
                       "D": (-5.0, 20.0)},
                      ("mu0", "gamma"))  # alpha, beta shape |v| < 2/alpha = v_stick: see FitWindow.select
    if cfg.rig == "drum-pendulum":
        return LawDef(cfg.rig, _drum,
                      {"A": f.A, "B": f.B_s_per_m, "C": f.C_s_per_m, "E": f.E, "eps": f.sgn_eps_m_per_s, "D": d},
                      {"A": (0.0, 5.0), "B": (0.1, 1e4), "C": (0.0, 1e4), "E": (-1.0, 2.0), "eps": (1e-6, 0.1),
                       "D": (-5.0, 20.0)},
                      ("A", "C", "E", "D"))  # B trades off against A and C over |v| < 25 mm/s: held
    if cfg.rig == "belt-ndof":
        m = cfg.mechanics
        v_u = m.normal_force_N / np.sqrt(m.stiffness_N_per_m * m.mass_kg)
        return LawDef(cfg.rig, _belt,
                      {"f_k0": f.f_k0, "k_fall": f.k_fall, "w_min": f.w_min, "k_rise": f.k_rise,
                       "amp": float(e[E.AS_AMP]), "D": d, "v_u": float(v_u)},
                      {"f_k0": (0.0, 10.0), "k_fall": (-5.0, 10.0), "w_min": (1e-3, 10.0), "k_rise": (-5.0, 10.0),
                       "amp": (-0.5, 0.5), "D": (-5.0, 20.0), "v_u": (1e-6, 1e3)},
                      ("f_k0", "amp"))  # slips stay beyond w_min, where k_fall trades off against f_k0: held
    raise ValueError(f"no friction law for rig {cfg.rig!r}")
