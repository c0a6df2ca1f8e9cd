"""How firmly the held-out windows prefer one explanation over a rival: a paired bootstrap over windows.

Why a bootstrap over windows: a diagnosis names an effect because it scores better on held-out windows than
the alternatives; whether that ordering would survive a different draw of windows (another stretch of the same
record, another machine's last bits in the fit) is what a scientist needs before writing "the missing effect is
X". Resampling the held-out windows (the same resamples for both models: paired) gives the spread of the score
difference; an explanation is preferred only when its lower bound (the LEVEL quantile) stays above zero.

Why the score difference in shares of the base model's excess: it is the unit every reduction is reported in,
so a margin of 0.12 reads "it explains 12 points more of the excess than its rival". Each window's mean square
is capped (diagnose.CAP_MS times the base model's median) as in the step scores, so no single window decides.

Pure functions over arrays; the seed is fixed, so the same input gives the same margin on every machine. A
:class:`Verdict` holds one named effect's margins (judged by verdict.judge).
Decision record: docs/decisions/0028-margins-and-honest-ties.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from daq.physics.catalog import CATALOG

from ..candidates import Candidate

N_BOOT = 2000  # resamples: the 5 % quantile's own spread is then ~0.5 % of the distribution's width
LEVEL = 0.05  # one-sided: an explanation is preferred when its rival does better in fewer than 5 % of resamples
SEED = 20261126  # fixed: a margin is a property of the data, not of the run
MIN_EXCESS = 0.10  # an error within this share above the noise floor leaves nothing to explain (diagnose, verdict)


@dataclass(frozen=True)
class Margin:
    """How much better ``named`` scores than ``rival`` on the held-out windows, in shares of the base excess."""

    named: str
    rival: str
    share: float  # point estimate: (rival's robust rms - named's) / base excess
    lower: float  # the LEVEL quantile of the bootstrap distribution of ``share``
    upper: float  # the 1 - LEVEL quantile
    rival_wins: float  # share of resamples in which the rival scored as well or better
    rival_at_floor: bool = False  # the rival itself reaches the noise floor: nothing is left that could prefer either

    @property
    def decided(self) -> bool:
        return self.lower > 0.0 and not self.rival_at_floor

    def as_json(self) -> dict:
        return {"rival": self.rival, "margin": self.share, "margin_lower": self.lower, "margin_upper": self.upper,
                "rival_wins": self.rival_wins, "rival_at_floor": self.rival_at_floor, "decided": self.decided}


def resamples(n: int, n_boot: int = N_BOOT, seed: int = SEED) -> np.ndarray:
    """Bootstrap indices (n_boot x n) over n windows; the first row is the sample itself."""
    rng = np.random.default_rng(seed + n)
    idx = rng.integers(0, n, size=(n_boot, n))
    idx[0] = np.arange(n)
    return idx


def margin(named: str, rival: str, ms_named: np.ndarray, ms_rival: np.ndarray, excess: float, cap: float,
           n_boot: int = N_BOOT, seed: int = SEED) -> Margin:
    """The paired bootstrap of the robust-rms difference between two models scored on the same held-out windows
    (per-window mean squares ``ms_named``, ``ms_rival``), in shares of ``excess`` (base error - noise floor)."""
    a = np.minimum(np.asarray(ms_named, float), cap)
    b = np.minimum(np.asarray(ms_rival, float), cap)
    if a.shape != b.shape or a.size == 0 or not excess > 0:
        return Margin(named, rival, 0.0, 0.0, 0.0, 1.0)
    idx = resamples(a.size, n_boot, seed)
    diff = (np.sqrt(b[idx].mean(axis=1)) - np.sqrt(a[idx].mean(axis=1))) / excess
    point = (math.sqrt(b.mean()) - math.sqrt(a.mean())) / excess
    lo, hi = np.quantile(diff, [LEVEL, 1.0 - LEVEL])
    return Margin(named, rival, float(point), float(lo), float(hi), float(np.mean(diff <= 0.0)))


NOTHING = "nothing more"  # the rival every named effect has: the model without it


@dataclass
class Verdict:
    """A member of the final model and how firmly the held-out windows prefer it: over the model without it
    (margins[0]) and over each plausible rival refitted in its place; over its phenomenon's other forms."""

    cand: Candidate
    margins: list[Margin]
    forms: list[Margin] = field(default_factory=list)  # a rival form that too reaches the noise floor is no
    # decision, however consistent its small difference (seen: 1.3x steps at 1 kHz, both laws at the floor, the
    # bootstrap's bound +0.00x; `daq analyse rsf` asks 10 noise variances of an event for the same call)

    @property
    def needed(self) -> bool:
        return self.margins[0].decided

    @property
    def decided(self) -> bool:
        return all(m.decided for m in self.margins)

    @property
    def ties(self) -> list[Margin]:
        """The rivals the data cannot tell from it."""
        return [m for m in self.margins[1:] if not m.decided]

    @property
    def weakest(self) -> Margin:
        return min(self.margins, key=lambda m: (m.lower, m.rival))

    def as_json(self) -> dict:
        w = self.weakest
        return {"effect": self.cand.phenomenon, "form": self.cand.form, "label": self.cand.label,
                "decided": self.decided, "margin": w.share, "margin_lower": w.lower, "nearest_rival": w.rival,
                "rivals": [m.as_json() for m in self.margins],
                "form_decided": all(m.decided for m in self.forms), "forms": [m.as_json() for m in self.forms],
                "forms_told_apart_by": CATALOG[self.cand.phenomenon].forms_told_apart_by
                if self.forms and self.cand.phenomenon in CATALOG else ""}
