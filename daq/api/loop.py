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
from daq.models import design
from daq.models.candidates import candidates_for, parse_candidate
from daq.models.compare import compare as compare_fitted
from daq.models.diagnose import diagnose as diagnose_session
from daq.models.figures import (
    compare_figure, cycles_figure, diagnose_figure, proposal_figure, ringing_figure, spectrogram_figure,
)
from daq.models.multi_session import MultiSession
from daq.models.programmes import write_programme
from daq.models.report import compare_text, diagnosis_json, diagnosis_text
from daq.models.session import Session
from daq.models.spec import Model, load_model, rig_config_for, save_model

from .results import Comparison, Diagnosis, Proposal

Progress = Callable[[str], None]
Data = str | Path | Recording | Sequence[str | Path]

# as the command line's `daq propose` (daq/cli/propose.py): the longest programme, twice the first record within these
MIN_RUN_S, MAX_RUN_S = 20.0, 60.0


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
            report: str | Path | None = None, progress: Progress = _quiet) -> Comparison:
    """`daq compare DATA --model MODEL [--report DIR]`: fit the model's free parameters (multiple shooting), score
    it on the held-out windows against the noise floor, and say where it fails. With ``report`` the command's
    folder is written (compare.png, spectrogram.png, cycles.png, ringing.png, compare.json, fitted.toml).
    The command also appends to its history file; this does not (``daq history`` reads that file)."""

    m = _model(model)
    s = _session(data, m, rig, loss, several_ok=False)
    progress(f"fitting {len(m.free_names())} free parameters")
    f = s.fit(m)
    progress("noise floor: the fitted model scored on its own simulated output with the measured noise")
    floor = s.noise_floor(f)
    progress("forward simulation and breakdowns")
    cmp = compare_fitted(s, f, floor)
    res = cmp.result
    if report is not None:
        rep = Path(report)
        rep.mkdir(parents=True, exist_ok=True)
        compare_figure(s, f, res, rep / "compare.png")
        spectrogram_figure(s, cmp.drawn, rep / "spectrogram.png")
        cycles_figure(s, res, cmp.drawn, rep / "cycles.png")
        ringing_figure(s, res, cmp.drawn, rep / "ringing.png")
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
    s = _session(data, m, rig, loss)
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
    if out.suffix.lower() != ".toml":
        raise InputError(str(out), "output", "must end in .toml (a ramp file the daemon runs)")
    if budget_s is not None and not budget_s > 0:
        raise InputError("budget_s", "budget_s", f"{budget_s:g} s: must be > 0")
    m = _model(model)
    known = {c.label: c for c in candidates_for(m)}
    given = []
    for text in rival:
        c = parse_candidate(text)
        if c.label not in known:
            raise InputError("rival", "rival", f"{text!r} is not a candidate of this model (one of: "
                                               f"{', '.join(sorted(known))})")
        given.append(c)
    data_list = [data] if isinstance(data, (str, Path, Recording)) else list(data)
    s = _session(data, m, rig, "huber")
    if given:
        rs = design.rivals_for(s, m, given, progress)
        why = f"rivals given: {', '.join(c.label for c in given)}"
    else:
        progress("diagnosing first: the rivals are what the diagnosis leaves standing")
        rs, why = design.rivals_from(s, m, diagnose_session(s, m, progress=progress, deliver=False), progress)
    progress(why)
    names = [str(d) if not isinstance(d, Recording) else s.source for d in data_list]
    if not rs:
        result = {"data": names, "programme": None, "reason": why, "decides": None}
        if output is not None:
            out.with_suffix(".json").write_text(_json.dumps(result, indent=1))
        return Proposal(result)
    v0 = design.drive_speed(s)
    max_run = max_run_s or min(MAX_RUN_S, max(MIN_RUN_S, 2.0 * float(s.m.t[-1] - s.m.t[0])))
    prop = design.propose(s, rs, math.inf if budget_s is None else budget_s, max_run, v0, progress)
    write_programme(prop.best.programme, out)
    result = design.as_json(s, prop)
    result["output"] = str(out)
    result["reason"] = why
    figure = out.with_suffix(".png")
    if output is not None:
        proposal_figure(s, prop, figure)
        result["figure"] = str(figure)
        out.with_suffix(".json").write_text(_json.dumps(result, indent=1, default=float))
    return Proposal(_json.loads(_json.dumps(result, default=float)), lambda path: proposal_figure(s, prop, path))
