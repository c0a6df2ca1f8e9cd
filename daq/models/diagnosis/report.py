"""The reports of compare and diagnose: the diagnosis's JSON, and the text both commands print, built from their
results (a Diagnosis, compare's JSON). Kept apart from the algorithms: diagnose decides, this module says what it
decided; a new field of a report is added here, not inside the search.

Decision record: docs/decisions/0041-models-core-as-a-solver.md.
"""

from __future__ import annotations

import math

import numpy as np

from ..fit.session import Session
from .compare import OUTLIER_SIGMAS
from .scoring import Diagnosis


def diagnosis_json(d: Diagnosis, session: Session) -> dict:
    """The diagnosis as `daq diagnose --json` prints it and diagnose.json keeps it."""
    primary = session.primary
    unit = session.m.units[primary]
    best = d.sequence[0] if d.sequence else None
    final = d.promised
    e0 = d.base.rms(primary)
    out = {
        "data": session.source,
        "filled_samples": session.rec.meta.get("filled", {}),
        "start_from_data": session.law_guess,
        "outliers": {k: int(v.size) for k, v in session.m.outliers.items()},
        "averaged": session.m.averaged,  # the file's samples per compared sample (block means to the model's step)
        "model": d.base.model.describe(),
        "error": e0,
        "error_unit": unit,
        "error_signal": primary,
        "noise_floor": d.floor,
        "excess": e0 - d.floor,
        "missing_effect_found": d.found,
        "best": best.cands[0].phenomenon if (best and d.found) else None,
        "best_form": best.cands[0].form if (best and d.found) else None,
        "summary": d.summary,
        "sequence": _sequence(d),
        "named": [v.cand.label for v in d.verdicts if v.decided] if d.found else [],
        "undecided": [{"between": [v.cand.label] + [m.rival for m in v.ties],
                       "margins": [m.as_json() for m in v.ties]} for v in d.verdicts if v.ties] if d.found else [],
        "margins": [v.as_json() for v in d.verdicts],
        "final_model": final.model.describe(),
        "final_error": final.rms(primary),
        "final_reduction": d.reduction(final, primary),  # what `model add` + `compare` deliver (delivered_fit)
        "search_error": e0 - d.search_total * (e0 - d.floor),  # the diagnosis's own fit of the same model
        "search_reduction": d.search_total,
        "unexplained": d.rest,
        "where": d.where,  # error by cycle phase, loading against the drive, ringing (compare.where_it_lives)
        "candidates": _candidates(d),
        "failed": _failed(d),
        "residual_correlations": d.correlations[:8],
        "windows": _windows(session),
        "noise": {"sigma": session.m.sigma, "source": session.m.sigma_source},
    }
    sources = getattr(session, "sources", None)
    if sources and len(sources) > 1:  # several records (MultiSession): each its own windows, noise and floor
        out["data"] = list(sources)
        out["records"] = session.records_json(final, d.floors)
    return out


def _sequence(d: Diagnosis) -> list[dict]:
    """What was added, one entry per effect (a pair: two), with its margins over its rivals where judged."""
    verdict = {v.cand: v for v in d.verdicts}
    return [{"effect": c.phenomenon, "form": c.form, "label": c.label, "step_reduction": s.step_reduction,
             "reduction": s.reduction, "consistency_z": s.t_stat, "error": s.error, "values": s.values,
             **({"decided": verdict[c].decided, "margin": verdict[c].weakest.share,
                 "margin_lower": verdict[c].weakest.lower, "nearest_rival": verdict[c].weakest.rival,
                 "undecided_with": [m.rival for m in verdict[c].ties]} if c in verdict else {})}
            for s in d.sequence for c in s.cands]


