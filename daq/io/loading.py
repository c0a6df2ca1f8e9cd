"""Opening a data file for analysis: a recording (HDF5) or an interchange CSV/TDMS file, on a uniform time base.

Recorder files carry host timestamps (jitter, repeats, NaN where a stream had not started);
the models and the papers' analyses want one uniform time base over the stretch where every
channel they read has data.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from daq.config import RigConfig, config_for_recording, load_rig
from daq.errors import InputError
from daq.io.importer import read_table, validate
from daq.io.interchange import Recording, read_recording
from daq.io.plausible import check_recording

# the channels a rig's model reads (and must find in a data file), and those it uses when present
MODEL_CHANNELS = {
    "brake-2dof": ("x1", "phi", "vb"),
    "drum-pendulum": ("phi", "vel", "thrust", "drum_speed"),
    "belt-ndof": ("x1", "vb"),
}
OPTIONAL_CHANNELS = ("vb_set", "temp")
GAP_PERIODS_FILLED = 1.5  # real samples farther apart than this many periods leave a hole that is filled in


def load_data(path: str | Path, rig: str | None, cfg: RigConfig | None = None) -> Recording:
    """A recording (HDF5) or an interchange CSV/TDMS file; irregular host timestamps are resampled.

    The rig's channels are checked against daq/io/plausible.py (``cfg``: the config the analysis uses;
    by default ``rig``'s, or the one a recording carries): a CSV/TDMS sample that is not finite, or any
    sample far outside the channel's range, is one InputError naming file, channel and sample. In a
    recording NaN marks where a stream had no data (before it started, across a gap): those samples are
    interpolated and counted in ``meta["filled"]``, which the commands report."""
    p = Path(path)
    if p.suffix.lower() in (".h5", ".hdf5"):
        rec = read_recording(p)
        if cfg is None and rec.rig is not None:
            cfg = config_for_recording(rec.meta.get("rig_config"), str(p), rig if rig and Path(rig).suffix else None,
                                       rec.rig, "this is")
        if cfg is not None:
            check_recording(str(p), rec, cfg)
    elif p.suffix.lower() in (".csv", ".tdms"):
        if rig is None:
            raise InputError(str(p), "--rig", "a CSV/TDMS file does not say which rig it is from: give --rig")
        cfg = cfg or load_rig(rig)
        table = read_table(p)
        channels, units = validate(table, cfg)
        rec = Recording(cfg.rig, table.t, {c: table.columns[c][0] for c in channels}, dict(zip(channels, units)))
        check_recording(str(p), rec, cfg)
    else:
        raise InputError(str(p), "(file)", "unsupported format (use .h5, .csv or .tdms)")
    if rig is not None and rec.rig is not None and rec.rig != rig and not Path(rig).suffix:
        raise InputError(str(p), "rig", f"the recording is from {rec.rig}, not {rig}")
    return uniform(rec, str(p))


def uniform(rec: Recording, source: str) -> Recording:
    """Recorder files carry host timestamps (jitter, repeats, NaN where a stream had not started) and extra
    streams (estimator output): keep the channels a model reads, over the stretch where all have data,
    on a uniform time base."""

    need = [c for c in (*MODEL_CHANNELS.get(rec.rig or "", ()), *OPTIONAL_CHANNELS) if c in rec.channels]
    t = np.asarray(rec.t, dtype=float)
    good = np.isfinite(t)
    for c in need:
        good &= np.isfinite(rec.channels[c])
    idx = np.flatnonzero(good)
    if idx.size < 2:
        raise InputError(source, "t", "no stretch where every channel has data")
    lo, hi = idx[0], idx[-1] + 1
    t = t[lo:hi]
    ch = {k: np.asarray(v[lo:hi], dtype=float) for k, v in rec.channels.items()}
    dt = np.diff(t)
    rate = 1.0 / float(np.median(dt)) if np.median(dt) > 0 else 0.0
    if rate <= 0 or np.any(dt < 0) and np.sum(dt < 0) > 0.01 * dt.size:
        raise InputError(source, "t", "times must increase")
    if np.all(dt > 0) and np.max(np.abs(dt * rate - 1.0)) <= 0.01 and all(np.all(np.isfinite(ch[c])) for c in need):
        return Recording(rec.rig, t, ch, rec.units, rec.meta, {})
    keep = np.concatenate([[True], dt > 0])  # repeated host times: keep the first
    keep &= np.maximum.accumulate(t) == t
    t = t[keep]
    tu = t[0] + np.arange(int(math.floor((t[-1] - t[0]) * rate)) + 1) / rate
    out = {}
    filled: dict[str, int] = {}
    spans: dict[str, list[list[float]]] = {}
    for k, v in ch.items():
        v = v[keep]
        ok = np.isfinite(v)
        out[k] = np.interp(tu, t[ok], v[ok]) if ok.sum() >= 2 else np.full(tu.size, np.nan)
        if k in need and ok.sum() >= 2:  # grid points inside a hole of this channel's real samples
            real = t[ok]
            nxt = np.clip(np.searchsorted(real, tu, side="right"), 1, real.size - 1)
            hole = real[nxt] - real[nxt - 1] > GAP_PERIODS_FILLED / rate
            inside = hole & (tu - real[nxt - 1] > 0.25 / rate) & (real[nxt] - tu > 0.25 / rate)
            n = int(np.sum(inside))
            if n:
                filled[k] = n
                spans[k] = filled_spans(tu, inside)
    meta = {**rec.meta, "resampled_Hz": rate}
    if filled:
        meta["filled"] = filled
        meta["filled_spans"] = spans
    return Recording(rec.rig, tu, out, rec.units, meta, {})


def filled_spans(t: np.ndarray, filled: np.ndarray) -> list[list[float]]:
    """[first, last] time of each run of filled-in samples: where a model's channel is a straight line drawn
    across a hole, not a measurement (windows over one are flagged, daq/models/fit/windows.py)."""
    edges = np.diff(np.concatenate([[0], filled.astype(np.int8), [0]]))
    return [[float(t[a]), float(t[b - 1])] for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1))]
