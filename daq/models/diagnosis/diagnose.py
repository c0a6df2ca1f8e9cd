"""Which physical effects is the model missing? Forward selection over the catalog, scored on held-out data
(scoring.py), said in words by summary.py.

Why forward selection: a real contact
carries several effects at once, and none of them need explain half of the excess alone. Each step
screens every candidate (each catalog effect in each of its forms, and the mechanics parameters: a
rig is never exactly its config) by the score test of one linearisation (daq/models/diagnosis/screening.py),
fits the most promising fully, from the current fit with the candidate at neutral (so no fit ends
worse than the model it extends), and keeps the one whose improvement on the held-out windows is
significant and consistent (Wilcoxon signed-rank over windows, as a z score) and large enough
(robust statistics: a window's error is capped at CAP_MS times the median, so no single window
decides), and that earns the step itself: the model without it, at the candidate fit's values of the
other parameters, must do worse (own_share; else the gain was the fit's, not the effect's). When no single
candidate passes, the best pairs are fitted together. The steps stop when nothing more helps; ``found`` is
judged on the combined model.

Decision records: docs/decisions/0009-held-out-scoring-and-noise-floor.md, docs/decisions/0015-diagnosis-forward-selection.md,
docs/decisions/0022-effects-confined-to-a-regime.md.
"""

from __future__ import annotations

import time

import numpy as np

from ..candidates import Candidate, candidates_for
from ..fit.linalg import FAILURES, failure_reason
from ..fit.session import Fitted, Session
from ..spec import Model
from .compare import where_it_lives
from .extensions import fit_extensions, keep_fits
from .margins import MIN_EXCESS
from .scoring import (
    CAP_MS,
    MIN_STEP,
    MIN_T,
    Diagnosis,
    Scored,
    Screened,
    consistency,
    correlations,
    failed_score,
    own_share,
    passes,
    records_of,
    score,
)
from .screening import column, linearise, predicted_gain
from .selection import MIN_GAIN, further_down, pairs_to_fit, past_bound, to_fit
from .summary import summary, unexplained
from .verdict import delivered_fit, judge

MAX_STEPS = 3  # effects added at most in one diagnosis
PAIR_BELOW = 0.8  # pairs (selection.PAIR_TOP) are tried when the best passing single removes less than this share...
PAIR_MARGIN = 0.2  # ...of the excess left, and a pair is taken over it when its score is higher by this much


def _screen(session: Session, current: Fitted, cands: list[Candidate]):
    """The score test of every candidate at the current fit: (linearisation, columns, each column's time, predicted
    gains). A column is one simulation with the candidate in: its time is the guess at the candidate fit's cost."""
    lin = linearise(current)
    cols, cost = {}, {}
    for c in cands:
        t0 = time.perf_counter()
        cols[c] = column(session, current, c, lin)
        cost[c] = time.perf_counter() - t0
    return lin, cols, cost, {c: predicted_gain(lin, [cols[c]]) for c in cands}


def switch_siblings(cands: list[Candidate], chosen: list[Candidate], cols: dict, scored: list[Scored]
                    ) -> list[Candidate]:
    """The forms left unfitted of a phenomenon whose structural switch passed. A switch that passes says its
    phenomenon is there; which form is a fit's question, not the score test's (FORM_SHARE). Seen: a lagging belt on
    a loaded machine's record, the measured drive passing at 63 % of the excess while the score test put the lag's
    own form at 114 against a cut of 917; fitted, the lag took the error to the floor (decision 15's note)."""
    return [c for c in cands if c not in chosen and any(
        s.cands[0].phenomenon == c.phenomenon and cols[s.cands[0]].switch and passes(s) for s in scored)]


