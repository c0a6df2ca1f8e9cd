"""Belt/drum speed programmes: paper 001's deceleration ramp (eq. 11) and ramp files.

A ramp file is TOML with segments (hold, linear, exponential, deceleration, and the rate-and-state protocols
velocity-steps and slide-hold-slide) or a CSV table ``t,vb``. Every programme becomes a piecewise-linear table (t, v) that
the simulator, and later the daemon's set-point generator, evaluate. Speeds
are surface speeds in m/s (drum: circumferential speed at the friction radius).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field, ValidationError, field_validator

from .errors import InputError, parse_toml, read_text
from .strict import Closed

EXP_POINTS = 200  # samples per exponential segment in the table
# Paper 001's deceleration, eq. (11), is the segment kind "deceleration"; files written before it had that name say
# "seed", still read. Inside the code, in proposals and in recordings' ramp names the kind is still "seed" (the
# models' programme family writes it), so both names read to that one value.
DECELERATION, DECELERATION_OLD = "deceleration", "seed"


class Segment(Closed):
    model_config = ConfigDict(allow_inf_nan=False)
    kind: Literal["hold", "linear", "exponential", "deceleration", "seed", "velocity-steps", "slide-hold-slide"]
    duration_s: float | None = Field(None, gt=0.0)
    to_m_per_s: float | None = Field(None, ge=0.0, description="end speed (linear, exponential)")
    tau_s: float | None = Field(None, gt=0.0, description="time constant (exponential)")
    V0_m_per_s: float | None = Field(None, ge=0.0, description="deceleration: initial speed")
    Tmax_s: float | None = Field(None, gt=0.0, description="deceleration: time to standstill")
    speeds_m_per_s: list[float] | None = Field(None, min_length=1, description="velocity-steps: the plateaus' speeds")
    slip_m: float | None = Field(None, gt=0.0, description="velocity-steps, slide-hold-slide: load-point travel of "
                                                          "each sliding plateau")
    holds_s: list[float] | None = Field(None, min_length=1, description="slide-hold-slide: the hold times, in order")
    rise_s: float = Field(0.01, gt=0.0, description="velocity-steps, slide-hold-slide: duration of each change of "
                                                    "speed (the rig's acceleration limit applies to it)")

    @field_validator("kind")
    @classmethod
    def _one_name_for_the_deceleration(cls, kind: str) -> str:
        return DECELERATION_OLD if kind == DECELERATION else kind


class Ramp(Closed):
    model_config = ConfigDict(allow_inf_nan=False)
    name: str = "ramp"
    start_m_per_s: float | None = Field(None, ge=0.0)
    segment: list[Segment] = Field(min_length=1)


def seed_ramp(v0: float, tmax: float, duration: float | None = None) -> Ramp:
    """Paper 001 eq. (11): v_b = V0 (1 - t/Tmax)."""
    return Ramp(name=f"seed V0={v0} Tmax={tmax}", segment=[
        Segment(kind="seed", V0_m_per_s=v0, Tmax_s=tmax, duration_s=duration or tmax)])


def constant_ramp(v0: float, duration: float) -> Ramp:
    return Ramp(name=f"constant {v0}", start_m_per_s=v0, segment=[Segment(kind="hold", duration_s=duration)])


def _need(seg: Segment, i: int, attr: str, source: str):
    v = getattr(seg, attr)
    if v is None:
        raise InputError(source, f"segment[{i}].{attr}", f"required for a '{seg.kind}' segment")
    return v


def ramp_table(ramp: Ramp, source: str = "ramp") -> tuple[np.ndarray, np.ndarray]:
    """Piecewise-linear (t, v) table of a ramp; exact for hold, linear and seed segments."""
    first = ramp.segment[0]
    v = ramp.start_m_per_s
    if v is None:
        v = first.V0_m_per_s if first.kind == "seed" and first.V0_m_per_s is not None else None
    if v is None:
        raise InputError(source, "start_m_per_s", "required unless the first segment is 'seed'")
    ts = [0.0]
    vs = [float(v)]
    t = 0.0
    for i, seg in enumerate(ramp.segment):
        if seg.kind == "hold":
            t += _need(seg, i, "duration_s", source)
            ts.append(t)
            vs.append(v)
        elif seg.kind == "linear":
            t += _need(seg, i, "duration_s", source)
            v = _need(seg, i, "to_m_per_s", source)
            ts.append(t)
            vs.append(v)
        elif seg.kind == "exponential":
            dur = _need(seg, i, "duration_s", source)
            target = _need(seg, i, "to_m_per_s", source)
            tau = _need(seg, i, "tau_s", source)
            v_start = v
            for k in range(1, EXP_POINTS + 1):
                tt = dur * k / EXP_POINTS
                ts.append(t + tt)
                vs.append(target + (v_start - target) * math.exp(-tt / tau))
            t += dur
            v = vs[-1]
        elif seg.kind in ("velocity-steps", "slide-hold-slide"):
            t, v = _protocol(seg, i, t, v, ts, vs, source)
        else:  # seed
            v0 = _need(seg, i, "V0_m_per_s", source)
            tmax = _need(seg, i, "Tmax_s", source)
            dur = seg.duration_s or tmax
            if dur > tmax:
                raise InputError(source, f"segment[{i}].duration_s", f"{dur} exceeds Tmax_s={tmax}")
            if abs(v0 - v) > 1e-12:  # a step to V0 at the segment start
                ts.append(t)
                vs.append(v0)
            t += dur
            v = v0 * (1.0 - dur / tmax)
            ts.append(t)
            vs.append(v)
    return np.asarray(ts, dtype=float), np.asarray(vs, dtype=float)


def _protocol(seg: Segment, i: int, t: float, v: float, ts: list[float], vs: list[float],
              source: str) -> tuple[float, float]:
    """A rate-and-state protocol appended to the table: velocity steps (a plateau of slip_m at each speed) or
    slide-hold-slide (slide slip_m at to_m_per_s, then for each hold: stop, hold, slide slip_m again); each
    change of speed takes rise_s. Returns the end time and speed."""
    slip = _need(seg, i, "slip_m", source)

    def go(speed: float, plateau_s: float) -> None:
        nonlocal t, v
        if abs(speed - v) > 1e-15:
            t += seg.rise_s
            ts.append(t)
            vs.append(speed)
            v = speed
        t += plateau_s
        ts.append(t)
        vs.append(v)

    if seg.kind == "velocity-steps":
        for k, speed in enumerate(_need(seg, i, "speeds_m_per_s", source)):
            if speed <= 0.0:
                raise InputError(source, f"segment[{i}].speeds_m_per_s[{k}]", f"{speed}: a plateau must slide (> 0)")
            go(speed, slip / speed)
        return t, v
    speed = _need(seg, i, "to_m_per_s", source)
    if speed <= 0.0:
        raise InputError(source, f"segment[{i}].to_m_per_s", f"{speed}: the slides need a speed > 0")
    go(speed, slip / speed)
    for k, hold in enumerate(_need(seg, i, "holds_s", source)):
        if hold <= 0.0:
            raise InputError(source, f"segment[{i}].holds_s[{k}]", f"{hold}: a hold lasts > 0 s")
        go(0.0, hold)
        go(speed, slip / speed)
    return t, v


def check_limits(rt: np.ndarray, rv: np.ndarray, max_speed: float, max_accel: float, source: str) -> None:
    """Refuse a programme beyond the rig's speed or acceleration limits, before any motion."""
    if not np.all(np.isfinite(rt)):
        raise InputError(source, "t", "non-finite time in the programme")
    if not np.all(np.isfinite(rv)):
        raise InputError(source, "speed", "non-finite speed in the programme")
    if np.any(rv < 0.0):
        raise InputError(source, "speed", "negative speed in the programme")
    i = int(np.argmax(rv))
    if rv[i] > max_speed * (1 + 1e-9):
        raise InputError(source, "speed", f"{rv[i]:.4g} m/s at t={rt[i]:.4g} s exceeds the rig limit {max_speed} m/s")
    dt = np.diff(rt)
    dv = np.abs(np.diff(rv))
    with np.errstate(divide="ignore", invalid="ignore"):
        acc = np.where(dt > 0, dv / np.where(dt > 0, dt, 1.0), np.where(dv > 0, np.inf, 0.0))
    if acc.size and acc.max() > max_accel * (1 + 1e-9):
        j = int(np.argmax(acc))
        raise InputError(source, "acceleration",
                         f"{acc[j]:.4g} m/s^2 at t={rt[j]:.4g} s exceeds the rig limit {max_accel} m/s^2")


