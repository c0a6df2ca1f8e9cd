"""Which candidates a diagnosis step fits: pure rules over the score test's predicted gains (daq/models/diagnosis/screening.py)
and the singles' ranking, apart from the fits themselves (daq/models/diagnosis/diagnose.py runs the step).

Why rules and not "fit everything": a fit costs seconds to minutes (a rate-and-state fit on a 90 s slider record,
minutes), a step screens 9-16 candidates, and pairs grow as their square. The score test ranks loosely, so each
rule below carries the case that set it. Decision record: docs/decisions/0015-diagnosis-forward-selection.md.
"""

from __future__ import annotations

from itertools import combinations

from ..candidates import Candidate
from .screening import gain_past_bound, predicted_gain

FIT_PHENOMENA = 3  # per step, the phenomena with the largest predicted gains get full fits...
SCREEN_TIE = 0.5  # ...and every other phenomenon predicted at least this share of the last of those: the score test
# ranks loosely, and a cut among near-equal predictions made the conclusion hang on a machine's last bits (decision
# 28: a spring predicted at 0.63 of the third phenomenon, fitted or not as the cut moved by one, changed what was
# named). Within 2x of the cut a phenomenon gets its fit, and with it its say as a rival (the margins)
FORM_SHARE = 0.0  # ...each in every form (the score test cannot choose between forms: they mirror each other:
# accel-sign keyed to the body with -amp is nearly the relative form with +amp, yet the score test rated
# them 20x apart on one recording, and the one rated lower was the better fit)
PAIR_TOP = 3  # when no single passes (or the best leaves much): pairs among this many best singles
MIN_GAIN = 3.3  # a predicted cost decrease below this is noise (0.5 chi2_1 at p = 0.01): not fitted


def to_fit(gains: dict[Candidate, float], first: bool, worth: float = MIN_GAIN) -> list[Candidate]:
    """The best FIT_PHENOMENA phenomena by predicted gain (and any predicted within SCREEN_TIE of the last of
    them), each in its forms predicted within FORM_SHARE of its best; candidates predicted below ``worth`` are
    not worth a fit (noise, or too small a share of the excess to pass MIN_STEP); in the first step the two best
    phenomena are fitted anyway: the prediction is only first order."""
    by_phen: dict[str, list[tuple[float, Candidate]]] = {}
    for c, g in gains.items():
        by_phen.setdefault(c.phenomenon, []).append((g, c))
    ranked = sorted(by_phen.values(), key=lambda lst: -max(g for g, _ in lst))
    if len(ranked) > FIT_PHENOMENA:  # the cut is not put between near-equal predictions (SCREEN_TIE)
        cut = SCREEN_TIE * max(g for g, _ in ranked[FIT_PHENOMENA - 1])
        ranked = ranked[:FIT_PHENOMENA] + [lst for lst in ranked[FIT_PHENOMENA:] if max(g for g, _ in lst) >= cut]
    out = []
    for i, lst in enumerate(ranked):
        best = max(g for g, _ in lst)
        if best < worth and not (first and i < 2):
            continue
        out += [c for g, c in sorted(lst, key=lambda gc: -gc[0]) if g >= FORM_SHARE * best or g == best]
    return out


def past_bound(lin, cols: dict, gains: dict[Candidate, float], first: bool, worth: float,
               chosen: list[Candidate], say) -> list[Candidate]:
    """Candidates the score test cut only because their first-order step crosses their strength's bound, fitted
    when their score past the bound would have put them among those fitted (:func:`to_fit`). Asked only when the
    singles fitted leave the step open (none passes, or the best leaves much of the excess), before pairs: where
    they explain the record it costs no fit (on `make test`'s diagnoses it fired in 6 tests asked first, +37 CPU-s
    of 199 in test_diagnose.py, and changed no conclusion).

    Why: the current fit may stand where other parameters make up for the missing effect, and the linear step
    from there is no guide to the sign. Seen: the aging slider (Dieterich's law, tests/refsim/slider.py) at 4 and
    16 mm/s judged together; the model without aging fitted at viscous damping 0.30 and k_fall 0.37 (truth 0 and
    0.30), where stick-time's step pointed below 0 (gain -0.0015) with a score of 18886 past the bound, third of
    nine. Cut, it was never fitted and nothing was named at 3.8x the floor; fitted, it took the error from 5.39 to
    1.44 um on a 1.42 um floor, the other parameters back at the truth."""
    past = {c: gain_past_bound(lin, cols[c]) for c in gains if c not in chosen}
    past = {c: g for c, g in past.items() if g > gains[c] and g >= worth}  # not the first step's two below worth
    extra = [c for c in to_fit({**gains, **past}, first, worth) if c in past]
    if extra:
        say("fitted past the score test's bound (its step would cross it; a compensating fit may mislead the sign): "
            + ", ".join(f"{c.label} {past[c]:.3g}" for c in extra))
    return extra


def pairs_to_fit(lin, cols: dict, scored: list) -> list[tuple[Candidate, Candidate]]:
    """_pairs' pairs, the best predicted first (``scored``: the singles fitted, diagnose.Scored, best first): of
    different phenomena, among the PAIR_TOP best by their best form's score and every structural switch fitted (it
    ranks loosely by its fit alone, as by its screening: seen 2026-11-29, the belt's measured drive 5th alone at 13 %,
    beside accel-sign (body) 96 %, pushed out by a spring), each phenomenon in every form fitted (a form that explains
    less alone can explain more beside another effect)."""
    phen = list(dict.fromkeys(sc.cands[0].phenomenon for sc in scored))[:PAIR_TOP]
    phen += [p for p in dict.fromkeys(sc.cands[0].phenomenon for sc in scored if cols[sc.cands[0]].switch)
             if p not in phen]
    top = [sc.cands[0] for sc in scored if sc.cands[0].phenomenon in phen]
    pairs = [(a, b) for a, b in combinations(top, 2) if a.phenomenon != b.phenomenon]
    return sorted(pairs, key=lambda ab: -predicted_gain(lin, [cols[ab[0]], cols[ab[1]]]))


def further_down(gains: dict[Candidate, float], chosen: list[Candidate], worth: float, say) -> list[Candidate]:
    """When no single fitted passes: the next FIT_PHENOMENA phenomena by predicted gain (each worth a fit, by
    :func:`to_fit`'s rules), fitted before pairs of the singles that failed. Why: the score test ranks loosely, and
    pairs of failed singles cost many fits where one unfitted single may explain the record. Seen 2026-11-29: the
    aging slider stepping 4 <-> 2 mm/s (tests/long/test_slider_aging.py), stick-time predicted 352 against
    23400-30300 for the drive, temperature and rate-and-state, none of which passed; their pairs took up to 17 CPU-min
    each (rate-and-state on a 90 s record) and the diagnosis had not ended in 24 min. stick-time (log) added and
    fitted as `compare` does: 23.1 -> 1.87 um on a 1.42 um floor."""
    done = {c.phenomenon for c in chosen}
    extra = to_fit({c: g for c, g in gains.items() if c.phenomenon not in done}, False, worth)
    if extra:
        say("no single passes, and the score test ranks loosely: the next phenomena before pairs: "
            + ", ".join(f"{c.label} {gains[c]:.3g}" for c in extra))
    return extra