def _candidates(d: Diagnosis) -> list[dict]:
    """The first step's candidates: the fitted ones, best first, then those only screened."""
    return ([{"effect": c.effect, "form": c.form, "label": c.label, "reduction": c.reduction,
              "step_reduction": c.step_reduction, "score": c.score, "error": c.error,
              "consistency_z": c.t_stat, "params_added": c.params_added, "values": c.values,
              "std": c.std, "predicted_gain": c.predicted_gain,
              "error_without_at_its_values": None if math.isnan(c.error_neutral) else c.error_neutral,
              "fit_only": c.fit_only, "failed": None}
             if c.failed is None else
             {"effect": c.effect, "form": c.form, "label": c.label, "reduction": None, "consistency_z": None,
              "values": {}, "predicted_gain": c.predicted_gain, "failed": c.failed}
             for c in d.candidates]
            + [{"effect": s.cand.phenomenon, "form": s.cand.form, "label": s.cand.label, "reduction": None,
                "predicted_gain": s.predicted_gain, "fitted": False} for s in d.screened])


def _failed(d: Diagnosis) -> list[dict]:
    """Every fit of the diagnosis that failed numerically (a candidate, a pair, a margin's refit, the user's path):
    the candidates the model was extended by, and why (decision 50)."""
    return [{"extended_by": sorted(c.label for c in key), "reason": why}
            for key, why in sorted(d.failed.items(), key=lambda kv: sorted(c.label for c in kv[0]))]


def _windows(session: Session) -> dict:
    flagged = session.win.transient if session.win.transient is not None else np.zeros(session.win.starts.size, bool)
    return {"length_s": (session.win.length - 1) / session.m.rate,
            "fit": int(session.win.select(False).size), "held_out": int(session.win.select(True).size),
            "flagged_transient": [float(t) for t in session.window_t(np.flatnonzero(flagged))]}


# ----------------------------------------------------------------------------- text


def diagnosis_text(d: Diagnosis, res: dict) -> str:
    """What `daq diagnose` prints without --json: the summary, the candidates' table, the steps and their margins,
    the promise, and what the residual follows when nothing was found (``res``: diagnosis_json's)."""
    lines = [d.summary, f"  {'candidate':36s} {'reduction':>9s} {'z':>6s}  params"]
    for c in res["candidates"]:
        if c.get("failed"):
            lines.append(f"  {c['label']:36s} {'failed':>9s} {'':6s}  (its fit failed: {c['failed']})")
            continue
        if c["reduction"] is None:
            lines.append(f"  {c['label']:36s} {'-':>9s} {'':6s}  (screened, predicted gain {c['predicted_gain']:.3g}; "
                         "not fitted)")
            continue
        lines.append(f"  {c['label']:36s} {c['reduction']:9.2f} {c['consistency_z']:6.1f}  "
                     + ", ".join(f"{k.rsplit('.', 1)[-1]}={v:.4g}" for k, v in c["values"].items()))
    for step in res["sequence"]:
        lines.append(f"  added: {step['label']} (removes {step['step_reduction']:.0%} of the excess left, "
                     f"z {step['consistency_z']:.1f})")
    for v in res["margins"]:
        lines.append(f"  margin: {v['label']} " + ("named" if v["decided"] else "undecided") + "; " + ", ".join(
            f"over {m['rival']} {m['margin']:+.2f} of the excess (5 % bound {m['margin_lower']:+.2f})"
            for m in v["rivals"]))
    if res["missing_effect_found"]:
        lines.append(f"  promised: {res['final_reduction']:.0%} of the excess, as `model add` + `compare` fit it "
                     f"(the diagnosis's own fit: {res['search_reduction']:.0%})")
    later = [f for f in res["failed"] if f["extended_by"] not in [[c["label"]] for c in res["candidates"]]]
    if later:
        lines.append("  fits that failed (left out, the diagnosis went on): " + "; ".join(
            f"{' + '.join(f['extended_by']) or 'the model'}: {f['reason']}" for f in later))
    if not d.found and d.correlations:
        lines.append("  residual correlates with: " + ", ".join(
            f"{c['quantity']} ({c['spearman_rho']:+.2f})" for c in d.correlations[:5]))
    return "\n".join(lines)