def _step(session: Session, base: Fitted, current: Fitted, floor_holder: dict, say, workers,
          first: bool, model: Model, seen: dict | None = None,
          prefix: tuple[Candidate, ...] = (), failed: dict | None = None
          ) -> tuple[list[Scored], list[Screened], Scored | None]:
    """One forward-selection step: screen, fit the most promising, pairs if no single passes. Every fit is kept in
    ``seen`` (by the set of candidates the base model was extended by; ``prefix``: the current model's), every fit
    that failed numerically in ``failed`` (the same keys, its reason: reported, decision 50). ``model``:
    the model file the diagnosis started from (its values are every fit's cold start; users_fit fits from it)."""
    seen = {} if seen is None else seen
    failed = {} if failed is None else failed
    cold = {n: p.value for n, p in model.params().items()}
    cands = candidates_for(current.model)
    if not cands:
        return [], [], None
    lin, cols, cost, gains = _screen(session, current, cands)
    worth = MIN_GAIN
    if not first:  # the excess left, in cost units: a step must be predicted to reach a fair share of it
        e, f = current.rms(session.primary), floor_holder[session.primary]
        worth = max(MIN_GAIN, 0.5 * MIN_STEP * lin.cost * max(1.0 - (f / e) ** 2, 0.0))
    chosen = to_fit(gains, first, worth)
    # a structural switch is no derivative: its screening only ranks it loosely, so it is fitted in every step (in
    # the first step only, a pair case's second effect, the belt's ripple, went unfitted in step 2 once a fourth
    # phenomenon had pushed it out of the pairs of step 1: the conclusion hung on how many phenomena were fitted)
    chosen += [c for c in cands if cols[c].switch and c not in chosen]
    top = sorted(gains.items(), key=lambda cg: -cg[1])[:6]
    say(f"screened {len(cands)} candidates (score test, predicted cost decrease: "
        + ", ".join(f"{c.label} {g:.3g}" for c, g in top) + f"); fitting {', '.join(c.label for c in chosen) or 'none'}")
    if not chosen:
        return [], sorted((Screened(c, g) for c, g in gains.items()), key=lambda s: -s.predicted_gain), None

    def singles(these: list[Candidate]) -> list[Scored]:
        why: dict = {}
        fits = fit_extensions(session, current, [(c,) for c in these], workers, cold=cold, cost=cost,
                              floors=floor_holder if not floor_holder else None, failures=why, on_done=_told(say))
        keep_fits(seen, prefix, fits)
        keep_failed(failed, prefix, why)
        return [score(base, current, fits[(c,)], (c,), floor_holder[session.primary], session, gains[c])
                if (c,) in fits else failed_score((c,), why[(c,)], gains[c]) for c in these]

    scored = singles(chosen)
    siblings = switch_siblings(cands, chosen, cols, scored)
    if siblings:
        say(f"a switch passes: fitting its other forms too: {', '.join(c.label for c in siblings)}")
        scored += singles(siblings)
        chosen += siblings
    scored.sort(key=lambda s: -s.score)
    floor = floor_holder[session.primary]
    if first and current.rms(session.primary) <= (1.0 + MIN_EXCESS) * floor:
        return scored, _unfitted(gains, chosen), None  # no excess to explain (the singles only rank): no pairs either
    ok = _taken(session, base, current, scored, floor, say)
    if not (ok and ok[0].step_reduction >= PAIR_BELOW):  # a second look before pairs: the bound the step crossed,
        # and where no single passed, the phenomena ranked next (selection.py)
        extra = past_bound(lin, cols, gains, first, worth, chosen, say)
        extra += further_down(gains, chosen + extra, worth, say) if not ok else []
        if extra:
            more = singles(extra)
            chosen += extra
            scored = sorted(scored + more, key=lambda s: -s.score)
            ok = sorted(ok + _taken(session, base, current, more, floor, say), key=lambda s: -s.score)
    screened = _unfitted(gains, chosen)
    if ok and ok[0].step_reduction < PAIR_BELOW:
        better = users_fit(session, model, base, current, ok[0], prefix, floor, say, failed)
        if better is not None:
            keep_fits(seen, prefix, {better.cands: better.fitted})
            ok = [better] + ok[1:]
            scored = sorted([better] + [s for s in scored if s.cands != better.cands], key=lambda s: -s.score)
    if ok and ok[0].step_reduction >= PAIR_BELOW:
        return scored, screened, ok[0]
    return scored, screened, _pairs(session, base, current, lin, cols, scored, ok, floor, say, workers, cold, cost,
                                    seen, prefix, failed)


def _told(say):
    """fit_extensions' on_done for a step's fits: each refit said, a failed one with its reason."""
    def done(task: tuple[Candidate, ...], failure: str | None = None) -> None:
        label = " + ".join(c.label for c in task)
        say(f"  refitted with {label}" if failure is None else f"  the fit with {label} failed: {failure}")
    return done


