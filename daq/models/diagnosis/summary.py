"""What a diagnosis says: its summary in words (what is missing, with its margins and the commands that add it; or why
nothing is named, and where in the cycle and the mechanics the model fails) and where the excess it leaves lives.
Kept apart from the search (diagnose.py): a new sentence is added here, not inside the search.
Decision records: docs/decisions/0028-margins-and-honest-ties.md, docs/decisions/0030-real-records-cycles-windows-floor.md.
"""

from __future__ import annotations

import math

import numpy as np

from daq.physics.catalog import CATALOG

from ..candidates import Candidate, add_command
from ..fit.session import Session
from .compare import RINGS_OFF
from .margins import MIN_EXCESS, NOTHING
from .scoring import MIN_T, Diagnosis, correlations, windows_needed, z_attainable


def _meaning(c: Candidate) -> str:
    if c.kind == "mechanics":
        return "the rig's " + c.name.split("_")[0] + " differs from its config"
    return CATALOG[c.name].form_meaning(c.form)


WHOLE = 0.7  # an explanation that removes less of the excess than this is reported as partial, with where the rest is


def unexplained(session: Session, d: Diagnosis) -> dict | None:
    """Where the excess the named effects leave lives, when they leave more than 1 - WHOLE of it: per signal (error
    against its floor), the held-out windows that carry most of it (time, error), and what the windows' errors
    follow (residual_correlations of the promised fit)."""
    p = session.primary
    f = d.promised
    share = d.reduction(f, p)
    if share >= WHOLE or not f.ms_held:
        return None
    ms = f.ms_held[p]
    t = session.window_t(f.held.windows)
    worst = np.argsort(-ms, kind="stable")[:3]
    sources = getattr(session, "sources", None)
    rec = session.win.record[f.held.windows] if sources and len(sources) > 1 else None
    return {"share_left": 1.0 - share,
            "by_signal": {k: {"error": float(math.sqrt(np.mean(v))), "noise_floor": d.floors.get(k)}
                          for k, v in f.ms_held.items()},
            "worst_windows": [{**({"data": sources[rec[i]]} if rec is not None else {}),
                               "t_s": float(t[i]), "error": float(math.sqrt(ms[i])),
                               "share_of_squared_error": float(ms[i] / ms.sum())} for i in worst],
            "follows": correlations(session, f)[:3]}


def summary(session: Session, d: Diagnosis, excess_ratio: float) -> str:
    """The diagnosis's summary: what it names (or why nothing), and which of its fits failed."""
    text = _summary_of_effects(session, d, excess_ratio)
    if d.failed:
        text += (f" {len(d.failed)} fit{'s' if len(d.failed) > 1 else ''} failed numerically and "
                 f"{'were' if len(d.failed) > 1 else 'was'} left out (" + "; ".join(
                     " + ".join(sorted(c.label for c in key)) or "the model" for key in d.failed) + "; `failed` in the "
                 "JSON says why).")
    return text


