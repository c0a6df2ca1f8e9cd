"""Measurements as a model sees them: which signals it predicts, their noise, the drive, window start states.

Why per rig: each rig measures different things (brake: positions only; drum:
angle, velocity, thrust; belt: mass positions) and a simulated window needs a
full state at its start. Here the base (RigData), what every rig shares and the registry that finds a rig's own
(data_smooth.py: brake-2dof and drum-pendulum; data_belt.py: belt-ndof); the physics stays in daq/physics and the
fitting in daq/models/fit/shooting.py.

belt-ndof's hybrid window starts, stick threshold and spike repair: docs/decisions/0021-belt-ndof-in-the-model-loop.md.
"""

from __future__ import annotations

import importlib
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from daq.config import RigConfig
from daq.errors import InputError
from daq.io.interchange import Recording
from daq.io.loading import MODEL_CHANNELS
from daq.physics.effects import DC_MIN, E, stick_rates
from daq.physics.jit import kernel
from daq.signals import block_mean, impulsive_runs, noise_sigma, sg
from daq.sim.rigs import SimRig

DRIVE_SMOOTH_S = 0.25  # the measured drive is smoothed over +-this: drive ripple and lag live at seconds, the
# tachometer's noise at milliseconds
SPIKE_SIGMAS = 10.0  # a run of samples this many noise levels off the cubic through its neighbours is a spike
FREE_POSITIONS_BELOW_HZ = 750.0  # at 1 kHz a lightly smoothed start position is ~sigma/3 off, at 500 Hz ~sigma; between
# the two common rates, so that a recording at 999.9 or 1000.1 Hz (a daemon's measured rate) is treated as 1 kHz


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


# each rig's data, imported when a session first asks for it (python-can's interface registry does the same): the
# rigs' modules import this one for RigData, so this one names them instead of importing them
RIG_DATA: dict[str, tuple[str, str]] = {"brake-2dof": ("data_smooth", "BrakeData"),
                                        "drum-pendulum": ("data_smooth", "DrumData"),
                                        "belt-ndof": ("data_belt", "BeltData")}


def rig_data(cfg: RigConfig, source: str = "model") -> RigData:
    """What the model sees of ``cfg``'s records: the rig's RigData."""
    where = RIG_DATA.get(cfg.rig)
    if where is None:
        raise InputError(source, "rig", f"model fitting is implemented for {', '.join(RIG_DATA)}, not {cfg.rig}")
    module, name = where
    return getattr(importlib.import_module(f"{__package__}.{module}"), name)(cfg)
