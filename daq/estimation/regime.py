"""Stick/creep vs slip classification from |v_rel| with hysteresis, vectorised per block."""

from __future__ import annotations

import numpy as np


def classify(v_rel: np.ndarray, v_stick: float, hysteresis: float, prev: int) -> np.ndarray:
    """1 = slip, 0 = stick/creep; the state changes only when |v_rel| leaves the band.

    Why hysteresis: noise on v_rel near the threshold would otherwise chatter the
    regime. Slip starts above v_stick (1 + h) and ends below v_stick (1 - h); inside the
    band the previous state holds (``prev``, -1 = unknown: plain threshold at v_stick).
    """
    av = np.abs(v_rel)
    mark = np.full(av.size, -1, dtype=np.int8)
    mark[av > v_stick * (1.0 + hysteresis)] = 1
    mark[av < v_stick * (1.0 - hysteresis)] = 0
    idx = np.where(mark >= 0, np.arange(av.size), -1)
    np.maximum.accumulate(idx, out=idx)
    if prev < 0:
        fill = (av > v_stick).astype(np.int8)
    else:
        fill = np.full(av.size, prev, dtype=np.int8)
    return np.where(idx >= 0, mark[np.maximum(idx, 0)], fill).astype(np.int8)


def switch_positions(state: np.ndarray, index: np.ndarray, prev: int) -> np.ndarray:
    """Where ``state`` changes, as half-integer sample numbers (between the two samples)."""
    s = state.astype(np.int8)
    first = s[:1] if prev < 0 else np.array([prev], dtype=np.int8)
    k = np.flatnonzero(np.diff(np.concatenate([first, s])) != 0)
    return index[k] - 0.5


def switch_distance(index: np.ndarray, switches: np.ndarray) -> np.ndarray:
    """Samples from each sample number in ``index`` to the nearest switch (inf if none)."""
    if switches.size == 0:
        return np.full(index.size, np.inf)
    j = np.searchsorted(switches, index)
    left = np.abs(index - switches[np.maximum(j - 1, 0)])
    right = np.abs(switches[np.minimum(j, switches.size - 1)] - index)
    return np.minimum(left, right)