def _summary_of_effects(session: Session, d: Diagnosis, excess_ratio: float) -> str:
    unit = session.m.units[session.primary]
    e0, floor = d.base.rms(session.primary), d.floor
    if d.found:
        f = d.promised
        share = d.reduction(f, session.primary)
        added = [v.cand for v in d.verdicts] or [c for s in d.sequence for c in s.cands]
        decided = [v for v in d.verdicts if v.decided]
        tied = [v for v in d.verdicts if not v.decided]
        parts = []
        if decided:
            parts.append("The model misses " + "; ".join(
                f"'{v.cand.label}' ({_meaning(v.cand)}; margin {v.weakest.share:+.2f} of the excess over "
                f"{_rival(v.weakest.rival)}, 5 % bound {v.weakest.lower:+.2f})" for v in decided) + ".")
        for v in tied:
            rivals = [v.cand.label] + [m.rival for m in v.ties]
            parts.append(f"Undecided between {' and '.join(repr(r) for r in rivals)}: '{v.cand.label}' scores "
                         + ", ".join(f"{m.share:+.2f} of the excess against '{m.rival}' (5 % bound {m.lower:+.2f})"
                                     for m in v.ties)
                         + f"; adding '{v.cand.label}' is the better guess, a run that separates them the way to know.")
        for v in d.verdicts:  # a phenomenon named whose form the data cannot tell (decision 32: aging or slip law)
            open_forms = [m for m in v.forms if not m.decided]
            if open_forms:
                run = CATALOG[v.cand.phenomenon].forms_told_apart_by if v.cand.phenomenon in CATALOG else ""
                parts.append(f"Its form is undecided: '{v.cand.label}' scores " + ", ".join(
                    f"{m.share:+.2f} of the excess against '{m.rival}' (5 % bound {m.lower:+.2f}"
                    + ("; it too reaches the noise floor)" if m.rival_at_floor else ")") for m in open_forms)
                    + "; the record does not tell these forms apart" + (f"; a run that does: {run}." if run else "."))
            elif v.forms:
                parts.append(f"Its form: '{v.cand.label}' over " + ", ".join(
                    f"'{m.rival}' by {m.share:+.2f} of the excess (5 % bound {m.lower:+.2f})" for m in v.forms) + ".")
        base_free = set(d.base.model.free_names())
        vals = ", ".join(f"{k.split('.', 1)[-1]} = {f.values[k]:.4g}" for k in f.model.free_names() if k not in base_free)
        cmds = "; ".join(f"daq model add MODEL {add_command(c)}" for c in added)
        whole = (f"Together they remove {share:.0%} of the excess error on held-out windows" if len(added) > 1
                 else f"It removes {share:.0%} of the excess error on held-out windows")
        parts.append(f"{whole} as `model add` + `compare` fit it ({e0:.3g} -> {f.rms(session.primary):.3g} {unit}, "
                     f"noise floor {floor:.3g}); fitted {vals or 'no parameters'}. To add: {cmds}.")
        rest = d.rest
        if rest is not None:
            follows = ", ".join(f"{c['quantity']} (rho {c['spearman_rho']:+.2f})" for c in rest["follows"]
                                if abs(c["spearman_rho"]) > 0.3) or "nothing measured"
            worst = ", ".join(f"t = {w['t_s']:.1f} s ({w['share_of_squared_error']:.0%})" for w in rest["worst_windows"])
            parts.append(f"That is only part: a form the catalog lacks, or another effect, holds the other "
                         f"{rest['share_left']:.0%}; it lives most in the held-out windows at {worst}, and follows "
                         f"{follows}.")
        return " ".join(parts + where_text(d.where, unit))
    if excess_ratio <= MIN_EXCESS:
        return (f"No missing effect: the model's error ({e0:.3g} {unit}) is within {MIN_EXCESS:.0%} of the noise "
                f"floor ({floor:.3g} {unit}).")
    corr = d.correlations
    strong = [c for c in corr if abs(c["spearman_rho"]) > 0.3 and c["p_value"] < 0.01]
    follows = ", ".join(f"{c['quantity']} (rho {c['spearman_rho']:+.2f})" for c in strong[:4]) or "nothing measured"
    best = next((c for c in d.candidates if c.failed is None), None)
    above = f"{excess_ratio:.0%} above" if excess_ratio < 1.0 else f"{1.0 + excess_ratio:.1f}x"
    why = ""
    if best is not None and best.fit_only and best.own_z < MIN_T and best.error_neutral > best.error:
        why = (f"; against the model without it at that fit's other values ({best.error_neutral:.3g} {unit}) its gain "
               f"is not consistent over the held-out windows (z {best.own_z:.2f} < {MIN_T})")
    elif best is not None and best.fit_only:
        why = (f"; the model without it, at that fit's other values, does as well ({best.error_neutral:.3g} {unit}): "
               f"its own fit can still improve")
    n_held = int(session.win.select(True).size)
    few = ""
    if z_attainable(n_held) < MIN_T:
        n_all = int(session.win.starts.size)  # held-out windows are a fixed share of all (make_windows)
        few = (f" Only {n_held} held-out windows: even if every one improved, the consistency test could not pass "
               f"(z {z_attainable(n_held):.1f} < {MIN_T}); a longer record (at least {windows_needed()} held-out windows, "
               f"about {math.ceil(windows_needed() * n_all / max(n_held, 1))} windows in all) can show it.")
    return " ".join([f"The model's error ({e0:.3g} {unit}) is {above} the noise floor, but no catalog "
                     f"effect explains it (best: '{best.label if best else '-'}', {best.reduction if best else 0:.0%}"
                     f"{why}). The residual follows: {follows}.{few}"] + where_text(d.where, unit))


def _rival(name: str) -> str:
    return "the model without it" if name == NOTHING else f"'{name}'"


CREEP_LATE = 0.5  # a record loaded late in the stick at less than this share of the drive's speed creeps
# the record's drops spread (quartiles over the median) more than this many times the model's free run read with the
# record's noise, and more than MIN_SPREAD: cycles that vary beyond noise (the lab's 42 um/s record: 0.25 against
# the seed model's 0.05)
SPREAD_RATIO = 2.0
MIN_SPREAD = 0.15