def keep_failed(failed: dict, prefix: tuple[Candidate, ...], why: dict[tuple[Candidate, ...], str]) -> None:
    """Remember each failed fit's reason by the set of candidates the base model was extended by (as keep_fits)."""
    for task, reason in why.items():
        failed[frozenset(prefix + task)] = reason


def users_fit(session: Session, model: Model, base: Fitted, current: Fitted, best: Scored,
              prefix: tuple[Candidate, ...], floor: float, say, failed: dict | None = None) -> Scored | None:
    """The best passing single, short of PAIR_BELOW, fitted as `model add` + `compare` will fit it (delivered_fit:
    the model file with the current model's members and this one added, each from the file's values); its score
    where that is better and it passes and earns its step (own_share) as the diagnosis's own fit did, else None.
    Why: the diagnosis fits a single from the current fit, whose other values have compensated for what is missing;
    the user's path starts from the file's values and can reach a better basin. Seen on the aging slider (issue 14's
    record): stick-time (log) 76-77 % of the excess in the diagnosis's fit, 98 % on the user's path; below PAIR_BELOW
    the step fitted 12 pairs it did not need, and the promise (98 %) was not the share the step had judged. Where the
    single is then named, the promise is this same fit (Session.fit keeps a model's own fit), so the refit costs
    nothing then; only a short single that pairs then beat costs one fit more."""
    try:
        fitted = delivered_fit(session, model, list(prefix) + list(best.cands))
    except FAILURES as exc:  # the diagnosis's own fit stands (decision 50)
        say(f"  {best.label} as the user's path fits it: the fit failed: {failure_reason(exc)}")
        if failed is not None:
            failed[frozenset(prefix + best.cands)] = failure_reason(exc)
        return None
    again = score(base, current, fitted, best.cands, floor, session, best.predicted_gain)
    if not (passes(again) and again.score > best.score and own_share(session, base, current, again, floor)):
        return None
    say(f"{best.label} as the user's path fits it: {again.step_reduction:.0%} of the excess left (the diagnosis's "
        f"own fit {best.step_reduction:.0%})")
    return again


def _unfitted(gains: dict[Candidate, float], chosen: list[Candidate]) -> list[Screened]:
    return sorted((Screened(c, g) for c, g in gains.items() if c not in chosen), key=lambda s: -s.predicted_gain)


def _taken(session: Session, base: Fitted, current: Fitted, scored: list[Scored], floor: float, say) -> list[Scored]:
    """The singles that pass and earn their step themselves (own_share), best first."""
    ok = [s for s in scored if passes(s)]
    for s in [s for s in ok if not own_share(session, base, current, s, floor)]:
        say(f"{s.label}: without it, at its fit's other values, the model reaches {s.error_neutral:.3g} (its fit "
            f"{s.error:.3g}): the fit improved, not the effect; not taken")
        ok.remove(s)
    return sorted(ok, key=lambda s: -s.score)


def _pairs(session: Session, base: Fitted, current: Fitted, lin, cols: dict, scored: list[Scored],
           ok: list[Scored], floor: float, say, workers, cold: dict[str, float], cost: dict, seen: dict,
           prefix: tuple[Candidate, ...], failed: dict) -> Scored | None:
    """No single passes, or the best leaves much of the excess: two effects at once may explain what neither
    does alone, and a single that mimics part of both (a mass for a friction keyed to acceleration) must
    not stand in for them. The pairs: pairs_to_fit; one is taken over a passing single only when clearly better."""
    pairs = pairs_to_fit(lin, cols, scored)
    if not pairs:
        return ok[0] if ok else None
    say(("no single candidate passes" if not ok else f"the best, {ok[0].label}, leaves "
         f"{1 - ok[0].step_reduction:.0%} of the excess") + "; fitting pairs: "
        + ", ".join(a.label + " + " + b.label for a, b in pairs))
    why: dict = {}
    pfits = fit_extensions(session, current, pairs, workers, cold=cold, cost=cost, failures=why, on_done=_told(say))
    keep_fits(seen, prefix, pfits)
    keep_failed(failed, prefix, why)
    pscored = sorted((score(base, current, pfits[p], p, floor, session) for p in pairs if p in pfits),
                     key=lambda s: -s.score)
    say("pairs: " + ", ".join([f"{s.label} {s.step_reduction:.0%} (z {s.t_stat:.1f})" for s in pscored]
                              + [f"{' + '.join(c.label for c in p)} failed" for p in why]))
    pok = [s for s in pscored if passes(s) and (not ok or s.score >= ok[0].score + PAIR_MARGIN)
           and own_share(session, base, current, s, floor)]
    return pok[0] if pok else (ok[0] if ok else None)


