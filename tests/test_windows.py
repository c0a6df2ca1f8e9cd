"""Windows over a hole in the data (daq/models/fit/windows.py, over_filled_spans): the loader fills a stream's hole with
a straight line (daq/io/loading.py, uniform); a window whose drive bends inside such a line, or whose predicted
signal is one, is flagged (neither fitted nor deciding), and a hole where the line is right is left alone."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np

from daq.io.loading import load_data
from daq.models.fit.session import Session
from daq.models.fit.windows import DRIVE_SMOOTH_S
from daq.models.spec import seed_model

LOADED_DEMO = Path(__file__).resolve().parent / "data" / "loaded-demo"


def _flagged_times(session: Session) -> list[tuple[float, float]]:
    w = session.win
    return [(float(session.m.t[i]), float(session.m.t[i + w.length - 1])) for i in w.starts[w.transient]]


def _cut(path: Path, stream: str, t_from: float, t_to: float) -> None:
    """Remove a stream's samples in [t_from, t_to] (host times from the file's start), as a stalled poll does."""
    with h5py.File(path, "r+") as f:
        g = f["streams"][stream]
        t = g["t"][()]
        keep = ~((t - f["streams/laser_serial/t"][0] >= t_from) & (t - f["streams/laser_serial/t"][0] <= t_to))
        for name in list(g):
            data = g[name][()][keep]
            del g[name]
            g[name] = data


def test_a_hole_in_the_run_up_flags_its_windows_and_a_hole_at_constant_speed_does_not(tmp_path):
    """The loaded demo's second run: the motor poll stalled 0.3 s while the belt ran up to speed (t ~ 1.7-2.0 s).
    Cut a second hole of the same length where the belt runs at a steady speed: that one is not flagged."""
    path = tmp_path / "run-2.h5"
    shutil.copy(LOADED_DEMO / "run-2.h5", path)
    _cut(path, "motor", 8.0, 8.3)
    rec = load_data(path, "brake-2dof")
    spans = rec.meta["filled_spans"]
    assert set(spans) == {"vb", "vb_set"}
    (a1, b1), (a2, b2) = spans["vb"]
    assert 1.6 < a1 < b1 < 2.0 and b1 - a1 > 0.25  # the poll that timed out
    assert 7.9 < a2 < b2 < 8.4 and b2 - a2 > 0.25  # the cut
    session = Session.open(path, seed_model("brake-2dof"))
    flagged = _flagged_times(session)
    pad = DRIVE_SMOOTH_S
    assert any(lo <= b1 + pad and hi >= a1 - pad for lo, hi in flagged)  # the run-up's hole
    assert not any(lo <= b2 + pad and hi >= a2 - pad for lo, hi in flagged)  # the steady speed's hole
    # flagged windows are neither fitted nor held out for scoring
    scored = set(session.win.scored().tolist())
    assert not scored & set(np.flatnonzero(session.win.transient).tolist())


def test_a_hole_in_a_predicted_signal_flags_its_windows_wherever_it_is(tmp_path):
    """A laser hole at the same steady stretch: the model's own output is a straight line there, never data."""
    path = tmp_path / "run-2.h5"
    shutil.copy(LOADED_DEMO / "run-2.h5", path)
    _cut(path, "laser_serial", 8.0, 8.1)
    session = Session.open(path, seed_model("brake-2dof"))
    (a, b), = [s for s in session.rec.meta["filled_spans"]["x1"] if s[0] > 7]
    flagged = _flagged_times(session)
    assert any(lo <= b and hi >= a for lo, hi in flagged)
    assert session.rec.meta["filled_spans"]["x1"] == session.rec.meta["filled_spans"]["phi"]
