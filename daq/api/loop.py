"""The researcher's loop from Python: ``compare``, ``diagnose``, ``propose`` over recordings and model files.

Each function does what its command does, through the same calls in the same order (daq/cli/models.py's
``cmd_compare`` and ``cmd_diagnose``, daq/cli/propose.py's ``cmd_propose``), and returns the command's JSON as a
typed result (results.py); tests/test_api.py holds the two to the same JSON on one record. Why not call the
command line: a notebook wants the objects (a figure drawn again, a field read as an attribute) without a
subprocess, and the same exceptions (``InputError`` naming file and field) the commands turn into one line.

``data`` is a path (a recording .h5, an interchange CSV or TDMS with ``rig=``), a ``Recording`` from
``daq.io.open`` (a lab's MATLAB or text file opened with ``rig=`` and ``maps=``), or a list of paths (several
recordings of one rig, judged together with one model). ``model`` is a model file's path or a ``Model``.
Progress lines go to ``progress`` (default: none; ``print`` shows them as the commands do on stderr).
"""

from __future__ import annotations

import json as _json
import math
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from daq.errors import InputError
from daq.io.jsonout import dumps_json
from daq.io.loading import uniform
from daq.io.plausible import check_values
from daq.io.recording import Recording
from daq.models.candidates import Candidate, candidates_for, parse_candidate
from daq.models.design import proposal as design
from daq.models.design.programmes import write_programme
from daq.models.diagnosis.compare import compare as compare_fitted
from daq.models.diagnosis.diagnose import diagnose as diagnose_session
from daq.models.diagnosis.report import compare_text, diagnosis_json, diagnosis_text
from daq.models.figures import (
    compare_figure,
    cycles_figure,
    diagnose_figure,
    proposal_figure,
    ringing_figure,
    spectrogram_figure,
)
from daq.models.fit.multi_session import MultiSession
from daq.models.fit.session import Session
from daq.models.spec import Model, load_model, rig_config_for, save_model

from . import MAX_RUN_S, MIN_RUN_S
from .results import Comparison, Diagnosis, Proposal

Progress = Callable[[str], None]
Data = str | Path | Recording | Sequence[str | Path]



def _quiet(msg: str) -> None:
    pass


def _model(model: str | Path | Model) -> Model:
    return model if isinstance(model, Model) else load_model(model)


def _session(data: Data, model: Model, rig: str | None, loss: str, several_ok: bool = True):
    """The session the commands open: one record (``Session``) or several of one rig (``MultiSession``)."""

    if isinstance(data, Recording):
        # daq.io.open's recording: checked and put on one time base as load_data does a file it reads
        cfg = rig_config_for(model)
        if data.rig is not None and data.rig != model.rig:
            raise InputError("recording", "rig", f"the recording is from {data.rig}, not {model.rig}")
        source = str(data.meta.get("source", "recording"))
        # NaN allowed as in a recorder's file (where a stream had no data; uniform fills it in): a file imported
        # through daq.io.open was refused non-finite values by the import
        check_values(source, data.t, data.channels, cfg, allow_nan=True)
        return Session(uniform(data, source), source, cfg, loss=loss)
    if isinstance(data, (str, Path)):
        return Session.open(data, model, rig, loss=loss)
    paths = [str(p) for p in data]
    if not paths:
        raise InputError("data", "data", "no recording given")
    if len(paths) == 1:
        return Session.open(paths[0], model, rig, loss=loss)
    if not several_ok:
        raise InputError("data", "data", "one recording at a time here")
    return MultiSession.open(paths, model, rig, loss=loss)


def compare(data: Data, model: str | Path | Model, *, rig: str | None = None, loss: str = "huber",
            report: str | Path | None = None, predict: bool = False, progress: Progress = _quiet) -> Comparison:
    """`daq compare DATA --model MODEL [--report DIR] [--predict]`: fit the model's free parameters (multiple
    shooting; with ``predict`` none, the model as its file states it), score it on the held-out windows against the
    noise floor, and say where it fails. With ``report`` the command's folder is written (compare.png,
    spectrogram.png, cycles.png, ringing.png, compare.json, fitted.toml). The command also appends to its history
    file; this does not (``daq history`` reads that file)."""
    m = _model(model)
    return compared(_session(data, m, rig, loss, several_ok=False), m, report=report, predict=predict,
                    progress=progress)


