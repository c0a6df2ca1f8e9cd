"""Aligning a rig's streams onto the position stream's time base (sample-and-hold of slower streams).

Why hold and wait: the belt speed comes at 200 Hz from the motor regulator, the
positions at 1 kHz from the laser; each arrives in its own blocks, at its own pace.
A position sample can be paired exactly with the last slower sample at or before it
once that stream has reached its time; if it has not after ``max_wait_s`` (a stalled
stream), the last known value is held rather than stalling the estimate. All the work
is per block (concatenate, searchsorted), never per sample.
"""

from __future__ import annotations

import numpy as np


class HoldBuffer:
    """The recent samples of some channels of one slower stream, for sample-and-hold lookup."""

    def __init__(self, columns: list[int], period: float = 0.0, capacity: int = 4096) -> None:
        self.columns = columns  # column indices in that stream's blocks
        self.period = period  # nominal sample period (0 = unknown): a held value is final until the next sample
        self.cap = capacity
        self.t = np.empty(0)
        self.v = np.empty((len(columns), 0))

    @property
    def covered_until(self) -> float:
        """Up to which time the held value is known to be final (the next sample is not due before)."""
        return float(self.t[-1]) + 0.999 * self.period if self.t.size else -np.inf

    def append(self, t: np.ndarray, data: np.ndarray) -> None:
        """Keep the newest ``capacity`` samples of our columns."""
        self.t = np.concatenate([self.t, t])[-self.cap:]
        self.v = np.concatenate([self.v, data[:, self.columns].T.astype(float)], axis=1)[:, -self.cap:]

    def hold(self, tq: np.ndarray) -> np.ndarray:
        """Values at times tq: the last sample at or before each (the first one before any)."""
        idx = np.searchsorted(self.t, tq, side="right") - 1
        return self.v[:, np.maximum(idx, 0)]


class Pending:
    """Position samples received but not yet estimated, with when and how they arrived."""

    def __init__(self, n_columns: int) -> None:
        self.t = np.empty(0)
        self.x = np.empty((n_columns, 0))
        self.sent = np.empty(0)  # the carrying block's sent_host_time (latency bookkeeping)
        self.arrived = np.empty(0)  # local monotonic time of arrival

    def append(self, t: np.ndarray, x: np.ndarray, sent: float, arrived: float) -> None:
        """Queue a position block's samples with its send and arrival times."""
        self.t = np.concatenate([self.t, t])
        self.x = np.concatenate([self.x, x], axis=1)
        self.sent = np.concatenate([self.sent, np.full(t.size, sent)])
        self.arrived = np.concatenate([self.arrived, np.full(t.size, arrived)])

    def take(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Remove and return the first n samples: (t, x, sent)."""
        out = self.t[:n], self.x[:, :n], self.sent[:n]
        self.t, self.x, self.sent, self.arrived = self.t[n:], self.x[:, n:], self.sent[n:], self.arrived[n:]
        return out

    def ready(self, covered_until: float, now: float, max_wait: float) -> int:
        """How many leading samples can be estimated: covered by every slower stream, or waited long enough."""
        if self.t.size == 0:
            return 0
        covered = int(np.searchsorted(self.t, covered_until, side="right"))
        stale = int(np.searchsorted(self.arrived, now - max_wait, side="right"))  # arrival order = time order
        return max(covered, stale)
