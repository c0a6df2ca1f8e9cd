"""How firmly the data prefer each effect of a diagnosis, and what the user's own commands will deliver.

judge(): every member of the final model against the model without it and against its plausible rivals refitted in
its place, by the paired bootstrap of margins.py; delivered_fit(): the model file with the members added as
`daq model add` adds them, fitted as `daq compare` fits it. Decision record: docs/decisions/0028-margins-and-honest-ties.md.
"""

from __future__ import annotations

from dataclasses import replace

from ..candidates import Candidate, add_command
from ..fit.session import Fitted, Session
from ..spec import Model
from .extensions import fit_extensions, keep_fits
from .margins import MIN_EXCESS, NOTHING, Verdict, margin
from .scoring import Scored

RIVALS = 2  # per named effect: the best other phenomena of the step it entered in, each refitted in its place...
RIVAL_SHARE = 0.5  # ...that explained at least this share of what the named one did alone in that step



def rivals_for(x: Candidate, singles: list[Scored], members: list[Candidate], min_t: float) -> list[Candidate]:
    """Plausible substitutes for ``x``: the best form of each other phenomenon among the singles of the step x
    entered in (not already a member), consistent (z >= ``min_t``, the step gate's) and explaining at least RIVAL_SHARE of what x did
    alone there; at most RIVALS, best first."""
    taken = {m.phenomenon for m in members}
    own = next((s.reduction for s in singles if s.cands == (x,)), 0.0)
    out: dict[str, Candidate] = {}
    for s in sorted(singles, key=lambda s: (-s.score, s.label)):
        c = s.cands[0]
        if c.phenomenon in taken or c.phenomenon in out:
            continue
        if s.t_stat >= min_t and s.reduction > 0 and s.reduction >= RIVAL_SHARE * own:
            out[c.phenomenon] = c
    return list(out.values())[:RIVALS]


def judge(session: Session, base: Fitted, final: Fitted, members: list[Candidate], entered: dict[Candidate, list],
          seen: dict, floor: float, say, workers, cap: float, min_t: float,
          failed: dict | None = None) -> tuple[list[Candidate], Fitted, list[Verdict]]:
    """Margins for every member of the final model: the paired bootstrap over held-out windows (margins.py) of the
    final model against the model without it and against each plausible rival refitted in its place (fits already
    made are reused from ``seen``; ``cap``: each window's mean square is capped there, as in the step scores). A member the data do not prefer over nothing at that margin is dropped (the
    weakest first, then all are judged again); a rival it does not beat stays standing beside it: a tie.
    Why substitution and not the step's own ranking: a step's singles each extend the model of that step, and an
    effect taken first can stand in for a later one (a mass for a friction keyed to acceleration) until the later
    one is in; only the final model with the rival in the member's place says which the data prefer.
    A refit that fails numerically (its reason kept in ``failed``, by its candidates) leaves that rival out; where
    it is the model without the member, the member is judged against the model without any member (decision 50)."""
    failed = {} if failed is None else failed
    p = session.primary
    excess = base.rms(p) - floor
    members = list(members)
    while members:
        plan: dict[Candidate, list[tuple[str, tuple[Candidate, ...]]]] = {}
        for x in members:
            rest = tuple(m for m in members if m != x)
            rivals = rivals_for(x, entered.get(x, []), members, min_t)
            plan[x] = [(NOTHING, rest)] + [(y.label, rest + (y,)) for y in rivals]
        todo: list[tuple[Candidate, ...]] = []
        for x in members:
            for _, t in plan[x]:
                if t and frozenset(t) not in seen and frozenset(t) not in map(frozenset, todo):
                    todo.append(t)
        if todo:
            say("margins: refitting " + ", ".join(" + ".join(c.label for c in t) for t in todo))
            why: dict = {}
            keep_fits(seen, (), fit_extensions(session, final, todo, workers, root=base.model, failures=why))
            for t, reason in why.items():
                failed[frozenset(t)] = reason
                say(f"  the fit with {' + '.join(c.label for c in t)} failed: {reason}")
        for x in members:  # a rival whose refit failed has no margin: left out; the model without x: without all
            plan[x] = [(name, t if not t or frozenset(t) in seen or name != NOTHING else ())
                       for name, t in plan[x] if not t or frozenset(t) in seen or name == NOTHING]
        verdicts = []
        for x in members:
            ms = [margin(x.label, name, final.ms_held[p], (seen[frozenset(t)] if t else base).ms_held[p], excess, cap)
                  for name, t in plan[x]]
            own = next((s for s in entered.get(x, []) if s.cands == (x,)), None)
            forms = [replace(margin(x.label, s.label, own.fitted.ms_held[p], s.fitted.ms_held[p], excess, cap),
                             rival_at_floor=s.fitted.rms(p) <= (1.0 + MIN_EXCESS) * floor)
                     for s in entered.get(x, []) if own is not None and own.fitted is not None and s.fitted is not None
                     and s.cands[0].phenomenon == x.phenomenon and s.cands != (x,)]
            verdicts.append(Verdict(x, ms, forms))
        say("margins: " + "; ".join(f"{v.cand.label} over {m.rival} {m.share:+.2f} (5 % bound {m.lower:+.2f})"
                                    for v in verdicts for m in v.margins))
        weak = [v for v in verdicts if not v.needed]
        if not weak:
            return members, final, verdicts
        v = min(weak, key=lambda v: (v.margins[0].lower, v.cand.label))
        members.remove(v.cand)
        final = seen.get(frozenset(members), base) if members else base  # (its fit failed: base, decision 50)
        say(f"  dropped {v.cand.label}: the model without it does as well within the margin "
            f"({v.margins[0].share:+.2f}, 5 % bound {v.margins[0].lower:+.2f})")
    return [], base, []


def delivered_fit(session: Session, model: Model, members: list[Candidate]) -> Fitted:
    """What the user gets: the model file with each member added as `daq model add` adds it, fitted as `daq compare`
    fits it (the same session, so the same windows and noise). Why not the diagnosis's own fit: it starts from the
    fitted base model with the candidates' paths, a compare starts from the file's values; the two can end in
    different basins, and a promise is only worth what the user's own commands reproduce."""
    for c in members:
        model = c.apply(model, f"model add {add_command(c)}")
    return session.fit(model)