def prune(session: Session, base: Fitted, final: Fitted, members: list[Candidate], floor: float, say,
          workers, seen: dict | None = None, failed: dict | None = None) -> tuple[list[Candidate], Fitted]:
    """The backward check of forward selection: each effect of the final model must still pass as the last
    one added to all the others. The model without it is refitted from the final fit's values (the others'
    fitted values, not their neutral starts: so it keeps any better basin the whole sequence found); the
    weakest that fails is dropped, and the check repeats. Why: a later step or a pair can lift the fit of an
    earlier effect into a better basin and take the credit for it (seen at 100 Hz on a 60 s ramp: stick-time
    alone, fitted from neutral, stopped at 63 % of the excess with Dc at its bound; paired with an Arrhenius
    temperature term of theta = -26 K, i.e. nothing, the pair reached 97 %), and collinear effects enter in
    the wrong order (on a deceleration ramp time, temperature and belt speed move together: a linear
    temperature term went in before the velocity strengthening that made the data)."""
    members = list(members)
    while len(members) >= 2:
        tasks = [tuple(m for m in members if m is not x) for x in members]
        why: dict = {}
        fits = fit_extensions(session, final, tasks, workers, root=base.model, failures=why)
        if seen is not None:
            keep_fits(seen, (), fits)
        if failed is not None:
            keep_failed(failed, (), why)
        # a member whose check cannot be fitted (the model without it failed numerically) is not checked: it stays
        checks = [(x, score(base, fits[t], final, (x,), floor, session)) for x, t in zip(members, tasks) if t in fits]
        say("backward check: " + ", ".join([f"{x.label} {s.step_reduction:.0%} (z {s.t_stat:.1f}) "
                                            f"{'holds' if passes(s) else 'fails'}" for x, s in checks]
                                           + [f"{x.label} not checked (the fit without it failed: {why[t]})"
                                              for x, t in zip(members, tasks) if t in why]))
        weak = [(x, s) for x, s in checks if not passes(s)]
        if not weak:
            break
        x, _ = min(weak, key=lambda xs: xs[1].score)
        final = fits[tasks[members.index(x)]]
        members.remove(x)
        say(f"  dropped {x.label}: the others explain what it did")
    return members, final


# --------------------------------------------------------------------------- the whole diagnosis


