"""The next experiment: the drive programme under which rival explanations of a record differ most (issue 26).

Why this way (model discrimination, Box and Hill 1967; T-optimality, Atkinson and Fedorov 1975): when a record leaves
rivals standing ("nothing more" against an effect it cannot see, or two effects that fit it equally well), the run
that decides is the one under which the data one rival predicts are furthest from what the other can produce. Each
rival is fitted to the record as well as it can be; for each candidate programme of the rig
(:mod:`daq.models.design.programmes`), the record the rival taken as true predicts (its fitted values, the record's noise
levels) is scored against the other rival at *its* fitted values, on the held-out windows the diagnosis would score,
start values fitted in each window as always. Both directions, every pair: the programme's score is the worst of them
(maximin: a proposal must decide whichever rival is true).

Two numbers per pair: ``z``, the Wilcoxon consistency of the per-window difference (what diagnose requires of a
claim, MIN_T), and ``separation``, the square root of the summed chi-square difference in noise units (how far
apart, which ranks programmes that all decide). A programme *decides* when ``z >= MIN_T`` in every direction.

The rival's parameters are held at their values on the first record, not refitted to the new one: the two records
will be judged together, with shared parameters, so the first record pins them (what a refit on both would do, to
first order). This is optimistic where the first record pins a parameter weakly.

A rival the record cannot see (an effect whose free fit stays at its neutral value, e.g. aging at one constant
drive speed) is taken at a generic strength (STRENGTH_START, deliberately not any simulator's hidden value), the
other parameters refitted: the rival that explains the record as well as "nothing more" does with the effect
present. The proposal then says which run would show it, if it is there at that strength.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np

from daq.errors import InputError
from daq.io.interchange import Recording
from daq.sim.run import simulate

from ..candidates import Candidate, candidates_for
from ..diagnosis.margins import MIN_EXCESS
from ..diagnosis.scoring import MIN_T, Diagnosis, consistency, records_of, z_attainable
from ..fit import forked
from ..fit.linalg import FAILURES, failure_reason
from ..fit.session import Fitted, Portable, Session, portable
from ..spec import STRENGTH_START, Model, form_key
from .programmes import Programme, family

NOTHING = "nothing more"
MAX_WINDOWS = 40  # held-out and fit windows of a predicted record (a third held out, as in any session)
EXPLAINS = 0.5  # nothing named, yet candidates that each remove this share of the excess: a tie the record cannot decide
MAX_RIVALS = 3  # besides "nothing more": each costs a fit on the record and a simulation per programme
CONTINUATION = 2  # a ruled-out strength is tried again reached in steps from 1/4 of it (see _held_at)
HALVINGS = 5  # a rival the record cannot see is tried at the generic strength and down to 1/32 of it
SEED = 2026  # the predicted records' noise: one realisation, the same for every programme (a fair comparison)


@dataclass
class Rival:
    """One explanation of the record: a model fitted to it; ``fixed``: its strength was set, not fitted."""

    label: str
    fitted: Fitted
    fixed: str | None = None  # the strength parameter held at a generic value (the record cannot see it)

    def error(self, session: Session) -> float:
        return self.fitted.rms(session.primary)


@dataclass
class PairScore:
    truth: str
    rival: str
    z: float
    separation: float
    n_held: int


@dataclass
class Scored:
    programme: Programme
    pairs: list[PairScore]

    @property
    def z(self) -> float:
        return min(p.z for p in self.pairs)

    @property
    def separation(self) -> float:
        return min(p.separation for p in self.pairs)

    @property
    def decides(self) -> bool:
        """Every pair decided: whichever rival is true, the run tells it from the others."""
        return self.z >= MIN_T

    def decided(self) -> list[str]:
        """The rivals each of whose pairs (both directions) this run decides."""
        names = dict.fromkeys(n for p in self.pairs for n in (p.truth, p.rival))
        return [n for n in names if n != NOTHING and all(p.z >= MIN_T for p in self.pairs if n in (p.truth, p.rival))]

    @property
    def decided_separation(self) -> float:
        """The narrowest separation among the pairs of the rivals this run decides; the worst pair's if it decides
        none. The pairs no run decides are noise here: ranking runs by them picked among equals at random."""
        names = set(self.decided())
        mine = [p.separation for p in self.pairs if p.truth in names or p.rival in names]
        return min(mine) if mine else self.separation

    def rank(self) -> tuple:
        """The most rivals decided, all of them first, then the widest separation of the pairs decided, then the
        shorter run. Why not the worst pair alone (maximin): against "nothing more" several unseen effects stand,
        and one that no run of the family reveals at its generic strength must not hide the run that reveals the
        others, nor choose among the runs that reveal them (its separation there is noise: 0.14 against 0.0 picked
        12 mm/s over 2 mm/s for the aging slider of tests/long/test_propose_aging.py)."""
        return (-len(self.decided()), not self.decides, -self.decided_separation, self.programme.duration_s)


@dataclass
class Proposal:
    best: Scored
    scored: list[Scored]  # in family order
    rivals: list[Rival]
    family_size: int
    seconds: float
    budget_s: float


def rivals_for(session: Session, model: Model, candidates: list[Candidate], say: Callable[[str], None],
               base: Fitted | None = None) -> list[Rival]:
    """"Nothing more" (the model fitted) and the model with each candidate, fitted from it; a candidate whose
    strength the fit leaves at neutral is held at a generic strength, the other parameters refitted."""
    if any(e.path is not None for e in model.effects.values()):
        raise InputError("--model", "effects", "a user effect cannot be simulated under another programme yet")
    base = base or session.fit(model)
    out = [Rival(NOTHING, base)]
    for c in candidates:
        m = c.apply(model, "propose")
        say(f"fitting the rival {c.label} on {session.source}")
        try:
            fitted = session.fit(m, warm=base)
            full = c.strength(m)
            fixed = None
            if full is not None:
                p = m.params()[full]
                start = STRENGTH_START.get(form_key(c.name, c.form) if c.kind == "effect" else "")
                if start is not None and abs(fitted.values[full] - p.value) < 0.5 * abs(start - p.value):
                    fitted, fixed = _standing(session, m, base, full, p.value, start, say), full
        except FAILURES as exc:  # a rival that cannot be fitted is left out, said (decision 50)
            say(f"  the rival {c.label} is left out: its fit failed: {failure_reason(exc)}")
            continue
        out.append(Rival(c.label, fitted, fixed))
    return out


def rivals_from(session: Session, model: Model, d: Diagnosis, say: Callable[[str], None]) -> tuple[list[Rival], str]:
    """The rival explanations a diagnosis leaves standing, and why (a sentence). Undecided between X and Y: the
    diagnosed model with X and the same with Y in its place. Nothing named with an excess that candidates explain
    (each at least EXPLAINS of it: a record too short to claim any): those candidates. Nothing named otherwise: "nothing
    more" against the catalog effects the record cannot see at a generic strength (:func:`_unseen`). Named and decided: no rivals
    (nothing to propose)."""
    by_label = {c.label: c for c in candidates_for(model)}
    members = [c for sc in d.sequence for c in sc.cands]
    tied = next((v for v in d.verdicts if v.ties), None) if d.found else None
    if tied is not None:
        rest = [c for c in members if c != tied.cand]
        out = []
        for c in [tied.cand] + [by_label[m.rival] for m in tied.ties if m.rival in by_label][:MAX_RIVALS - 1]:
            say(f"fitting the rival {c.label} (with {', '.join(x.label for x in rest) or 'nothing else'})")
            try:
                out.append(Rival(c.label, session.fit(_extend(model, rest + [c]))))
            except FAILURES as exc:  # left out, said (decision 50)
                say(f"  the rival {c.label} is left out: its fit failed: {failure_reason(exc)}")
        return out, f"undecided between {' and '.join(r.label for r in out)}"
    if d.found and members:
        return [], f"decided: {', '.join(c.label for c in members)}; nothing to propose"
    explains = [sc for sc in d.candidates if sc.fitted is not None and sc.reduction >= EXPLAINS][:MAX_RIVALS]
    if explains and d.base.rms(session.primary) > (1.0 + MIN_EXCESS) * d.floor:
        rivals = ([Rival(NOTHING, d.base)] if len(explains) == 1 else []) + [Rival(sc.label, sc.fitted) for sc in explains]
        return rivals, (f"nothing named for an excess of {d.base.rms(session.primary) / d.floor:.1f} x the floor, which "
                        + ", ".join(f"{sc.label} ({sc.reduction:.0%})" for sc in explains)
                        + " each explain: the record cannot decide")
    rivals = _unseen(session, model, d.base, say)
    if len(rivals) < 2:
        return [], "nothing named, and every candidate at a generic strength is ruled out by the record: nothing to propose"
    return rivals, f"nothing named; the record cannot see {', '.join(r.label for r in rivals[1:])} at generic strengths"


def _unseen(session: Session, model: Model, base: Fitted, say: Callable[[str], None]) -> list[Rival]:
    """"Nothing more" and the catalog effects the record cannot see: each held at its generic strength
    (STRENGTH_START), the other parameters refitted, and kept when the record cannot tell it from "nothing more"
    (:func:`_rules_out`). One the record tells apart is reached once more in steps from 1/4 of that strength
    (CONTINUATION, :func:`_held_at`), and held at the largest step the record cannot tell, if any; the walk stops at
    the first step the record tells (since 2026-11-28: the steps above it, each reached from a told one, were told on
    every record seen, and cost a fit each, 19 s of the 64 s this took on a 10 s brake record; one told at the first
    step is said at it, the smallest strength ruled out). An effect the record rules out at all of them is absent
    as far as any run can tell at those strengths; one it cannot is what another run must look for. At most
    MAX_RIVALS, those the record comes closest to telling first (the largest error ratio still untold). Why that
    order, a heuristic: an effect that leaves no trace at all at its strength (ratio 1.000: a temperature law on a
    record whose temperature hardly moves) is the least likely to show on another run of the same family; one that
    moves the error by 8 % without being told (aging on a slider at one speed, seen: 1.078) is one a run that
    changes its conditions can reveal. Before 2026-11-27 the least visible came first, by z, and the slider's aging
    was the fourth of four, left out. The effects' walks are independent of each other: with cores to spare each
    runs in a forked worker (forked.py), said in order."""
    hw = session.win.select(True)
    held = []  # (candidate, the model with it, its strength parameter) for the effects with a generic strength
    for c in candidates_for(model, mechanics=False):
        m = c.apply(model, "propose")
        full = c.strength(m)
        if STRENGTH_START.get(form_key(c.name, c.form)) is not None and full is not None:
            held.append((c, m, full))
    work = partial(_walk, session, base, hw, held)
    if len(held) > 1 and forked.can_fork():  # each effect's walk is independent of the others': one per worker
        with forked.pool(min(len(held), os.cpu_count() or 1), work) as pool:
            walks = _told(pool.imap(forked.run, range(len(held))), say)
    else:
        walks = _told(map(work, range(len(held))), say)
    standing = [(w.ratio, Rival(w.label, session.restore(w.fit), w.full)) for w in walks if w.fit is not None]
    standing.sort(key=lambda er: -er[0])
    return [Rival(NOTHING, base)] + [r for _, r in standing[:MAX_RIVALS]]


@dataclass
class _Walked:
    """One effect's walk (:func:`_walk`) as plain parts a forked worker sends back: what it said, and where the
    record cannot tell the effect from "nothing more", the fit that stands (``fit``) and its error ratio."""

    label: str
    lines: list[str]
    full: str = ""
    ratio: float = 0.0
    fit: Portable | None = None


def _told(walks, say: Callable[[str], None]) -> list[_Walked]:
    """Say each walk's lines as it comes back (in the candidates' order)."""
    out = []
    for w in walks:
        for line in w.lines:
            say(line)
        out.append(w)
    return out


def _walk(session: Session, base: Fitted, hw: np.ndarray, held: list[tuple[Candidate, Model, str]],
          i: int) -> _Walked:
    """The ``i``-th of ``held`` (a candidate, the model with it, its strength parameter) held at its generic
    strength, and where the record tells it, reached in steps (see :func:`_unseen`). By index: a forked worker
    inherits ``held``."""
    c, m, full = held[i]
    try:
        return _walk_one(session, base, hw, c, m, full)
    except FAILURES as exc:  # an effect whose fit fails cannot stand as a rival: left out, said (decision 50)
        return _Walked(c.label, [f"{c.label}: left out, its fit failed: {failure_reason(exc)}"])


def _walk_one(session: Session, base: Fitted, hw: np.ndarray, c: Candidate, m: Model, full: str) -> _Walked:
    """_walk of one effect (a candidate, the model with it, its strength parameter)."""
    start = STRENGTH_START[form_key(c.name, c.form)]
    lines: list[str] = []
    value, fitted = start, _held_at(session, m, base, full, start)
    z, seen = _rules_out(session, fitted, base, hw)
    if seen:  # once more reached in steps (see _held_at); the largest step the record cannot tell stands
        neutral = m.params()[full].value
        walked, untold = base, None
        for step in [neutral + (start - neutral) / 2 ** k for k in range(CONTINUATION, -1, -1)]:
            walked = _held_at(session, m, walked, full, step)
            z_step, seen_step = _rules_out(session, walked, base, hw)
            lines.append(f"  {c.label} reached in steps, at {step:.3g}: {walked.rms(session.primary):.4g} "
                         f"(z {z_step:.2f})")
            if not seen_step:
                untold = (step, walked, z_step)
                continue
            if untold is None:  # told at the first step: said at the smallest strength the record rules out
                value, fitted, z = step, walked, z_step
            break  # told at this step: a stronger effect, reached from it, is told the more (no fit spent on it)
        if untold is not None:
            (value, fitted, z), seen = untold, False
    e0 = base.rms(session.primary)
    lines.append(f"{c.label} at {value:.3g}: {fitted.rms(session.primary):.4g} on the record against {e0:.4g} "
                 f"(z {z:.2f}: {'rules it out' if seen else 'cannot tell it'})")
    if seen:
        return _Walked(c.label, lines)
    return _Walked(c.label, lines, full, fitted.rms(session.primary) / e0, portable(fitted))


def _held_at(session: Session, m: Model, warm: Fitted, full: str, value: float) -> Fitted:
    """``m`` fitted with its strength ``full`` held at ``value``, from ``warm`` (its values, the held one replaced).
    Why a continuation exists: from the model without the effect, the effect switched on at its generic strength
    at once can throw the fit into a poor basin (seen on a spring-slider, aging held at 0.1: f_k0 2.0 and accel-sign
    -0.4, 10x the error of the model without it, i.e. "ruled out" by a failed fit; reached in three steps from
    0.025, 1.09x)."""
    held = m.with_values({full: value})
    held.params()[full].free = False
    if full in warm.values:
        warm = dataclasses.replace(warm, values={**warm.values, full: value})
    return session.fit(held, warm=warm)


def _rules_out(session: Session, fitted: Fitted, base: Fitted, hw: np.ndarray) -> tuple[float, bool]:
    """Does the record tell ``fitted`` (an effect held at a strength) from "nothing more" (``base``), as diagnose
    judges a claim: its held-out windows consistently worse (Wilcoxon z >= MIN_T) *and* its error more than
    MIN_EXCESS above base's? Returns (z, told). Why both: at the noise floor a difference of 0.7 % is consistent in
    every window (seen: the reference slider's own aging strength, z 2.5) and still nothing diagnose would name."""
    z = (consistency(session.weighted(fitted.ms_held, hw) - session.weighted(base.ms_held, hw), records_of(session, hw))
         if hw.size else 0.0)
    return z, z >= MIN_T and fitted.rms(session.primary) > (1.0 + MIN_EXCESS) * base.rms(session.primary)


def _extend(model: Model, cands: list[Candidate]) -> Model:
    for c in cands:
        model = c.apply(model, "propose")
    return model


def _standing(session: Session, m: Model, base: Fitted, full: str, neutral: float, start: float,
              say: Callable[[str], None]) -> Fitted:
    """The model ``m`` with its strength ``full`` held at the largest of start, start/2, start/4, ... (at most
    HALVINGS halvings) at which, the other parameters refitted, the record cannot tell it from "nothing more" as
    diagnose judges a claim: the per-window difference on the held-out windows is not consistent (z < MIN_T) or the
    error is within 1 + MIN_EXCESS of it. A rival the record leaves standing. Where none is, the smallest tried
    (the record all but rules it out already; the proposal then confirms that)."""
    hw = session.win.select(True)
    e0 = base.rms(session.primary)
    for k in range(HALVINGS + 1):
        value = neutral + (start - neutral) / 2 ** k
        fitted = _held_at(session, m, base, full, value)
        z, told = _rules_out(session, fitted, base, hw)
        say(f"  {full} held at {value:.4g}: {fitted.rms(session.primary):.4g} on the record against {e0:.4g} (z {z:.2f})")
        if not told:
            break
    return fitted


def predicted(session: Session, rival: Rival, prog: Programme, noise: bool = True, seed: int = SEED) -> Recording:
    """The record ``rival`` predicts under ``prog``: its fitted model simulated at the session's rate, the record's
    noise level added to each output (``noise``)."""
    b = rival.fitted.problem.builder
    vals = {**b.base_values, **rival.fitted.values}
    rec = simulate(b.config(vals), e=b.effect_vector(vals), ramp=prog.table(), ramp_source=prog.name,
                   duration=prog.duration_s, rate=session.m.rate, noise=False, keep_states=True)
    rng = np.random.default_rng(seed)
    for k, s in session.m.sigma.items():
        if noise and k in rec.channels:
            rec.channels[k] = np.asarray(rec.channels[k], dtype=float) + rng.normal(0.0, s, len(rec.channels[k]))
    return rec


class _TruthRecord:
    """The record ``truth`` predicts, read as a session, and ``truth``'s own error on its held-out windows: the
    same for every rival scored against it, so computed once (a held-out score fits every window's start; it was
    computed once per rival, 12 scores a programme where 10 differ)."""

    def __init__(self, session: Session, truth: Rival, rec: Recording) -> None:
        self.truth = truth
        self.s = Session(rec, "(predicted)", session.cfg, max_windows=MAX_WINDOWS, loss=session.loss,
                         window_s=(session.win.length - 1) / session.m.rate)
        self.s.m.sigma = dict(session.m.sigma)  # the record's noise model, not a re-estimate
        self.hw = self.s.win.select(True)
        pr = self.s.problem(truth.fitted.model)
        self.near = self._own_states(rec, pr.slots)  # every held-out fit on this record starts here (a twin: d = 0)
        _, self.ms = self.s.held_out(pr, truth.fitted.values, near=self.near)

    def _own_states(self, rec: Recording, slots: list[int]) -> np.ndarray | None:
        """The start values ``truth``'s own simulation passed through at each held-out window's start: where the
        start fits of the truth and of every rival on this record begin (the same start for all, so a rival equal
        to the truth is never separated), with damping lm.NEAR_DAMPING, instead of at the data's estimate with
        lm.START_DAMPING. Why: from the data's estimate a start fit took 45-130 batched simulations, mostly
        Jacobians while the damping fell from 100. Measured on a 10 s brake record's family of 42 programmes
        (2026-11-28, beside another job): 74.7 -> 56.3 CPU-s; the same best programme, deciding the same rivals;
        of 252 pairs, 247 separations within 1 %, two within 2.1 %, three at 3.2, 4.0 and 30 % (the last at the
        noise level, 0.96 -> 1.25); one z crossed the bar, 2.38 -> 2.30, on a programme that was not the best. The
        same start with START_DAMPING moved the same pairs the same way for 71.2 CPU-s: the start, not the damping,
        moves them. None where the session resampled the record (its samples are not the simulation's)."""
        states = rec.truth.get("state")
        if states is None or len(states) != self.s.m.t.size:
            return None
        return states[self.s.win.starts[self.hw]][:, slots]

    def against(self, rival: Rival) -> PairScore:
        """``rival`` at its values against this record, on its held-out windows."""
        s = self.s
        _, ms_r = s.held_out(s.problem(rival.fitted.model), rival.fitted.values, near=self.near)
        d = s.weighted(ms_r, self.hw) - s.weighted(self.ms, self.hw)
        n = int(d.size)
        chi2 = float(np.sum((s.win.length - 1) * d))
        return PairScore(self.truth.label, rival.label, min(consistency(d), z_attainable(n)),
                         math.sqrt(max(chi2, 0.0)), n)


def score_pair(session: Session, truth: Rival, rival: Rival, rec: Recording) -> PairScore:
    """``rival`` at its values against the record ``truth`` predicts, on that record's held-out windows."""
    return _TruthRecord(session, truth, rec).against(rival)


def score(session: Session, rivals: list[Rival], prog: Programme) -> Scored:
    """The ordered pairs of rivals under ``prog``: every pair, except that against "nothing more" the other rivals
    are only paired with it (the question there is whether anything is present, not which of the unseen)."""
    pairs = []
    for truth in rivals:
        others = [o for o in rivals if o is not truth and NOTHING in (truth.label, o.label)
                  or o is not truth and rivals[0].label != NOTHING]
        if others:
            record = _TruthRecord(session, truth, predicted(session, truth, prog))
            pairs += [record.against(other) for other in others]
    return Scored(programme=prog, pairs=pairs)


def _score_task(session: Session, rivals: list[Rival], progs: list[Programme], i: int) -> Scored:
    """Programme ``i`` scored in a forked process (forked.py: the session and the rivals' fits inherited)."""
    return score(session, rivals, progs[i])


def propose(session: Session, rivals: list[Rival], budget_s: float, max_run_s: float, v0: float,
            say: Callable[[str], None], workers: int | None = None) -> Proposal:
    """Score the rig's programmes in family order until the budget is spent; the best one by :meth:`Scored.rank`.
    With cores to spare, programmes are scored in forked processes (each inherits the session and the rivals'
    fits; a score comes back as plain data), in family order as they finish."""
    if len(rivals) < 2:
        raise InputError("--rival", "--rival", "a proposal needs at least one rival to 'nothing more'")
    progs = family(session.cfg, v0, max_run_s)
    workers = workers or (os.cpu_count() or 1)
    t0 = time.monotonic()
    scored: list[Scored] = []

    def take(res: Scored) -> bool:
        scored.append(res)
        best = min(scored, key=Scored.rank)
        say(f"[{len(scored)}/{len(progs)}] {res.programme.name}: z {res.z:.2f}, separation {res.separation:.1f}; "
            f"best so far: {best.programme.name}")
        if time.monotonic() - t0 > budget_s and len(scored) < len(progs):
            say(f"budget of {budget_s:g} s spent: {len(scored)} of {len(progs)} programmes scored")
            return False
        return True

    if workers > 1 and forked.can_fork():
        with forked.pool(min(workers, len(progs)), partial(_score_task, session, rivals, progs)) as pool:
            for res in pool.imap(forked.run, range(len(progs))):
                if not take(res):
                    break
    else:
        for prog in progs:
            if not take(score(session, rivals, prog)):
                break
    return Proposal(min(scored, key=Scored.rank), scored, rivals, len(progs), time.monotonic() - t0, budget_s)


def drive_speed(session: Session) -> float:
    """The record's drive speed to build the family around: its median commanded speed while moving."""
    v = np.asarray(session.m.drive_command, dtype=float)
    moving = v[v > 0]
    if moving.size == 0:
        raise InputError(session.source, "drive", "the belt never moves in this record: no speed to vary around")
    return float(np.median(moving))


def as_json(session: Session, p: Proposal) -> dict:
    best = p.best
    return {
        "data": session.source,
        "programme": best.programme.name, "duration_s": best.programme.duration_s,
        "varies": list(best.programme.varies), "ramp": best.programme.toml(),
        "decides": best.decides, "decided_rivals": best.decided(), "z": best.z, "separation": best.separation,
        "pairs": [vars(x) for x in best.pairs],
        "rivals": [{"label": r.label, "error_on_record": r.error(session), "error_unit": session.m.units[session.primary],
                    "held_at_generic_strength": r.fixed,
                    "values": {k: r.fitted.values[k] for k in r.fitted.model.free_names()}} for r in p.rivals],
        "scored": [{"programme": s.programme.name, "z": s.z, "separation": s.separation, "decides": s.decides,
                    "decided_rivals": s.decided(), "decided_separation": s.decided_separation,
                    "pairs": [vars(x) for x in s.pairs]}
                   for s in p.scored],
        "family_size": p.family_size, "seconds": p.seconds, "budget_s": p.budget_s if math.isfinite(p.budget_s) else None,
    }
