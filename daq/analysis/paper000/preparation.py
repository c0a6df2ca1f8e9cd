"""Paper 000's recordings made ready for the analyses: the rig's units, the belt speed, the noise, the sticks.

Why a step of its own: every analysis of the paper (the law identification and the
Poincaré section) reads the same things off a belt-ndof recording: positions of the
masses, the belt speed that drives them, the position noise, and where each mass
sticks to the belt. Bad input is refused here, once, naming the file and field.

Units: everything the law sees is dimensionless as in the paper's eq. (2) and our
rig config: x = K X / F0, t = tau / tau0 with tau0 = sqrt(M/K), w = (S - X') / v_u with
v_u = F0 / sqrt(K M), f = F / F0. The stick-time and force-rate effects keep the
catalog's units (tau [s], Delta and q0 [N/s]) so that results compare with
``daq sim --effect stick-time:tau=...`` directly.

Damping d is a rig property, not part of the friction law: it comes from the rig
config (``[seed_effects] viscous-damping.d``) unless given. It matters: d x' shifts
f by d s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict
from scipy.signal import savgol_coeffs

from daq.config import BeltRig, config_for_recording
from daq.errors import InputError
from daq.io.interchange import Recording
from daq.io.plausible import check_values
from daq.signals import noise_sigma, savgol

RIG = "belt-ndof"


# ----------------------------------------------------------------------------- data


class Mechanics(BaseModel):
    """What the analyses need to know about the rig: mechanics, damping, units of the scaling (2)."""

    model_config = ConfigDict(frozen=True)
    n_masses: int
    mass_kg: float
    stiffness_N_per_m: float
    normal_force_N: float
    d: float  # dimensionless viscous damping of eq. (3)
    q0_N_per_s: float  # force-rate reference rate (fixed in the static fit, as in daq.models)
    config_source: str

    @property
    def tau0(self) -> float:
        """Time unit sqrt(M/K) [s]."""
        return math.sqrt(self.mass_kg / self.stiffness_N_per_m)

    @property
    def x_unit(self) -> float:
        """Length unit F0/K [m]."""
        return self.normal_force_N / self.stiffness_N_per_m

    @property
    def v_unit(self) -> float:
        """Velocity unit F0/sqrt(K M) [m/s]."""
        return self.normal_force_N / math.sqrt(self.stiffness_N_per_m * self.mass_kg)


@dataclass
class BeltRun:
    """One belt-ndof recording prepared for the analyses (SI units; dimensionless helpers below)."""

    source: str
    cfg: BeltRig
    mech: Mechanics
    t: np.ndarray
    rate: float
    x: np.ndarray  # (n_masses, N) positions [m]
    vb: np.ndarray  # belt speed driving the analysis [m/s]
    vb_source: str
    sigma_x: np.ndarray  # position noise per mass [m]
    extra: dict[str, object] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return self.x.shape[0]

    @property
    def belt_travel(self) -> np.ndarray:
        """Belt travel [m] from the start (trapezoidal integral of vb)."""
        return np.concatenate([[0.0], np.cumsum(0.5 * (self.vb[1:] + self.vb[:-1]) * np.diff(self.t))])


def _config_for(rec: Recording, source: str, rig: str | None) -> BeltRig:
    """The rig config: --rig (id or TOML path), else the one stored in the recording, else the built-in."""
    return config_for_recording(rec.meta.get("rig_config"), source, rig, RIG,  # type: ignore[return-value]
                                "paper 000 analyses need")


def prepare(rec: Recording, source: str, rig: str | None = None, damping: float | None = None,
            min_samples: int = 200) -> BeltRun:
    """Check a recording and put it in the form the analyses need; bad input names the file and field."""
    if rec.rig not in (None, RIG):
        raise InputError(source, "rig", f"paper 000 analyses need a {RIG} recording, this is {rec.rig}")
    cfg = _config_for(rec, source, rig)
    masses = [f"x{i}" for i in (1, 2, 3) if f"x{i}" in rec.channels]
    if not masses or masses[0] != "x1" or masses != [f"x{i}" for i in range(1, len(masses) + 1)]:
        raise InputError(source, "x1", "missing column (need x1[, x2[, x3]] mass positions [m])")
    if "vb" not in rec.channels and "vb_set" not in rec.channels:
        raise InputError(source, "vb", "missing column (belt speed [m/s])")
    t = np.asarray(rec.t, dtype=float)
    if t.size < min_samples:
        raise InputError(source, "t", f"{t.size} samples: too few (need at least {min_samples})")
    dt = np.diff(t)
    rate = 1.0 / float(np.median(dt))
    if np.max(np.abs(dt * rate - 1.0)) > 0.01:
        raise InputError(source, "t", "samples must be evenly spaced (resample first)")
    check_values(source, t, rec.channels, cfg)  # non-finite or far outside the channel's range: one error
    x = np.vstack([np.asarray(rec.channels[m], dtype=float) for m in masses])
    if "vb_set" in rec.channels:
        vb, vsrc = np.asarray(rec.channels["vb_set"], dtype=float), "vb_set (command)"
    else:  # the tachometer's noise removed over +-0.05 s; belt programmes change slower than that
        vb = savgol(np.asarray(rec.channels["vb"], dtype=float), max(3, int(0.05 * rate)), degree=2)
        vsrc = "vb (smoothed)"
    if not np.any(vb > 0):
        raise InputError(source, "vb", "the belt never moves: nothing to identify")
    mech_cfg = cfg.mechanics
    d = damping if damping is not None else float(
        (cfg.seed_effects.get("viscous-damping") or {}).get("d", 0.0))
    fr = cfg.seed_effects.get("force-rate") or cfg.effects.get("force-rate") or {}
    mech = Mechanics(n_masses=len(masses), mass_kg=mech_cfg.mass_kg, stiffness_N_per_m=mech_cfg.stiffness_N_per_m,
                     normal_force_N=mech_cfg.normal_force_N, d=d, q0_N_per_s=float(fr.get("q0", 2.0)),
                     config_source=rig or ("recording" if "rig_config" in rec.meta else RIG))
    sig = np.array([noise_sigma(xi) for xi in x])
    for i, m in enumerate(masses):
        ch = cfg.channels.get(m)
        if ch is not None and (ch.noise_std > 0 or ch.lsb > 0):  # the third-difference estimate is an upper bound
            sig[i] = min(sig[i], math.hypot(ch.noise_std, ch.lsb / math.sqrt(12.0))) if sig[i] > 0 else \
                math.hypot(ch.noise_std, ch.lsb / math.sqrt(12.0))
        sig[i] = max(sig[i], 1e-9)
    return BeltRun(source, cfg, mech, t, rate, x, vb, vsrc, sig)


# ----------------------------------------------------------------------------- stick / slip from data


def sg_gain(half: int, deriv: int, degree: int = 3) -> float:
    """Noise gain of a centred Savitzky-Golay filter (per unit white input noise, per sample^deriv)."""

    c = savgol_coeffs(2 * half + 1, min(degree, 2 * half), deriv=deriv)
    return float(np.sqrt(np.sum(c * c)))


@dataclass
class Stick:
    """One stick episode of one mass: samples [start, end] (inclusive) move with the belt."""

    mass: int
    start: int  # first stuck sample
    end: int  # last stuck sample (the break-away follows)
    open_start: bool  # the stick began before the record (its stick time is unknown)
    open_end: bool  # the record ends stuck (no break-away)


def find_sticks(run: BeltRun, mass: int, half: int = 3, k_sigma: float = 4.0, min_len: int = 6) -> list[Stick]:
    """Stick episodes of one mass: where its velocity equals the belt's within the velocity noise.

    Velocity from a centred cubic Savitzky-Golay derivative over +-half samples; a
    sample is stuck when |x' - vb| < k_sigma * (its noise) + 1 % of the belt speed.
    The detected ends sit within ~half samples of the true transitions (the stage
    that needs the exact times, the output-error fit, finds them itself).
    """
    dt = 1.0 / run.rate
    v = savgol(run.x[mass], half, 1, dt)
    sig_v = run.sigma_x[mass] * sg_gain(half, 1) / dt
    stuck = np.abs(v - run.vb) < k_sigma * sig_v + 0.01 * np.abs(run.vb)
    edges = np.flatnonzero(np.diff(stuck.astype(np.int8)))
    starts = list(edges[stuck[edges + 1]] + 1)
    ends = list(edges[~stuck[edges + 1]])
    if stuck[0]:
        starts.insert(0, 0)
    if stuck[-1]:
        ends.append(stuck.size - 1)
    out = []
    travel = run.belt_travel
    for a, b in zip(starts, ends):
        if b - a + 1 < min_len:
            continue
        # a mass that only grazes the belt speed drifts against the belt: while truly stuck,
        # x - belt travel is constant within the noise (slope test over the inner samples)
        ia, ib = a + 1, b
        tt = run.t[ia:ib]
        if tt.size < 4:
            continue
        r = run.x[mass, ia:ib] - travel[ia:ib]
        slope = np.polyfit(tt - tt.mean(), r, 1)[0]
        se = run.sigma_x[mass] / math.sqrt(np.sum((tt - tt.mean()) ** 2))
        if abs(slope) > 5.0 * se:
            continue
        out.append(Stick(mass, int(a), int(b), a == 0, b >= stuck.size - 1 - half))
    return out
