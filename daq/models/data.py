"""Measurements as a model sees them: which signals it predicts, their noise, the drive, window start states.

Why per rig: each rig measures different things (brake: positions only; drum:
angle, velocity, thrust; belt: mass positions) and a simulated window needs a
full state at its start. Everything rig-specific about *data* lives here; the
physics stays in daq/physics and the fitting in daq/models/shooting.py.

belt-ndof's hybrid window starts, stick threshold and spike repair: docs/decisions/0021-belt-ndof-in-the-model-loop.md.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from daq.config import RigConfig
from daq.errors import InputError
from daq.estimation.rsf_fit import fit_law, start_values
from daq.estimation.rsf_programme import events, load_point_travel, plateaus, programme_table
from daq.io.interchange import Recording
from daq.io.loading import MODEL_CHANNELS
from daq.physics import beltndof, brake2dof, drum
from daq.physics.contact import AUX
from daq.physics.effects import DC_MIN, TAIL, E, stick_rates
from daq.physics.jit import kernel
from daq.signals import block_mean, impulsive_runs, noise_sigma, sg
from daq.sim.rigs import SimRig

from .cycle_features import load_cycles

DRIVE_SMOOTH_S = 0.25  # the measured drive is smoothed over +-this: drive ripple and lag live at seconds, the
# tachometer's noise at milliseconds
SPIKE_SIGMAS = 10.0  # a run of samples this many noise levels off the cubic through its neighbours is a spike
FREE_POSITIONS_BELOW_HZ = 750.0  # at 1 kHz a lightly smoothed start position is ~sigma/3 off, at 500 Hz ~sigma; between
# the two common rates, so that a recording at 999.9 or 1000.1 Hz (a daemon's measured rate) is treated as 1 kHz
# belt-ndof's model steps per period of the chain's fastest linear mode (BeltData.model_step). Measured on the
# belt seed model, one mass (3.2 Hz), each window of the 750 000-sample bench record simulated at 0.5 ms and at
# the coarser step: see docs/decisions/0023-a-model-rate-for-long-records.md.
STEPS_PER_PERIOD = 100


@dataclass
class Measured:
    """One recording prepared for a rig's model."""

    rig: str
    source: str
    t: np.ndarray
    rate: float
    outputs: dict[str, np.ndarray]  # the signals a model predicts
    units: dict[str, str]
    sigma: dict[str, float]  # white-noise level per output
    sigma_source: dict[str, str]
    drive_measured: np.ndarray  # surface speed of belt/drum [m/s], smoothed
    drive_command: np.ndarray  # what the base model is driven with [m/s]
    command_source: str
    temp: np.ndarray | None
    context: dict[str, np.ndarray] = field(default_factory=dict)  # quantities residuals may correlate with
    aging: dict[object, np.ndarray] = field(default_factory=dict)  # the contact's state along the data, per Dc (law)
    v_rel: np.ndarray | None = None  # data-derived relative sliding speed (for regimes)
    d_abs_v_rel: np.ndarray | None = None
    v_stick: float | None = None  # |v_rel| below this is stuck in these data (None: the rig config's v_stick)
    outliers: dict[str, np.ndarray] = field(default_factory=dict)  # per output, the file's indices of repaired spikes
    averaged: int = 1  # the file's samples per sample here (block means down to the model's rate, RigData.prepare)
    recording: Recording | None = None  # the samples the model sees: spikes repaired, block-averaged

    def stick_threshold(self, cfg: RigConfig) -> float:
        return self.v_stick if self.v_stick is not None else cfg.contact.v_stick_m_per_s

    @property
    def primary(self) -> str:
        return next(iter(self.outputs))

    @property
    def n(self) -> int:
        return self.t.size