def compare_text(res: dict, report: str | None = None) -> str:
    """What `daq compare` prints without --json (``res``: compare's JSON; ``report``: the folder written, if any)."""
    u = res["error_unit"]
    lines = [(f"error {res['error']:.4g} {u} on held-out windows (noise floor {res['noise_floor']:.4g}; all windows "
              f"{res['error_all_windows']:.4g})  model: {res['model']}"),
             "  by regime: " + "; ".join(f"{k} {v['error']:.3g}" for k, v in res["by_regime"].items()),
             "  by signal: " + "; ".join(f"{k} {v['error']:.3g} {v['unit']} (floor {v['noise_floor']:.3g})"
                                         for k, v in res["by_signal"].items())]
    if res["clock_jitter_s"] > 0:
        lines.append(f"  clock jitter {res['clock_jitter_s'] * 1e3:.3g} ms (samples taken early or late, read from the "
                     "residual's sample-to-sample part growing with speed): counted in the noise floor")
    far = {k: n for k, n in res["residual_outliers"].items() if n}
    if far:
        lines.append(f"  beyond {OUTLIER_SIGMAS:g} noise levels of the model (spikes left, or where it fails): "
                     + ", ".join(f"{k} {n} samples" for k, n in far.items()))
    capped = {k: n for k, n in res["loss_capped"].items() if n}
    if capped:
        lines.append(f"  {res['loss']} loss: counted linearly, not squared (beyond 3 x the window's residual scale): "
                     + ", ".join(f"{k} {n} samples" for k, n in capped.items()))
    lines.append("  invariants (measured / model): " + "; ".join(
        f"{k} {v['measured']:.4g} / {v['model']:.4g}" for k, v in res["invariants"].items()))
    lines += _cycles_text(res)
    mo = res["motion"]
    lines.append(f"  ringing (strongest line within 2x of the rig's lowest natural frequency {mo['natural_Hz']:.3g} Hz, "
                 f"mains masked): record {mo['line_Hz_record']:.3g} Hz, model {mo['line_Hz_model']:.3g} Hz with "
                 f"{mo['band_power_model_over_record']:.2g} of the record's power there")
    amp = mo.get("by_amplitude")
    if amp and amp["windows"]:
        lines.append(f"  ringing by amplitude ({amp['windows']} windows): {amp['line_Hz_small']:.3g} Hz in the smallest "
                     f"quarter (up to {amp['amplitude_q25']:.3g} {res['cycles']['unit']}), {amp['line_Hz_large']:.3g} Hz "
                     f"in the largest (from {amp['amplitude_q75']:.3g}); Spearman {amp['rho']:+.2f} (p {amp['p']:.2g})")
    lines.append(f"  worst regime: {res['worst_regime']}" + (f"; report in {report}/" if report else ""))
    return "\n".join(lines)


def _cycles_text(res: dict) -> list[str]:
    """compare's cycles, record against model free run: medians, the loading in the stick, error by cycle phase."""
    c = res["cycles"]
    lines = [(f"  cycles (record / model free run, medians; {c['record']['cycles']} / {c['model']['cycles']} cycles): "
              f"stick {c['record']['stick_s_median']:.3g} / {c['model']['stick_s_median']:.3g} s "
              f"(at the peak load {c['record']['creep_s_median']:.3g} / {c['model']['creep_s_median']:.3g} s), "
              f"drop {c['record']['drop_median']:.3g} / {c['model']['drop_median']:.3g} {c['unit']}, "
              f"slip {c['record']['slip_s_median']:.3g} / {c['model']['slip_s_median']:.3g} s, "
              f"mean period {c['record']['period_s_mean']:.3g} / {c['model']['period_s_mean']:.3g} s")]
    ld = c["loading"]
    lines.append(f"  loading in the stick, early / late, over the drive's speed: record {ld['early_record']:.2f} / "
                 f"{ld['late_record']:.2f}, model {ld['early_model']:.2f} / {ld['late_model']:.2f} (1: loaded as a "
                 f"stuck slider is; lower late: it creeps before it slips)")
    if res["by_cycle_phase"]:
        lines.append("  error by cycle phase (share of samples): " + ", ".join(
            f"{k} {v['error']:.3g} {res['error_unit']} ({v['fraction']:.0%})" for k, v in res["by_cycle_phase"].items()))
    return lines
