"""What a data file may hold: the policy for non-finite and absurd samples, one copy for every reader.

Why a policy and not a tolerance in each analysis: a NaN, an inf or a 1e300 in a lab's file is a fact
about the file (a dropped sample, a logger's overflow code, a column in the wrong unit), not about the
contact. Before this module, ``daq import`` wrote such values into the recording, ``compare`` silently
interpolated over NaN, reported "error inf m" on 1e300 and wrote ``Infinity`` (not JSON) into its
history, and ``diagnose`` on that file concluded "no missing effect" (issue 16). So:

* a non-finite sample in one of the rig's channels is refused, naming the file, the channel and the
  first sample (and how many there are); only where the user asks (``daq import --drop-nonfinite``) are
  those samples' rows dropped, and every dropped span is written into the recording as an event
  (kind ``dropped``) - never interpolated without a word;
* a finite sample far outside what the channel can read is refused whatever the user asks: no option
  turns a 1e300 into a measurement. "Far outside" is the channel's ``plausible_range`` in the rig config
  when the config states one (a sensor's full scale, say), otherwise a generous bound per unit below:
  two or more orders of magnitude beyond anything a friction rig's sensors read, plus the physical
  bound where there is one (nothing is colder than -273.15 degC), and for speeds 100 x the drive's
  ``max_speed_m_per_s``;
* columns that are not the rig's channels (kept from a lab's file as they are) are stored as the file
  has them: NaN there marks a missing value, and nothing reads them.

Decision record: docs/decisions/0019-plausible-values.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from daq.config import ChannelCfg, RigConfig
from daq.errors import InputError
from daq.io.interchange import Recording

# unit -> (lowest, highest) plausible value when the rig config does not say (see the module docstring)
UNIT_RANGE: dict[str, tuple[float, float]] = {
    "m": (-10.0, 10.0),
    "rad": (-1e4, 1e4),
    "rad/s": (-1e4, 1e4),
    "N": (-1e6, 1e6),
    "m/s^2": (-1e5, 1e5),
    "degC": (-273.15, 2000.0),
    "count": (-1e12, 1e12),
}
ANY_RANGE = (-1e15, 1e15)  # a unit we know nothing of: still no 1e300
SPEED_FACTOR = 100.0  # plausible |speed| = this x the drive's max_speed_m_per_s


@dataclass
class Dropped:
    """One run of consecutive rows dropped for non-finite values (0-based, ``stop`` exclusive)."""

    start: int
    stop: int
    t_start: float
    t_stop: float
    channels: tuple[str, ...]

    def detail(self) -> str:
        return (f"dropped samples {self.start + 1}-{self.stop} (t {self.t_start:.6g}-{self.t_stop:.6g} s): "
                f"non-finite {', '.join(self.channels)}")


def plausible_range(name: str, spec: ChannelCfg, cfg: RigConfig) -> tuple[float, float]:
    """The range a channel's samples must lie in: the config's ``plausible_range``, else the unit's."""
    if spec.plausible_range is not None:
        return spec.plausible_range
    if spec.unit == "m/s":
        v = SPEED_FACTOR * cfg.drive.max_speed_m_per_s
        return (-v, v)
    return UNIT_RANGE.get(spec.unit, ANY_RANGE)


def _where(t: np.ndarray, i: int) -> str:
    return f"sample {i + 1}" + (f", t = {t[i]:.6g} s" if i < t.size and np.isfinite(t[i]) else "")


def check_values(source: str, t: np.ndarray, columns: dict[str, np.ndarray], cfg: RigConfig,
                 drop_nonfinite: bool = False, allow_nan: bool = False) -> tuple[np.ndarray, list[Dropped]]:
    """Check the rig's channels in ``columns`` (sample for sample with ``t``); return the rows to keep.

    Raises one InputError naming ``source``, the channel and its first bad sample: for a non-finite value
    unless ``drop_nonfinite``, for a value outside :func:`plausible_range` always. With
    ``drop_nonfinite`` the returned mask drops every row where a checked channel is non-finite, and the
    list says which spans went (for the recording's events). ``allow_nan``: a recording's NaN (a stream
    without data there) passes; its infinities do not."""
    t = np.asarray(t, dtype=float)
    keep = np.ones(t.size, dtype=bool)
    bad_by_row: dict[str, np.ndarray] = {}
    for name, spec in cfg.channels.items():
        if name not in columns:
            continue
        x = np.asarray(columns[name], dtype=float)
        finite = np.isfinite(x)
        lo, hi = plausible_range(name, spec, cfg)
        out = finite & ((x < lo) | (x > hi))
        if out.any():
            i = int(np.argmax(out))
            raise InputError(source, f"{name} ({_where(t, i)})",
                             f"{x[i]:.6g} {spec.unit} is far outside what this channel can read "
                             f"({lo:g} to {hi:g} {spec.unit}; {int(out.sum())} in all) - a wrong unit "
                             f"or a logger's error code? Set [channels.{name}] plausible_range in the rig "
                             f"config if the sensor really reads this")
        if allow_nan:
            finite |= np.isnan(x)
        if not finite.all():
            if not drop_nonfinite:
                i = int(np.argmax(~finite))
                raise InputError(source, f"{name} ({_where(t, i)})",
                                 f"non-finite value {x[i]} ({int((~finite).sum())} in all); give "
                                 f"--drop-nonfinite to `daq import` to drop those rows (recorded as events)")
            bad_by_row[name] = ~finite
            keep &= finite
    return keep, _spans(t, keep, bad_by_row)


def check_recording(source: str, rec: Recording, cfg: RigConfig) -> None:
    """:func:`check_values` on a file read whole: a recording (HDF5) may hold NaN where a stream had no data,
    any other file may not; nothing is dropped here (``daq import --drop-nonfinite`` does that)."""
    check_values(source, rec.t, rec.channels, cfg, allow_nan=Path(source).suffix.lower() in (".h5", ".hdf5"))


def _spans(t: np.ndarray, keep: np.ndarray, bad: dict[str, np.ndarray]) -> list[Dropped]:
    """Consecutive dropped rows as spans, each naming the channels that were non-finite in it."""
    edges = np.diff(np.concatenate([[0], (~keep).astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [Dropped(int(a), int(b), float(t[a]), float(t[b - 1]),
                    tuple(n for n, m in bad.items() if m[a:b].any())) for a, b in zip(starts, stops)]