def compared(s: Session, m: Model, *, report: str | Path | None = None, predict: bool = False,
             progress: Progress = _quiet) -> Comparison:
    """compare on an opened session: what ``compare`` and `daq compare` both run."""
    if predict:  # the model as its file states it: nothing fitted but each window's start state
        m = m.with_fixed()
        progress("the model as its file states it (--predict): only each window's start state fitted")
    else:
        progress(f"fitting {len(m.free_names())} free parameters")
    f = s.fit(m)
    progress("noise floor: the fitted model scored on its own simulated output with the measured noise")
    floor = s.noise_floor(f)
    progress("forward simulation and breakdowns")
    cmp = compare_fitted(s, f, floor)
    res = cmp.result
    res["predicted"] = predict  # True: no parameter fitted
    if report is not None:
        rep = Path(report)
        rep.mkdir(parents=True, exist_ok=True)
        compare_figure(s, f, res, rep / "compare.png")
        spectrogram_figure(s, cmp.drawn, rep / "spectrogram.png")
        cycles_figure(s, res, cmp.drawn, rep / "cycles.png")
        ringing_figure(s, res, cmp.drawn, rep / "ringing.png")  # where the record rings off the rig's mechanics
        (rep / "compare.json").write_text(dumps_json(res))
        save_model(f.model, rep / "fitted.toml")
        res["report"] = str(rep)
    return Comparison(res, lambda path: compare_figure(s, f, res, path), compare_text(res, str(report) if report else None))


def diagnose(data: Data, model: str | Path | Model, *, rig: str | None = None, loss: str = "huber",
             workers: int | None = None, report: str | Path | None = None,
             progress: Progress = _quiet) -> Diagnosis:
    """`daq diagnose DATA... --model MODEL [--report DIR]`: which effect of the catalog (docs/effects.md) the model
    lacks, named only when it beats every rival by a margin whose 5 % bound is above zero, and the share of the
    excess that `model add` + `compare` remove with it. Several recordings: one model, judged together."""

    if workers is not None and workers < 1:
        raise InputError("workers", "workers", f"must be a whole number >= 1, got {workers}")
    m = _model(model)
    return diagnosed(_session(data, m, rig, loss), m, workers=workers, report=report, progress=progress)


def diagnosed(s: Session | MultiSession, m: Model, *, workers: int | None = None, report: str | Path | None = None,
              progress: Progress = _quiet) -> Diagnosis:
    """diagnose on an opened session: what ``diagnose`` and `daq diagnose` both run."""
    t0 = time.perf_counter()
    d = diagnose_session(s, m, progress=progress, workers=workers)
    res = diagnosis_json(d, s)
    res["seconds"] = time.perf_counter() - t0
    one = len(getattr(s, "parts", ())) <= 1  # the figure is drawn for one recording
    if report is not None:
        rep = Path(report)
        rep.mkdir(parents=True, exist_ok=True)
        if one:
            diagnose_figure(s, d, rep / "diagnose.png")
        else:
            progress("several recordings: diagnose.json only (the figure is drawn for one recording)")
        (rep / "diagnose.json").write_text(dumps_json(res))
        res["report"] = str(rep)
    draw = (lambda path: diagnose_figure(s, d, path)) if one else None
    return Diagnosis(res, draw, diagnosis_text(d, res))


def propose(data: Data, model: str | Path | Model, output: str | Path | None = None, *,
            rival: Sequence[str] = (), rig: str | None = None, budget_s: float | None = None,
            max_run_s: float | None = None, progress: Progress = _quiet) -> Proposal:
    """`daq propose DATA... --model MODEL -o NEXT.toml`: the drive programme of the rig's family under which the
    rivals the diagnosis leaves standing (or ``rival``: ``EFFECT[:FORM]`` each) differ most, in noise units on the
    windows a diagnosis would score. With ``output`` the ramp file, its figure (.png) and JSON (.json) are written
    as the command writes them; ``proposal.ramp`` holds the ramp's text either way."""
    out = Path(output) if output is not None else Path(tempfile.mkdtemp(prefix="daq-propose-")) / "next.toml"
    m = _model(model)
    given = rivals_given(m, rival, "rival")
    check_proposal(out, budget_s, "output", "budget_s")
    return proposed(_session(data, m, rig, "huber"), m, given, out, budget_s=budget_s, max_run_s=max_run_s,
                    write=output is not None, progress=progress)