def load_ramp(path: str | Path) -> tuple[Ramp | None, np.ndarray, np.ndarray]:
    """Load a ramp file (.toml segments or .csv table t,vb); returns (ramp or None, t, v)."""
    path = Path(path)
    src = str(path)
    text = read_text(path)
    if path.suffix.lower() == ".csv":
        rt, rv = _csv_table(text, src)
        return None, rt, rv
    data = parse_toml(text, src)
    try:
        ramp = Ramp.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(f"[{x}]" if isinstance(x, int) else str(x) for x in err["loc"]).replace(".[", "[")
        raise InputError(src, field or "(root)", err["msg"]) from None
    rt, rv = ramp_table(ramp, src)
    return ramp, rt, rv


def _csv_table(text: str, src: str) -> tuple[np.ndarray, np.ndarray]:
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise InputError(src, "(header)", "empty file")
    header = [h.strip() for h in rows[0]]
    for col in ("t", "vb"):
        if col not in header:
            raise InputError(src, col, "missing column (need t, vb)")
    it, iv = header.index("t"), header.index("vb")
    ts, vs = [], []
    for n, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        try:
            t, v = float(row[it]), float(row[iv])
        except (ValueError, IndexError):
            raise InputError(src, f"line {n}", "t and vb must be numbers") from None
        if not (math.isfinite(t) and math.isfinite(v)):
            raise InputError(src, f"line {n}", "t and vb must be finite numbers")
        ts.append(t)
        vs.append(v)
    rt, rv = np.asarray(ts), np.asarray(vs)
    if rt.size < 2 or np.any(np.diff(rt) <= 0):
        raise InputError(src, "t", "need at least two rows with strictly increasing t")
    return rt - rt[0], rv