def where_text(where: dict | None, unit: str) -> list[str]:
    """Sentences for the summary from compare.where_it_lives: the cycle phase that carries most of the error, creep
    the model lacks (loading late in the stick), ringing off the rig file's mechanics."""
    if not where:
        return []
    out = []
    phases = where["by_cycle_phase"]
    if phases:
        worst = max(phases, key=lambda k: phases[k]["error"])
        out.append(f"In the cycle it lives most {'in the ' if worst != 'at the peak load' else ''}{worst} "
                   f"({phases[worst]['error']:.3g} {unit}; " + ", ".join(
                       f"{k} {v['error']:.3g}" for k, v in phases.items() if k != worst) + ").")
    ld = where["loading"]
    late_rec, late_mod = ld["late_record"], ld["late_model"]
    # only against a model that has sticks of its own: without any, the sentence on its missing cycles says it, and
    # a record that never stops (4.3 mm/s) has no stick to creep in, only the rising half of its oscillation
    if np.isfinite(late_rec) and late_rec < CREEP_LATE and np.isfinite(late_mod) and late_mod >= CREEP_LATE:
        out.append(f"In the stick the record is loaded at {ld['early_record']:.2f} of the drive's speed early and "
                   f"{late_rec:.2f} late (the model's {ld['early_model']:.2f} / {late_mod:.2f}): the slider creeps "
                   f"before it slips, and the model does not (missing: creep in the contact law, in the stick's "
                   f"second half).")
    rec, mod = where["cycles"]["record"], where["cycles"]["model"]
    if rec["cycles"] and not mod["cycles"]:
        out.append(f"The record has {rec['cycles']} cycles, the fitted model's free run none: the fit settles on "
                   f"steady sliding and predicts the mean load (missing: what keeps the record cycling).")
    elif rec["cycles"] and mod["cycles"]:
        spread = {who: (c["drop_q75"] - c["drop_q25"]) / c["drop_median"] for who, c in (("record", rec), ("model", mod))}
        if spread["record"] > SPREAD_RATIO * spread["model"] and spread["record"] > MIN_SPREAD:
            out.append(f"The record's drops spread {spread['record']:.2f} of their median (quartiles), the model's "
                       f"{spread['model']:.2f} with the same noise on it: the record's cycles vary more than noise "
                       f"makes a regular cycle vary (missing: a contact that varies along the track, or a chaotic "
                       f"or noise-driven cycle, which a model started from each window's state follows for about a "
                       f"cycle).")
    return out + ringing_text(where["motion"])


SOFTENS_P = 0.01  # a ringing's frequency against its amplitude: a rank correlation beyond this chance is a reading


def ringing_text(mo: dict) -> list[str]:
    """Sentences on a record that rings off the rig file's natural frequency where the model does not (compare.motion),
    and, where the record's ringing was read window by window (``by_amplitude``), the stiffness that holds the slider
    at small amplitude, with the run that decides between a contact stiffness and other mechanics: at half the
    spring's stiffness a contact adds the same stiffness, a lighter slider keeps the ratio."""
    f_rec, f_nat, f_mod = mo["line_Hz_record"], mo["natural_Hz"], mo["line_Hz_model"]
    if not (np.isfinite(f_rec) and np.isfinite(f_nat) and abs(f_rec / f_nat - 1.0) > RINGS_OFF) \
            or (np.isfinite(f_mod) and abs(f_mod / f_rec - 1.0) <= RINGS_OFF / 2
                and mo["band_power_model_over_record"] > RINGS_OFF):
        return []
    out = [(f"The record rings at {f_rec:.3g} Hz where the rig file's mechanics ring at {f_nat:.3g} Hz "
            f"((f / f0)^2 = {(f_rec / f_nat) ** 2:.2f}; the model: {f_mod:.3g} Hz at "
            f"{mo['band_power_model_over_record']:.2g} of the record's power there): a stiffer spring or a "
            f"lighter slider than the rig file's, or a contact that adds stiffness while the slider moves; "
            f"the same run at another spring stiffness tells them apart (missing: mechanics, in the slip).")]
    amp = mo.get("by_amplitude")
    if not amp or not np.isfinite(amp["line_Hz_small"]) \
            or not amp["swing_speed_small"] < amp["drive_speed"]:  # its small swings must slide throughout
        return out
    small, ratio, half = amp["line_Hz_small"], (amp["line_Hz_small"] / f_nat) ** 2, f_nat / np.sqrt(2.0)
    trend = (f" and {amp['line_Hz_large']:.3g} Hz in its largest (Spearman {amp['rho']:+.2f} against the amplitude)"
             if amp["p"] < SOFTENS_P else "")
    out.append(f"Read window by window ({amp['windows']} windows), it rings at {small:.3g} Hz in its smallest quarter of "
               f"swings (peak speed up to {amp['swing_speed_small']:.2g} m/s, the drive's {amp['drive_speed']:.2g})"
               f"{trend}: at small amplitude, where a friction that depends on the speed alone damps the swing but "
               f"does not retune it, the slider is held by {ratio:.2f} times the rig file's stiffness over its mass. "
               f"At half the spring's stiffness a contact stiffness would add the same and ring at "
               f"{half * np.sqrt(2.0 * ratio - 1.0):.3g} Hz, a lighter slider keep the ratio and ring at "
               f"{half * np.sqrt(ratio):.3g} Hz: that run decides (missing: a stiffness in the contact, or the rig "
               f"file's mass or spring).")
    return out
