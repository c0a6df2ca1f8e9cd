"""What paper 001 itself reports, to set our results beside it (``--paper-marks``).

Why kept apart: these are the paper's numbers, not ours: the segment boundaries of its V0 = 0.25 m/s,
Tmax = 160 s run (section 5, Fig. 8), "indicated conditionally based on visual estimates", and the plane
windows of its Fig. 11. The analysis compares with them only when asked.
"""

from __future__ import annotations

from pydantic import Field

from daq.strict import Closed

from .transitions import TransitionResult

# paper 001, section 5 (Fig. 8): segment boundaries of the V0 = 0.25 m/s, Tmax = 160 s run "indicated
# conditionally based on visual estimates", and what the text says happens in each
PAPER_160_SEGMENTS = [
    (0.0, 98.0, "quasi-steady"),
    (98.0, 110.0, "period doubling -> irregular (narrow strip of widening spectrum)"),
    (110.0, 130.0, "regular multiple-frequency"),
    (130.0, 135.0, "narrow strip of widening spectrum"),
    (135.0, 140.0, "regular multiple-frequency"),
    (140.0, 150.0, "wide strip of dense spectrum (localised spikes)"),
]
PAPER_160_BOUNDARIES = [98.0, 110.0, 130.0, 135.0, 140.0, 150.0]


class PaperMark(Closed):
    """A segment the paper reports for the V0 = 0.25 m/s, Tmax = 160 s run, beside what we found there."""

    start_s: float
    end_s: float
    paper: str
    found: list[str] = Field(description="regime kinds (with their share of the interval) and widening share")


def paper_planes(t0: float, t1: float) -> list[tuple[float, float]]:
    """The windows of the paper's Fig. 11 that lie inside the run."""
    wins = [(1.0, 3.0), (98.0, 100.0), (102.0, 104.0), (120.0, 122.0), (136.0, 138.0), (155.0, 157.0)]
    return [w for w in wins if w[0] >= t0 and w[1] <= t1]


def compare_paper_160(tr: TransitionResult) -> list[PaperMark]:
    """For each segment the paper reports on the 160 s run: which of our kinds cover it, and how much."""
    out = []
    for a, b, what in PAPER_160_SEGMENTS:
        share: dict[str, float] = {}
        wide = 0.0
        for s in tr.segments:
            ov = max(0.0, min(b, s.end_s) - max(a, s.start_s))
            if ov <= 0:
                continue
            if s.track == "regime":
                share[s.kind] = share.get(s.kind, 0.0) + ov / (b - a)
            else:
                wide += ov / (b - a)
        found = [f"{k} {v:.0%}" for k, v in sorted(share.items(), key=lambda kv: -kv[1])]
        found.append(f"widening {wide:.0%}")
        out.append(PaperMark(start_s=a, end_s=b, paper=what, found=found))
    return out