class RigData(ABC):
    drive_channel: str = ""  # the channel that measures the drive (belt or drum speed)
    """What a rig's model needs from data: predicted signals and the state at a window's start."""

    rig: str
    velocity_slots: tuple[int, ...]  # state entries estimated per window (free in multiple shooting)
    position_slots: tuple[int, ...] = ()  # measured state entries, also free per window at slow sampling

    def start_slots(self, rate: float) -> tuple[int, ...]:
        """State entries each window's fit estimates: the velocities, and below FREE_POSITIONS_BELOW_HZ the positions.

        Why positions too at slow sampling: a window's start position is one raw sample (a local
        smoother at 100 Hz would bend through the nearest slip); its noise then offsets the whole
        window and the error floor of a perfect model rises to ~sqrt(2) sigma (7.1 um for 5 um noise
        on brake-2dof), burying weak effects (stick-time at seed strength: 2 % above that floor).
        Estimated from the window's samples, start sample included as a measurement, the floor is
        ~sigma (4.8 um) and stick-time at 100 Hz is found (docs/recovery-table.md).

        Why 500 Hz too: the start position's smoother there spans 7 samples (~0.6-1 sigma of noise left), and in a
        window that starts stuck the position is the only start value (the velocity is the drive's), so its offset
        moves the first break-away and the phase of every cycle after it. Measured on the reference spring-slider
        (Dieterich aging, 40 s at 500 Hz, noise 5e-4 and steps 1e-3 of F/mg): the true model scored 3.9 um on
        held-out windows from the smoothed sample, worse than the aging-free seed model fitted (3.2 um), so the
        aging a run must look for was "ruled out" by its own record; with the position estimated, ~the noise.
        """
        return self.velocity_slots + (self.position_slots if rate < FREE_POSITIONS_BELOW_HZ else ())

    def __init__(self, cfg: RigConfig) -> None:
        self.cfg = cfg
        self.averaged = 1  # of the recording prepare() last read

    def prepare(self, rec: Recording, source: str) -> Measured:
        for ch in MODEL_CHANNELS[self.rig]:
            if ch not in rec.channels:
                raise InputError(source, ch, f"missing column (a {self.rig} model needs {', '.join(MODEL_CHANNELS[self.rig])})")
            if not np.all(np.isfinite(rec.channels[ch])):
                raise InputError(source, ch, "contains NaN or infinite values")
        t = np.asarray(rec.t, dtype=float)
        dt = np.diff(t)
        if t.size < 50:
            raise InputError(source, "t", f"{t.size} samples: too few to compare a model with")
        rate = 1.0 / float(np.median(dt))
        if np.max(np.abs(dt * rate - 1.0)) > 0.01:
            raise InputError(source, "t", "samples must be evenly spaced (resample first)")
        self.averaged = 1
        channels, outliers = dict(rec.channels), {}
        for name in self.output_channels():
            if name in channels:
                channels[name], idx = self._despike(name, np.asarray(channels[name], dtype=float))
                if idx.size:
                    outliers[name] = idx
        q = max(1, int(rate * self.model_step() + 1e-9))
        if q > 1 and t.size // q >= 50:  # sampled faster than the model steps: block means, one per model step
            channels = {k: block_mean(np.asarray(v, dtype=float), q) for k, v in channels.items()}
            t = block_mean(t, q)
            rate /= q
            self.averaged = q
        if outliers or q > 1:
            rec = Recording(rec.rig, t, channels, rec.units, {**rec.meta, "averaged": self.averaged},
                            rec.truth if q == 1 else {}, rec.events)
        m = self._prepare(rec, t, rate, source)
        m.outliers = outliers
        m.averaged = self.averaged
        m.recording = rec
        return m

    def model_step(self) -> float:
        """The model's integrator step [s]: the rig config's. A record sampled more than once per step is
        block-averaged down to one sample per step before anything reads it (what finer samples add, the
        model cannot use; they cost simulation time in every window)."""
        return self.cfg.integrator.dt_s

    def output_channels(self) -> tuple[str, ...]:
        """The channels the model predicts (where single-sample spikes are repaired before anything reads them)."""
        return tuple(c for c in MODEL_CHANNELS[self.rig] if c not in (self.drive_channel, "thrust", "drum_speed"))

    def _despike(self, name: str, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Spikes (impulsive noise: single samples and bursts of up to three) replaced by the cubic through the two
        samples on each side (daq.signals.impulsive_runs).

        Why repair, not the robust loss alone: a spike also corrupts everything computed from the samples
        around it before any fit runs (the smoothed velocities that say where the contact sticks, so the stick
        clock aging is read from, each window's start state); and a spike of 100 noise units dominates the rms
        error a user is shown. A run is a spike when every sample of it stands more than SPIKE_SIGMAS noise levels
        off the cubic through its neighbours (a smooth motion, stick-slip kinks included, is predicted to a
        fraction of the noise). Counted per channel and shown (``outliers`` in compare's and diagnose's JSON).
        What is left (glitches under the threshold) the fit's Huber loss caps (robust.py).
        """
        if x.size < 5:
            return x, np.zeros(0, dtype=int)
        # the noise the samples show, but never below what the instrument declares: a slow creep read through a
        # coarse quantiser has third differences that are mostly 0 (a data estimate of 0), and each of its steps
        # would read as a spike (seen: 22 of 2000 samples "repaired" on a noise-free 20 um/s creep at 10 um steps)
        est = float(noise_sigma(x))
        sigma = max(est if np.isfinite(est) else 0.0, self._declared_sigma(name))
        if sigma <= 0.0:  # no noise level known: nothing can be called a spike
            return x, np.zeros(0, dtype=int)
        out, idx = impulsive_runs(x, SPIKE_SIGMAS * sigma)
        return (out, idx) if idx.size else (x, idx)

    @abstractmethod
    def _prepare(self, rec: Recording, t: np.ndarray, rate: float, source: str) -> Measured: ...

    @abstractmethod
    def predict(self, sim: SimRig, states: np.ndarray) -> dict[str, np.ndarray]:
        """The output signals from simulated states (last axis = state)."""

    def output_rates(self, sim: SimRig, states: np.ndarray, dt: float) -> dict[str, np.ndarray]:
        """The outputs' time derivatives from simulated states (samples on the second-to-last axis): what a sample
        taken early or late by clock jitter reads wrong, per second of it. Here by differences at the sample
        rate; rigs whose outputs are states override it with the states' own rates (exact through a slip)."""
        return {k: np.gradient(x, dt, axis=-1) for k, x in self.predict(sim, states).items()}

    @abstractmethod
    def start_state(self, sim: SimRig, m: Measured, i: int) -> np.ndarray:
        """Full state (mechanics + contact tail) at sample i, velocities from the data."""

    def law_guess(self, m: Measured) -> dict[str, float]:
        """A first guess of the friction law's levels from the data (parameter name -> value), for a fit to start
        from besides the model file's values; empty where the rig has none (the config's law is the start)."""
        return {}

    def effect_guess(self, m: Measured, name: str, form: str | None, v_ref: float) -> dict[str, float]:
        """A start for an effect's parameters (and the law levels they shift) read from the data by a reduction of
        its own, or empty: the catalog's generic start is then the only one."""
        return {}

    def before_window(self, sim: SimRig, m: Measured, i: int, s0: np.ndarray) -> None:
        """Set whatever the simulator keeps besides the state vector for a run from ``s0`` at sample i (belt-ndof:
        each mass's stick/slip mode and stick clock; ``s0`` may be corrected in place). Smooth rigs keep nothing."""

    def synthetic_extras(self, sim: SimRig, states: np.ndarray, aux: np.ndarray, channels: dict[str, np.ndarray],
                         rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Channels besides the predicted outputs that a synthetic copy of the data must take from the model."""
        return {}

    def _drive(self, rec: Recording, t: np.ndarray, rate: float, measured: np.ndarray,
               command_channel: str | None) -> tuple[np.ndarray, np.ndarray, str]:
        smooth = sg(measured, rate, DRIVE_SMOOTH_S, degree=3)
        if command_channel and command_channel in rec.channels and np.all(np.isfinite(rec.channels[command_channel])):
            return smooth, np.asarray(rec.channels[command_channel], dtype=float), command_channel
        if is_programme(measured):
            # no noise at all: not a measurement but a programme (an imported `--map vb=...` constant or steps, as a
            # spring-slider's driver speed): it is the command, and smoothing would round its steps
            return measured.astype(float), measured.astype(float), f"{self.drive_channel} (noise-free: the programme)"
        # no command recorded: the slow trend of the measured speed (what a programme would have been)
        tt = (t - t[0]) / max(t[-1] - t[0], 1e-9)
        coef = np.polynomial.polynomial.polyfit(tt, measured, 3)
        return smooth, np.polynomial.polynomial.polyval(tt, coef), "cubic fit of the measured speed"

    def _sigma(self, name: str, x: np.ndarray) -> tuple[float, str]:
        """White-noise level of a channel: the data's estimate, capped by the instrument's declared figure.

        The third-difference estimate is an upper bound (at 100 Hz the motion itself leaks in), so
        where the rig config declares the instrument's noise the smaller of the two is the tighter
        bound we know. Without a declared figure the data estimate is all there is.
        """
        est = noise_sigma(x)
        nominal = self._declared_sigma(name)
        if nominal > 0:
            if not np.isfinite(est) or est >= nominal:
                return nominal, "rig config (the data's estimate is higher: signal leaks into it)"
            return max(est, 1e-12), "data"
        return (est if np.isfinite(est) and est > 0 else 1e-9), "data"

    def _declared_sigma(self, name: str) -> float:
        """The instrument's declared noise and quantisation of a channel (rig config), 0 where it declares none;
        in block means of ``averaged`` samples, sqrt(averaged) times less."""
        ch = self.cfg.channels.get(name)
        level = math.sqrt(ch.noise_std**2 + ch.lsb**2 / 12.0) if ch is not None else 0.0
        return level / math.sqrt(self.averaged)

    def _temp(self, rec: Recording, rate: float) -> np.ndarray | None:
        if "temp" in rec.channels and np.all(np.isfinite(rec.channels["temp"])):
            return sg(np.asarray(rec.channels["temp"], dtype=float), rate, 0.5, degree=1)
        return None


@kernel
def _stick_tail(v_rel, load_rate, dt, n_sub, v_stick, fr_tau, st_reset, ts_out, q_out):
    """The contact tail's stick clock and load-rate memory, integrated along the data's v_rel.

    Why integrate the model's own rates (effects.stick_rates) instead of counting
    stuck samples: the clock's rise and decay depend on how deep the contact sticks;
    a window starting with a clock the model would not have produced starts wrong.
    """
    ts = 0.0
    q = load_rate[0]
    h = dt / n_sub
    for i in range(v_rel.size):
        ts_out[i] = ts
        q_out[i] = q
        for _ in range(n_sub):
            d_ts, d_q = stick_rates(v_rel[i], load_rate[i], ts, q, v_stick, fr_tau, st_reset)
            ts += h * d_ts
            q += h * d_q


@kernel
def _dieterich_tail(v_rel, dt, dc, out):
    """Dieterich's aging law d theta/dt = 1 - |v| theta/Dc along the data, solved exactly per sample (v held)."""
    th = 0.0
    for i in range(v_rel.size):
        out[i] = th
        v = abs(v_rel[i])
        k = v * dt / dc
        if k < 1e-9:
            th += dt
        else:
            ss = dc / v
            th = ss + (th - ss) * math.exp(-k)


@kernel
def _rsf_state_tail(v, v_start, dt, dc, v_ref, law, out):
    """Rate-and-state's state psi = ln(v_ref theta / Dc) along the data's slip speed v (>= 0), each sample solved
    exactly with v held (aging: theta relaxes to Dc/v, or grows by dt at rest; slip: psi relaxes to ln(v_ref/v),
    held at rest), from steady state at v_start."""
    v0 = max(v_start, v_ref)
    psi = math.log(v_ref / v0)
    for i in range(v.size):
        out[i] = psi
        vi = v[i]
        k = vi * dt / dc
        if law == 0:  # aging, in theta
            th = dc / v_ref * math.exp(psi)
            if k < 1e-9:
                th += dt
            else:
                ss = dc / vi
                th = ss + (th - ss) * math.exp(-k)
            psi = math.log(v_ref * th / dc)
        elif k > 0.0:
            ss = math.log(v_ref / vi)
            psi = ss + (psi - ss) * math.exp(-k)


RSF_GUESS_EVENTS = 8  # events the rate-and-state start reads (the first; each is a fit of ~10-50 ms)
RSF_SPEED_S = 0.05  # the slip speed the state reads: the data's v_rel averaged over this long (a slip keeps its length)


def rsf_state_at(sim: SimRig, m: Measured, i: int) -> float:
    """Rate-and-state's contact state at sample i for this model (its law, Dc and v_ref): integrated along the
    data's slip speed (cached per parameter set, as the aging clock is). Why not steady state at the drive's speed:
    a window that starts within a few Dc of a velocity step starts with the state of the speed before it."""
    e = sim.e
    law = 1 if e[E.RS_B_SLIP] != 0.0 else 0
    key = ("rsf", law, float(e[E.RS_DC]), float(e[E.RS_VREF]))
    psi = m.aging.get(key)
    if psi is None:
        if len(m.aging) > 64:
            m.aging.clear()
        w = max(1, int(round(RSF_SPEED_S * m.rate)))
        padded = np.pad(np.asarray(m.v_rel, dtype=float), (w // 2, w - 1 - w // 2), mode="edge")
        v = np.abs(np.convolve(padded, np.ones(w) / w, mode="valid"))
        psi = np.empty(m.n)
        v_start = abs(float(np.median(m.v_rel[:max(1, int(m.rate))])))  # the first second's (v_rel is noisy)
        _rsf_state_tail(np.ascontiguousarray(v, dtype=float), v_start, 1.0 / m.rate, float(e[E.RS_DC]), float(e[E.RS_VREF]),
                        law, psi)
        m.aging[key] = psi
    return float(psi[i])


def clock_at(sim: SimRig, m: Measured, i: int) -> float:
    """The contact's clock at sample i for this model: the stick clock, or Dieterich's state where the model's
    log-aging form asks for it (its Dc is a fitted parameter: the state is integrated along the data per Dc)."""
    dc = float(sim.e[E.ST_DC])
    if dc <= 0.0 or sim.e[E.ST_LOG_GAIN] == 0.0:
        return float(m.context["stick_clock"][i])
    dc = max(dc, DC_MIN)
    th = m.aging.get(dc)
    if th is None:
        if len(m.aging) > 64:  # a fit visits many Dc; keep the cache small
            m.aging.clear()
        th = np.empty(m.n)
        _dieterich_tail(np.ascontiguousarray(m.v_rel, dtype=float), 1.0 / m.rate, dc, th)
        m.aging[dc] = th
    return float(th[i])


def stick_tail(v_rel: np.ndarray, load_rate: np.ndarray, rate: float, cfg: RigConfig) -> tuple[np.ndarray, np.ndarray]:
    c = cfg.contact
    n_sub = max(1, int(math.ceil((1.0 / rate) / min(2e-4, 0.2 * c.stick_reset_tau_s))))
    ts, q = np.empty(v_rel.size), np.empty(v_rel.size)
    _stick_tail(np.ascontiguousarray(v_rel, dtype=float), np.ascontiguousarray(load_rate, dtype=float),
                1.0 / rate, n_sub, c.v_stick_m_per_s, c.force_rate_tau_s, c.stick_reset_tau_s, ts, q)
    return ts, q


class BrakeData(RigData):
    drive_channel = "vb"  # the measured drive: belt speed [m/s]
    rig = "brake-2dof"
    velocity_slots = (1, 3)
    position_slots = (0, 2)

    def _prepare(self, rec, t, rate, source):
        x1 = np.asarray(rec.channels["x1"], dtype=float)
        phi = np.asarray(rec.channels["phi"], dtype=float)
        vb = np.asarray(rec.channels["vb"], dtype=float)
        drive_m, drive_c, csrc = self._drive(rec, t, rate, vb, "vb_set")
        sig = {}
        src = {}
        for name, x in (("x1", x1), ("phi", phi)):
            sig[name], src[name] = self._sigma(name, x)
        r = self.cfg.mechanics.r_m
        half = 0.006 if rate >= 500 else 1.5 / rate
        x1d = sg(x1, rate, half, 1)
        y1d = r * sg(phi, rate, half, 1)
        v_rel = x1d - drive_m
        m = Measured(self.rig, source, t, rate, {"x1": x1, "phi": phi}, {"x1": "m", "phi": "rad"}, sig, src,
                     drive_m, drive_c, csrc, self._temp(rec, rate))
        m.v_rel = v_rel
        m.d_abs_v_rel = sg(np.abs(v_rel), rate, half, 1, degree=2)
        mech = self.cfg.mechanics
        load_rate = (mech.k1_N_per_m + mech.k2_N_per_m) * x1d + mech.k2_N_per_m * y1d  # as brake2dof.rhs
        ts, q = stick_tail(v_rel, load_rate, rate, self.cfg)
        # start positions: lightly smoothed at kHz rates; at 100 Hz a local cubic over +-30 ms would bend
        # through the nearest slip (bias ~100 um), while the raw sample is off by the sensor noise only
        pos = (lambda x: sg(x, rate, half)) if rate >= 500 else (lambda x: x)
        m.context = {"x1_smooth": pos(x1), "y1_smooth": r * pos(phi), "x1_dot": x1d,
                     "y1_dot": y1d, "stick_clock": ts, "load_rate": q}
        return m

    def predict(self, sim, states):
        return {"x1": states[..., 0], "phi": states[..., 2] / sim.p[brake2dof.P.r]}

    def output_rates(self, sim, states, dt):
        return {"x1": states[..., 1], "phi": states[..., 3] / sim.p[brake2dof.P.r]}

    def start_state(self, sim, m, i):
        c = m.context
        s = np.zeros(brake2dof.N_STATE)
        s[0], s[1], s[2], s[3] = c["x1_smooth"][i], c["x1_dot"][i], c["y1_smooth"][i], c["y1_dot"][i]
        n = brake2dof.N_MECH
        s[n + TAIL.TS] = clock_at(sim, m, i)
        s[n + TAIL.Q] = c["load_rate"][i]
        s[n + TAIL.TEMP] = m.temp[i] if m.temp is not None else self.cfg.contact.t_ambient_C
        s[n + TAIL.VLAG] = m.drive_measured[i]
        return s


class DrumData(RigData):
    drive_channel = "drum_speed"  # the measured drive: drum speed [rad/s]
    """drum-pendulum: predicts phi and the surface velocity; the runout phase comes from the thrust gauge."""

    rig = "drum-pendulum"
    velocity_slots = (1,)
    position_slots = (0,)

    def _prepare(self, rec, t, rate, source):
        R = self.cfg.mechanics.R_m
        phi = np.asarray(rec.channels["phi"], dtype=float)
        vel = np.asarray(rec.channels["vel"], dtype=float)
        thrust = np.asarray(rec.channels["thrust"], dtype=float)
        wd = np.asarray(rec.channels["drum_speed"], dtype=float)
        drive_m, drive_c, csrc = self._drive(rec, t, rate, R * wd, None)
        sig, src = {}, {}
        for name, x in (("phi", phi), ("vel", vel)):
            sig[name], src[name] = self._sigma(name, x)
        half = 0.003 if rate >= 500 else 1.5 / rate
        w = sg(vel, rate, half, 0) / R
        v_rel = R * w - drive_m
        m = Measured(self.rig, source, t, rate, {"phi": phi, "vel": vel}, {"phi": "rad", "vel": "m/s"}, sig, src,
                     drive_m, drive_c, csrc, self._temp(rec, rate))
        m.v_rel = v_rel
        m.d_abs_v_rel = sg(np.abs(v_rel), rate, half, 1, degree=2)
        # drum angle from the surface travel; its offset from the thrust gauge's runout (one fit per run)
        travel = np.concatenate([[0.0], np.cumsum(0.5 * (drive_m[1:] + drive_m[:-1]) / rate)])
        theta = travel / R
        p_nom, ro = self.cfg.mechanics.thrust_N, self.cfg.mechanics.runout
        rel = thrust / p_nom - 1.0
        a, b = np.linalg.lstsq(np.column_stack([np.sin(theta), np.cos(theta)]), rel, rcond=None)[0]
        theta0 = math.atan2(b, a) if ro > 0 and math.hypot(a, b) > 0.2 * ro else 0.0
        mech = self.cfg.mechanics
        load_rate = mech.k_N_per_m * mech.Rs_m**2 * np.cos(2.0 * phi) * w / R  # as drum.rhs
        ts, q = stick_tail(v_rel, load_rate, rate, self.cfg)
        m.context = {"phi_smooth": sg(phi, rate, half) if rate >= 500 else phi, "w": w, "travel": R * (theta + theta0),
                     "stick_clock": ts, "load_rate": q, "thrust": thrust}
        return m

    def predict(self, sim, states):
        return {"phi": states[..., 0], "vel": sim.p[drum.P.R] * states[..., 1]}

    def synthetic_extras(self, sim, states, aux, channels, rng):
        # the thrust gauge reads the model's normal load (its runout phase is the model's own)
        thrust = aux[:, AUX.N_INST]
        return {"thrust": thrust + rng.normal(0.0, noise_sigma(channels["thrust"]), thrust.size)}

    def start_state(self, sim, m, i):
        c = m.context
        s = np.zeros(drum.N_STATE)
        s[0], s[1] = c["phi_smooth"][i], c["w"][i]
        n = drum.N_MECH
        s[n + TAIL.TS] = clock_at(sim, m, i)
        s[n + TAIL.Q] = c["load_rate"][i]
        s[n + TAIL.TEMP] = m.temp[i] if m.temp is not None else self.cfg.contact.t_ambient_C
        s[n + TAIL.VLAG] = m.drive_measured[i]
        s[n + TAIL.POS] = c["travel"][i]
        return s


def is_programme(x: np.ndarray) -> bool:
    """A drive channel without noise: a programme written as numbers (a constant, steps, ramps), not a measurement.

    Judged on its updates, each taken once: an instrument slower than the sampling holds each reading (the drum's
    100 Hz tachometer repeats it ten times at 1 kHz), so the third differences of the samples are mostly 0 and
    read as no noise; the drum was then driven by a staircase (refsim's drum with nothing hidden: 23.97 um against
    a 20.51 um floor, belt-speed claimed; at the floor with the smoothed measurement). A programme's updates are
    few (steps) or lie on lines (ramps): no noise left, or too few to tell."""
    x = np.asarray(x, dtype=float)
    change = np.r_[True, np.diff(x) != 0.0]
    # steps: nearly every sample on a plateau held exactly for >= PROGRAMME_RUN samples (at 100 Hz a 10 ms change
    # between nine plateaus left 17 updates whose differences read as noise: the drive became a cubic fit)
    runs = np.diff(np.r_[np.flatnonzero(change), x.size])
    if x.size and runs[runs >= PROGRAMME_RUN].sum() >= 0.9 * x.size:
        return True
    updates = x[change]
    s = noise_sigma(updates)
    return not s > 1e-9 * float(np.max(np.abs(x)) if x.size else 0.0)  # (nan: under 11 updates)


PROGRAMME_RUN = 100  # samples: a held instrument reading repeats for ~10 (a 100 Hz tachometer at 1 kHz)


def stuck_by_hysteresis(v_rel: np.ndarray, v_lo: float, v_hi: float) -> np.ndarray:
    """Stuck samples: everything outside the runs of |v_rel| > v_lo that reach v_hi somewhere.

    Why hysteresis: one threshold near the velocity noise cuts a long stick into pieces wherever the noise
    crosses it (seen at a 1 mm/s drive: sticks of 0.3 s read as runs of 0.02-0.2 s), and a window that starts
    with a stick clock that short breaks away far too early once static friction ages with stick time. A real
    slip is fast; noise that crosses v_lo but never v_hi is still a stick."""
    above = np.abs(v_rel) > v_lo
    edges = np.diff(np.concatenate([[0], above.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    stuck = np.ones(v_rel.size, dtype=bool)
    big = np.abs(v_rel) > v_hi
    for a, b in zip(starts, stops):
        if big[a:b].any():
            stuck[a:b] = False
    return stuck


def stuck_time(stuck: np.ndarray, rate: float) -> np.ndarray:
    """Per sample, how long the contact has been stuck without a break [s] (0 where it slips)."""
    idx = np.arange(stuck.size)
    last_slip = np.maximum.accumulate(np.where(stuck, -1, idx))  # the latest slipping sample so far (-1: none)
    return np.where(stuck, (idx - last_slip) / rate, 0.0)


def last_stick(stuck_s: np.ndarray) -> np.ndarray:
    """Per sample, how long the stick that ended last before it lasted [s] (0 before the first stick ended)."""
    ended = np.flatnonzero((stuck_s[1:] == 0.0) & (stuck_s[:-1] > 0.0)) + 1  # first slipping sample after a stick
    out = np.zeros(stuck_s.size)
    if ended.size:
        which = np.searchsorted(ended, np.arange(stuck_s.size), side="right") - 1  # the latest end at or before
        held = which >= 0
        out[held] = stuck_s[ended[which[held]] - 1]
    return out


class BeltData(RigData):
    """belt-ndof (paper 000): predicts every mass's position; a window starts with each mass's stick/slip mode.

    Why a hybrid start: paper 000's law is discontinuous, so its simulator keeps each mass's mode (stuck or
    slipping), its stick clock and the break-away level beside the state vector (daq/physics/beltndof.py).
    A window's start sets them from the data: a mass whose smoothed velocity is within v_stick of the belt's
    is stuck, stuck since the first sample of that run (the stick clock the stick-time effect reads); a mass
    that slips started slipping at the static limit of its last stick (the break-away level its falling
    branch starts from).
    """

    drive_channel = "vb"
    rig = "belt-ndof"

    def __init__(self, cfg: RigConfig) -> None:
        super().__init__(cfg)
        self.n = cfg.mechanics.n_masses
        self.position_slots = tuple(range(self.n))
        self.velocity_slots = tuple(range(self.n, 2 * self.n))

    def _prepare(self, rec, t, rate, source):
        names = [f"x{i + 1}" for i in range(self.n)]
        for name in names:
            if name not in rec.channels:
                raise InputError(source, name, f"missing column (the rig has {self.n} masses: needs {', '.join(names)})")
        xs = {name: np.asarray(rec.channels[name], dtype=float) for name in names}
        vb = np.asarray(rec.channels["vb"], dtype=float)
        drive_m, drive_c, csrc = self._drive(rec, t, rate, vb, "vb_set")
        sig, src = {}, {}
        for name, x in xs.items():
            sig[name], src[name] = self._sigma(name, x)
        half = 0.006 if rate >= 500 else 1.5 / rate
        xd = {name: sg(x, rate, half, 1) for name, x in xs.items()}
        v_rel = xd["x1"] - drive_m
        m = Measured(self.rig, source, t, rate, xs, {name: "m" for name in names}, sig, src, drive_m, drive_c, csrc,
                     self._temp(rec, rate))
        m.v_rel = v_rel
        m.d_abs_v_rel = sg(np.abs(v_rel), rate, half, 1, degree=2)
        # stuck: within the contact's v_stick of the belt, or within the velocity's own noise where that is larger
        # (seen: 20 um tracker noise at 250 Hz puts 1.7 mm/s on the derivative; with the config's 1 mm/s alone
        # 17 % of the samples read stuck, against 56 % in the simulator's truth; with 4 sigma, 57 %)
        # and never more than a quarter of the drive's speed: the config's 1 mm/s is a belt rig's band at 0.2 m/s;
        # on a spring-slider driven at 1.1 mm/s it read every sample stuck (the slider's 3 mm/s swings included),
        # windows started in stick mode and a perfect model scored 5.6 um on 0.93 um of noise
        band = min(self.cfg.contact.v_stick_m_per_s, 0.25 * float(np.median(np.abs(drive_m))))
        v_stick = max(band, 4.0 * float(noise_sigma(v_rel)))
        m.v_stick = v_stick
        pos = (lambda x: sg(x, rate, half)) if rate >= 500 else (lambda x: x)
        travel = np.concatenate([[0.0], np.cumsum(0.5 * (drive_m[1:] + drive_m[:-1]) / rate)])
        m.context = {"travel": travel}
        for name in names:
            stuck = stuck_by_hysteresis(xd[name] - drive_m, v_stick, 3.0 * v_stick)
            m.context[f"{name}_smooth"] = pos(xs[name])
            m.context[f"{name}_dot"] = np.where(stuck, drive_m, xd[name])
            m.context[f"{name}_stuck_s"] = stuck_time(stuck, rate)
            # the stick that ended last before each sample: how long it lasted (the static limit it broke at)
            m.context[f"{name}_last_stick_s"] = last_stick(m.context[f"{name}_stuck_s"])
        m.context["stick_clock"] = m.context["x1_stuck_s"]
        return m

    def output_channels(self):
        return tuple(f"x{i + 1}" for i in range(self.n))

    def model_step(self):
        """STEPS_PER_PERIOD steps per period of the chain's fastest linear mode (never finer than the config's).
        Why coarser than the simulator's step: the hybrid integrator locates every event (stick, slip, a kink of
        the law) and between events RK4 integrates a smooth oscillator, whose error at 100 steps per period is
        far below any tracker's noise; the rig config's 0.5 ms is the simulator's, chosen so that 2 kHz
        sensors need no sub-steps. At 0.5 ms a 2 kHz record costs 6x the simulation it needs."""
        mech = self.cfg.mechanics
        f_max = float(np.max(beltndof.chain_modes(mech.mass_kg, mech.stiffness_N_per_m, mech.n_masses)))
        return max(self.cfg.integrator.dt_s, 1.0 / (STEPS_PER_PERIOD * f_max))

    def law_guess(self, m):
        """Break-away and kinetic levels of mass 1 from the spring force the data show (an equation-error pass
        without derivatives): at the last stuck sample before each slip the chain holds the static level; over
        the slips it oscillates about the kinetic level. Why: a contact far from the config's law (a user's
        f_s0 = 0.62 against the default 1.33) left the fit at 1061 um against a 2.4 um floor, stuck near the start.
        """
        mech = self.cfg.mechanics
        x = m.context["x1_smooth"]
        need = mech.stiffness_N_per_m * (2.0 * x - m.context["x2_smooth"] if self.n > 1 else x)
        stuck = m.context["x1_stuck_s"] > 0.0
        ends = np.flatnonzero(stuck[:-1] & ~stuck[1:])
        slip = ~stuck
        f0 = mech.normal_force_N
        if ends.size < 2 or slip.sum() < 10:
            return self._law_from_cycles(m, f0) if self.n == 1 else {}
        return {"friction.f_s0": float(np.median(need[ends]) / f0), "friction.f_k0": float(np.mean(need[slip]) / f0)}

    def _law_from_cycles(self, m, f0):
        """Where the data's v_rel cannot tell stick from slip (a spring-slider at 42 um/s: the speed's noise, 50 um/s,
        is above the drive), the load cycles can: the spring holds the static level at each peak, and an inertial
        slip from f_s overshoots the kinetic level as far again, so f_k = f_s - drop k / (2 F0). Without it the
        lab's 42 um/s record kept the config's f_s0 = 1.33 against a load of 0.37 F0: the model never slipped and
        the fit did not move."""
        k = self.cfg.mechanics.stiffness_N_per_m
        cyc = load_cycles(m.t, m.outputs["x1"], m.sigma["x1"])
        if cyc["peak"].size < 3:
            return {}
        f_s = float(np.median(cyc["peak"])) * k / f0
        return {"friction.f_s0": f_s, "friction.f_k0": f_s - float(np.median(cyc["drop"])) * k / (2.0 * f0)}

    def effect_guess(self, m, name, form, v_ref):
        """rate-and-state from the record's own velocity steps and holds, reduced as `daq analyse rsf` does (the
        quasi-static slider, each event on its own window; decision 31): the medians of a, b and Dc by the form's
        law, and the law's level that puts the steady friction where the events found it. Why: from a = b = 0 (or
        the generic a = 0.01) the fit of a velocity-stepping record stayed put or fell into Dc = 0.6 mm, 1.55 um
        against the seed model's 1.31 um; from the reduction's values it reached the floor. A record without steps
        or holds (one constant drive) gives no start."""
        if name != "rate-and-state" or self.n != 1:
            return {}
        mech = self.cfg.mechanics
        t = m.t
        mu = mech.stiffness_N_per_m * np.asarray(m.outputs["x1"]) / mech.normal_force_N
        plats = plateaus(m.drive_command)
        evs = events(t, plats)[:RSF_GUESS_EVENTS]
        if not evs:
            return {}
        rt, rv = programme_table(t, plats)
        travel = load_point_travel(t, rt, rv)
        law = "slip" if form == "slip" else "aging"
        got = []
        for ev in evs:
            sl = slice(ev.i_start, ev.i_end + 1)
            f = fit_law(ev, t[sl], mu[sl], rt, rv, law, start_values(ev, t[sl], mu[sl], travel[sl], None))
            if f.ok:
                got.append((f.a.value, f.b.value, f.Dc_m.value, f.mu0.value - f.a_minus_b.value * math.log(ev.v1 / v_ref)))
        if not got:
            return {}
        a, b, dc, level = (float(np.median(col)) for col in zip(*got))
        return {"effects.rate-and-state.a": a, "effects.rate-and-state.b": b, "effects.rate-and-state.dc": dc,
                "friction.f_k0": level, "friction.f_s0": level}

    def predict(self, sim, states):
        return {f"x{i + 1}": states[..., i] for i in range(self.n)}

    def output_rates(self, sim, states, dt):
        return {f"x{i + 1}": states[..., self.n + i] for i in range(self.n)}

    def start_state(self, sim, m, i):
        c, n = m.context, self.n
        s = np.zeros(beltndof.n_state(n))
        for k in range(n):
            s[k] = c[f"x{k + 1}_smooth"][i]
            s[n + k] = c[f"x{k + 1}_dot"][i]
        tail = 2 * n
        s[tail + TAIL.TEMP] = m.temp[i] if m.temp is not None else self.cfg.contact.t_ambient_C
        s[tail + TAIL.VLAG] = m.drive_measured[i]
        s[tail + TAIL.POS] = c["travel"][i]
        if sim.e[E.RS_DC] > 0.0:
            s[tail + TAIL.PSI] = rsf_state_at(sim, m, i)
        return s

    def before_window(self, sim, m, i, s0):
        c, n = m.context, self.n
        p, e = sim.p, sim.e
        t_rel = float(m.t[i] - m.t[0])
        vb = float(m.drive_measured[i])
        hs = beltndof.new_hybrid(n, p[beltndof.P.F_S0], 1.0)
        rate_need = p[beltndof.P.K] * vb  # paper 000's Delta for a mass on a steady belt: K S
        for k in range(n):
            stuck_s = float(c[f"x{k + 1}_stuck_s"][i])
            if stuck_s > 0.0:
                level = beltndof._static_limit(stuck_s, rate_need, p, e) + beltndof.state_term(s0, 2 * n, e)
                need = self._need_stuck(p, e, s0, k, vb)
                if abs(need) <= p[beltndof.P.F0] * level:
                    hs[beltndof.H.MODE, k] = beltndof.STICK
                    hs[beltndof.H.STICK_T0, k] = t_rel - stuck_s
                    # a stuck mass moves with the belt: its start velocity is no free value (a fit that moved it,
                    # seen at 1e3-4e7 m/s since nothing depended on it, made the contact chatter 3e5 times a window)
                    s0[n + k] = vb
                else:
                    # read stuck, but the springs at the start pull harder than the static limit holds: the mass
                    # broke away within the last samples (its slip speed still below the stick threshold). Started
                    # stuck it would break at once from u = 0, late, and slip too far (seen: a window starting 4 ms
                    # after a break, 21 um on a 1.4 um floor with the true law; the fit moved the start 9 um to
                    # compensate). It starts slipping, from the static level, on the drop, start velocity free.
                    hs[beltndof.H.SLIP_DIR, k] = 1.0 if need > 0.0 else -1.0
                    hs[beltndof.H.FS_BREAK, k] = level
            else:
                w = vb - float(c[f"x{k + 1}_dot"][i])
                hs[beltndof.H.SLIP_DIR, k] = 1.0 if w >= 0.0 else -1.0
                hs[beltndof.H.FS_BREAK, k] = beltndof._static_limit(float(c[f"x{k + 1}_last_stick_s"][i]), rate_need,
                                                                    p, e)
        sim.hybrid = hs

    @staticmethod
    def _need_stuck(p, e, s0, k, vb) -> float:
        """Friction [N] that would hold mass k stuck at the start state s0 on a belt at vb (its inertia on a
        steady belt neglected: a window's start velocity is all the data give)."""
        n = int(p[beltndof.P.N])
        K = p[beltndof.P.K]
        damp = e[E.D_BELT] * math.sqrt(K * p[beltndof.P.M])
        return damp * vb + beltndof.chain_at(s0[:n], k, n, K)


RIG_DATA: dict[str, type[RigData]] = {"brake-2dof": BrakeData, "drum-pendulum": DrumData, "belt-ndof": BeltData}


def rig_data(cfg: RigConfig, source: str = "model") -> RigData:
    cls = RIG_DATA.get(cfg.rig)
    if cls is None:
        raise InputError(source, "rig", f"model fitting is implemented for {', '.join(RIG_DATA)}, not {cfg.rig}")
    return cls(cfg)
