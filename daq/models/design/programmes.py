"""The drive programmes a rig can run: the candidates for the next experiment (issue 26, `daq propose`).

Why a family, not an optimiser over free-form speed tables: the proposal must be a ramp file the daemon runs as it
is, which an operator can read before pressing start, and which a lab can repeat; the experiments that separate
friction effects are few and known (a deceleration ramp of another V0 or length changes speed and acceleration
together; an acceleration reverses the sign of the acceleration; velocity steps and slide-hold-slide vary how long a
contact has stuck, which is the only way to see aging of static friction at all: docs/examples/spring-slider.md).
A discrete family of these, each within the rig's limits, scored one by one, is also what a fixed protocol that
"sweeps every programme" would run, so the count of runs the proposal saves is measured against the same set.

Two families, by the rig's default programme (``[drive] ramp``):

- ``seed`` (the brake's deceleration ramps, paper 001 eq. 11): decelerations from other V0 and over other
  durations, accelerations (the sign of dv/dt reversed), velocity steps between two speeds, holds at three speeds;
- ``constant`` (the spring-slider, the drum): other constant speeds, velocity steps between the record's speed and
  another, slide-hold-slide with three hold series at the record's speed and at half of it.

Every programme is built from :mod:`daq.ramps` segments, passes ``ramp_table`` and ``check_limits`` with the rig's
speed and acceleration limits (what the daemon's ramp runner checks before any motion), and lasts at most
``max_s``. Each change of speed takes at least what the rig's acceleration limit allows (``rise_s``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import tomli_w

from daq.config import RigConfig, Strict
from daq.errors import InputError
from daq.ramps import Ramp, Segment, check_limits, ramp_table

# What a programme varies, for the proposal's text and for tests that ask "does it vary stick times?"
Varies = Literal["speed", "acceleration", "stick time", "hold time"]

SEED_FRACTIONS = (0.35, 0.6, 1.0, 1.5, 2.1, 3.0)  # decelerations' V0 as multiples of the record's V0 (capped)
SEED_DURATIONS = (10.0, 20.0, 40.0)  # s, before ``max_s`` caps them
CONSTANT_FACTORS = (0.1, 0.25, 0.5, 1.5, 2.0, 3.0, 4.0)  # other constant speeds, x the record's (0.1: a creep dwell)
STEP_FACTORS = (0.25, 0.5, 2.0, 4.0)  # velocity steps: V0 <-> V0 x this
STEP_PAIRS = (1, 3)  # a velocity-steps programme: V0, V1 this many times over
HOLD_SERIES = ((1.0, 3.0, 10.0), (3.0, 10.0, 30.0), (1.0, 10.0, 30.0))  # slide-hold-slide hold times [s]
HOLD_SCALE = (1.0, 0.5, 0.25)  # each series also scaled down, for short runs (first that fits wins)
MIN_SLIDE_S = 1.0  # a slide or plateau shorter than this shows no steady sliding: the programme is left out


class Programme(Strict):
    """One candidate drive programme: its ramp (what the daemon runs), how long it lasts, what it varies."""

    name: str
    ramp: Ramp
    duration_s: float
    varies: tuple[Varies, ...]

    def table(self) -> tuple[np.ndarray, np.ndarray]:
        """The programme as the simulator and the daemon's set-point generator evaluate it: (t, v)."""
        return ramp_table(self.ramp, self.name)

    def toml(self) -> str:
        """The ramp file's text (``daq ctl ramp FILE`` and ``daq sim --ramp FILE`` read it as it is)."""
        return ramp_toml(self.ramp)


def ramp_toml(ramp: Ramp) -> str:
    """A ramp as the TOML of a ramp file (unset fields left out, so the file reads as one written by hand)."""
    return tomli_w.dumps(ramp.model_dump(mode="json", exclude_none=True))


def write_programme(p: Programme, path: str | Path) -> Path:
    """Write ``p`` as a ramp file (the proposal's ``-o next.toml``)."""
    path = Path(path)
    path.write_text(f"# {p.name}: varies {', '.join(p.varies)}; {p.duration_s:.1f} s\n" + p.toml())
    return path


def family(cfg: RigConfig, v0: float, max_s: float, source: str = "--max-run-s") -> list[Programme]:
    """The programmes of ``cfg``'s rig around its record's drive speed ``v0`` [m/s], each at most ``max_s`` long and
    within the rig's limits, in a fixed order (the order a protocol that sweeps them all would run them in)."""
    drive = cfg.drive
    if not 0.0 < v0 <= drive.max_speed_m_per_s:
        raise InputError(source, "V0", f"{v0:.4g} m/s: the record's drive speed must be in (0, "
                                       f"{drive.max_speed_m_per_s}] m/s, the rig's limit")
    if not max_s >= 4 * MIN_SLIDE_S:
        raise InputError(source, "max_s", f"{max_s:g} s: a programme needs at least {4 * MIN_SLIDE_S:g} s")
    make = _seed_family if drive.ramp == "seed" else _constant_family
    out, names = [], set()
    for name, varies, segments, start in make(v0, max_s, drive.max_speed_m_per_s, drive.max_accel_m_per_s2):
        if name in names:
            continue
        ramp = Ramp(name=name, start_m_per_s=start, segment=segments)
        rt, rv = ramp_table(ramp, name)
        check_limits(rt, rv, drive.max_speed_m_per_s, drive.max_accel_m_per_s2, name)
        if rt[-1] > max_s * (1 + 1e-9):
            continue
        names.add(name)
        out.append(Programme(name=name, ramp=ramp, duration_s=float(rt[-1]), varies=varies))
    return out