def check_proposal(out: Path, budget_s: float | None, out_field: str, budget_field: str) -> None:
    """A proposal's output and budget, refused in one line before any work."""
    if out.suffix.lower() != ".toml":
        raise InputError(str(out), out_field, "must end in .toml (a ramp file the daemon runs)")
    if budget_s is not None and not budget_s > 0:
        raise InputError(budget_field, budget_field, f"{budget_s:g} s: must be > 0")


def rivals_given(m: Model, texts: Sequence[str], field: str) -> list[Candidate]:
    """The candidates named by ``texts`` (``EFFECT[:FORM]`` or a mechanics parameter, as diagnose names them); one
    InputError naming ``field`` for one the model cannot take."""
    known = {c.label: c for c in candidates_for(m)}
    given = []
    for text in texts:
        c = parse_candidate(text)
        if c.label not in known:
            raise InputError(field, field, f"{text!r} is not a candidate of this model (one of: "
                                           f"{', '.join(sorted(known))})")
        given.append(c)
    return given


def proposed(s: Session | MultiSession, m: Model, given: list[Candidate], out: Path, *, budget_s: float | None = None,
             max_run_s: float | None = None, write: bool = True, progress: Progress = _quiet) -> Proposal:
    """propose on an opened session: what ``propose`` and `daq propose` both run. ``write``: the ramp file (always
    written to ``out``), its figure and JSON beside it."""
    sources = [p.source for p in getattr(s, "parts", ())] or [s.source]
    if given:
        rs = design.rivals_for(s, m, given, progress)
        why = f"rivals given: {', '.join(c.label for c in given)}"
    else:
        progress("diagnosing first: the rivals are what the diagnosis leaves standing")
        rs, why = design.rivals_from(s, m, diagnose_session(s, m, progress=progress, deliver=False), progress)
    progress(why)
    if not rs:
        result = {"data": sources, "programme": None, "reason": why, "decides": None}
        if write:
            out.with_suffix(".json").write_text(_json.dumps(result, indent=1))
        return Proposal(result, text=f"no run to propose: {why}")
    v0 = design.drive_speed(s)
    max_run = max_run_s or min(MAX_RUN_S, max(MIN_RUN_S, 2.0 * float(s.m.t[-1] - s.m.t[0])))
    for r in rs:
        progress(f"{r.label}: {r.error(s):.4g} {s.m.units[s.primary]} on the record"
                 + (f" ({r.fixed} held at a generic strength: the record cannot tell it from nothing)" if r.fixed
                    else ""))
    prop = design.propose(s, rs, math.inf if budget_s is None else budget_s, max_run, v0, progress)
    best = prop.best.programme
    write_programme(best, out)
    result = design.as_json(s, prop)
    result["output"] = str(out)
    result["reason"] = why
    figure = out.with_suffix(".png")
    if write:
        proposal_figure(s, prop, figure)
        result["figure"] = str(figure)
        out.with_suffix(".json").write_text(_json.dumps(result, indent=1, default=float))
    worst = min(prop.best.pairs, key=lambda p: p.z)
    verdict = ("decides" if prop.best.decides else
               f"does not decide (z {prop.best.z:.2f} < 2.33): the best of {len(prop.scored)} scored")
    text = (f"next run: {best.name} ({best.duration_s:.1f} s, varies {', '.join(best.varies)}) -> {out}\n"
            f"  {verdict}; separation {prop.best.separation:.1f} noise units, worst pair {worst.truth} vs "
            f"{worst.rival}\n  {len(prop.scored)} of {prop.family_size} programmes scored in {prop.seconds:.1f} s"
            + (f"; figure {figure}" if write else ""))
    return Proposal(_json.loads(_json.dumps(result, default=float)), lambda path: proposal_figure(s, prop, path), text)