def diagnose(session: Session, model: Model, progress=None, workers: int | None = None,
             base: Fitted | None = None, max_steps: int = MAX_STEPS, deliver: bool = True) -> Diagnosis:
    """Forward selection, the backward check, margins (judge), and with ``deliver`` what `model add` + `compare` will
    deliver (delivered_fit: the promise; without it the diagnosis's own fit stands in, as for a conclusion alone)."""
    say = progress or (lambda msg: None)
    if base is None:
        say(f"fitting the model ({len(model.free_names())} free parameters) on {len(session.win.select(False))} windows")
        base = session.fit(model)
    primary = session.primary
    unit = session.m.units[primary]
    e0 = base.rms(primary)
    say(f"model error {e0:.4g} {unit} on held-out windows; screening what it may lack")
    floors: dict[str, float] = {}
    current, sequence = base, []
    first_scored: list[Scored] = []
    first_screened: list[Screened] = []
    seen: dict = {}
    failed: dict = {}  # fits that failed numerically, keyed as ``seen``: reported, the diagnosis goes on
    entered: dict[Candidate, list[Scored]] = {}  # each member: the singles of the step it entered in (its rivals)
    for k in range(max_steps):
        prefix = tuple(c for s in sequence for c in s.cands)
        scored, screened, accepted = _step(session, base, current, floors, say, workers, first=(k == 0), model=model,
                                           seen=seen, prefix=prefix, failed=failed)
        if k == 0:
            first_scored, first_screened = scored, screened
            say(f"noise floor {floors[primary]:.4g} {unit}")
            if e0 <= (1.0 + MIN_EXCESS) * floors[primary]:
                break
        if accepted is None:
            break
        sequence.append(accepted)
        entered.update({c: scored for c in accepted.cands})
        current = accepted.fitted
        say(f"step {k + 1}: + {accepted.label} removes {accepted.step_reduction:.0%} of the excess left "
            f"(z {accepted.t_stat:.1f}); error {accepted.error:.4g} {unit}")
        if current.rms(primary) <= (1.0 + MIN_EXCESS) * floors[primary]:
            break
    floor = floors[primary]
    members = [c for s in sequence for c in s.cands]
    # The backward check also for a pair taken in one step: its refits start from the pair's values, and the single
    # fitted from neutral can sit in a poorer basin (skipping it here named temperature beside the slider's aging,
    # tests/long: stick-time (log) alone 61 % from neutral, the pair 96 %, the margin against the single +0.34)
    if len(members) >= 2:
        members, current = prune(session, base, current, members, floor, say, workers, seen, failed)
    search, verdicts, delivered = current, [], None
    cap = CAP_MS * float(np.median(base.ms_held[primary])) if base.ms_held else float("inf")
    while members:
        if deliver:  # the promise, and the fit the margins are judged on when it is the better one (decision 28)
            say("what the user gets: the model file + " + ", ".join(c.label for c in members) + ", fitted as compare does")
            try:
                delivered = delivered_fit(session, model, members)
            except FAILURES as exc:  # the diagnosis's own fit is the promise then, and the failure is reported
                failed[frozenset(members)] = f"as `model add` + `compare` fit it: {failure_reason(exc)}"
                say(f"  that fit failed: {failure_reason(exc)}; the diagnosis's own fit stands in")
                delivered = None
            if delivered is not None and fit_error(session, delivered) < fit_error(session, current):
                say(f"  the user's path fits better than the diagnosis's ({delivered.rms(primary):.4g} against "
                    f"{current.rms(primary):.4g} {unit} held out): margins judged on it")
                current = seen[frozenset(members)] = delivered
        kept, current, verdicts = judge(session, base, current, members, entered, seen, floor, say, workers,
                                        cap=cap, min_t=MIN_T, failed=failed)
        if kept == members:
            break
        members, search = kept, current  # one dropped: the rest's promise is fitted again
    if [c for s in sequence for c in s.cands] != members:  # what is left, scored as one step from the base model
        sequence = [score(base, base, search, tuple(members), floor, session)] if members else []
    excess_ratio = (e0 - floor) / floor if floor > 0 else float("inf")
    total = (e0 - current.rms(primary)) / (e0 - floor) if e0 > floor else 0.0
    z_total = (consistency(session.weighted(base.ms_held, base.held.windows)
                           - session.weighted(current.ms_held, current.held.windows),
                           records_of(session, current.held.windows)) if sequence else 0.0)
    # every step passed on its own held-out evidence; the combined model must hold up as a whole too
    found = bool(sequence and excess_ratio > MIN_EXCESS and total >= MIN_STEP and z_total >= MIN_T)
    search_total = (e0 - search.rms(primary)) / (e0 - floor) if e0 > floor and members else 0.0
    delivered = delivered if found else None
    corr = correlations(session, base)
    d = Diagnosis(base, floor, floors, first_scored, found, "", corr, sequence, first_screened,
                  current if sequence else None, verdicts, delivered, search_total, failed=failed)
    d.rest = unexplained(session, d) if found else None
    if (not found and excess_ratio > MIN_EXCESS) or d.rest is not None:
        say("where the model fails: cycle phases, loading, ringing")
        d.where = where_it_lives(*session.where_view(d.promised))
    d.summary = summary(session, d, excess_ratio)
    return d


def fit_error(session: Session, f: Fitted) -> float:
    """A fit's mean square on the fit windows, each output in units of its noise: which of two fits of one model is
    the better one, read off the data it was fitted to (not the held-out windows it is judged on; the window
    weights of two fits need not be the same, so not their costs)."""
    return float(np.mean(session.weighted(f.ms_fit, f.fit.windows)))