def _rise(dv: float, max_accel: float) -> float:
    """The time a change of speed dv takes at the rig's acceleration limit (with 1 % to spare), at least 10 ms."""
    return max(0.01, 1.01 * abs(dv) / max_accel)


def _speeds(v0: float, factors: tuple[float, ...], vmax: float) -> list[float]:
    """v0 times each factor, at most vmax, rounded to 4 significant digits, without v0 and without repeats."""
    out: list[float] = []
    for f in factors:
        v = float(f"{min(v0 * f, vmax):.4g}")
        if all(abs(v - u) > 1e-9 for u in out) and abs(v - v0) > 1e-9 * v0:
            out.append(v)
    return out


def _seed_family(v0: float, max_s: float, vmax: float, amax: float):
    """Decelerations (seed ramps), accelerations, velocity steps and holds for a belt whose record was a ramp."""
    durations = sorted({min(d, max_s) for d in SEED_DURATIONS})
    for v in [v0, *_speeds(v0, SEED_FRACTIONS, vmax)]:
        for d in durations:
            for tmax in (d, 2 * d):  # to standstill, and to half the start speed
                if v / tmax > amax:
                    continue
                yield (f"decelerate {v:.4g} m/s over {tmax:g} s, run {d:g} s", ("speed", "acceleration"),
                       [Segment(kind="seed", V0_m_per_s=v, Tmax_s=tmax, duration_s=d)], None)
    low = float(f"{0.02 * v0:.4g}")
    for v in [v0, *_speeds(v0, SEED_FRACTIONS, vmax)]:
        for d in durations:
            if (v - low) / d > amax:
                continue
            yield (f"accelerate {low:.4g} -> {v:.4g} m/s over {d:g} s", ("speed", "acceleration"),
                   [Segment(kind="linear", duration_s=d, to_m_per_s=v)], low)
    for v1 in _speeds(v0, (1 / 3, 0.5, 2.0), vmax):
        yield from _steps(v0, v1, 2, max_s, amax, ("speed",))
    for v in [v0, *_speeds(v0, (1 / 3, 2.0), vmax)]:
        yield (f"hold {v:.4g} m/s for {max_s:g} s", ("speed",), [Segment(kind="hold", duration_s=max_s)], v)


def _steps(v0: float, v1: float, pairs: int, run_s: float, amax: float, varies: tuple[Varies, ...]):
    """Velocity steps V0, V1 (``pairs`` times over) from V0, the plateaus of one load-point travel filling run_s."""
    plateaus = [v0, v1] * pairs
    rises = (len(plateaus) - 1) * _rise(v1 - v0, amax)
    slip = (run_s - rises) / sum(1.0 / s for s in plateaus)
    if slip / max(plateaus) >= MIN_SLIDE_S:
        yield (f"steps {v0:.4g} <-> {v1:.4g} m/s x{pairs} in {run_s:g} s", varies,
               [Segment(kind="velocity-steps", speeds_m_per_s=plateaus, slip_m=slip, rise_s=_rise(v1 - v0, amax))],
               v0)


def _constant_family(v0: float, max_s: float, vmax: float, amax: float):
    """Other constant speeds, velocity steps and slide-hold-slide for a slider or drum whose record was at one speed,
    each over the whole run and over half of it."""
    for run_s in (max_s, max_s / 2):
        for v in _speeds(v0, CONSTANT_FACTORS, vmax):
            yield (f"constant {v:.4g} m/s for {run_s:g} s", ("speed", "stick time"),
                   [Segment(kind="hold", duration_s=run_s)], v)
        for v1 in _speeds(v0, STEP_FACTORS, vmax):
            for pairs in STEP_PAIRS:
                yield from _steps(v0, v1, pairs, run_s, amax, ("speed", "stick time"))
        for v in [v0, *_speeds(v0, (0.5,), vmax)]:
            rise = _rise(v, amax)
            for series in HOLD_SERIES:
                for scale in HOLD_SCALE:
                    holds = [h * scale for h in series]
                    slide_s = (run_s - sum(holds) - 2 * len(holds) * rise) / (len(holds) + 1)
                    if slide_s >= MIN_SLIDE_S:
                        yield (f"slide-hold-slide at {v:.4g} m/s, holds {', '.join(f'{h:g}' for h in holds)} s, "
                               f"in {run_s:g} s", ("stick time", "hold time"),
                               [Segment(kind="slide-hold-slide", to_m_per_s=v, slip_m=slide_s * v, holds_s=holds,
                                        rise_s=rise)], v)
                        break
