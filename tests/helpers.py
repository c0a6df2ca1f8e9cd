"""What several tests share: bad-input assertions (one line naming file and field), ramp files, a lab's slider."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import scipy.io

from daq.cli.main import main as daq
from daq.config import rig_path
from daq.errors import InputError

M, K, G = 0.05, 200.0, 9.81  # the spring-slider of docs/examples/spring-slider.md: mass, spring, gravity


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def expect_error(exc: InputError, source: str, field: str, *fragments: str) -> None:
    """The error is one line 'SOURCE: FIELD: message' with the given source and field."""
    text = str(exc)
    assert "\n" not in text
    assert (exc.source, exc.field) == (source, field), text
    assert text == f"{source}: {field}: {exc.message}"
    assert exc.message
    for frag in fragments:
        assert frag in exc.message, (frag, text)


def ramp_text(hold_s: float, stop: bool = True) -> str:
    """A ramp file for the daemon tests: 0.5 s up to 0.15 m/s, a hold, and (``stop``) 0.5 s down to rest."""
    text = ('start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 0.5\nto_m_per_s = 0.15\n'
            f'[[segment]]\nkind = "hold"\nduration_s = {hold_s}\n')
    return text + ('[[segment]]\nkind = "linear"\nduration_s = 0.5\nto_m_per_s = 0.0\n' if stop else "")


def slider_rig(tmp_path: Path) -> Path:
    """The spring-slider of docs/examples/spring-slider.md as a user's belt-ndof rig file."""
    text = rig_path("belt-ndof").read_text()
    text = text.replace("mass_kg = 0.5", f"mass_kg = {M}").replace("normal_force_N = 4.905", f"normal_force_N = {M * G}")
    assert 'driven = "belt"' in text
    text = text.replace('driven = "belt"', 'driven = "spring"', 1)  # the driver pulls the spring; the track is fixed
    path = tmp_path / "slider-rig.toml"
    path.write_text(text)
    return path


def slider_compare(tmp_path: Path, t: np.ndarray, f_over_mg: np.ndarray, drive: str) -> dict:
    """A lab's slider record through the user's path: a .mat of t and F/mg (500 Hz; noise 5e-4, steps 1e-3 of
    F/mg) -> the rig file edited -> `import --map` (x1 from F/mg, vb = ``drive``, arithmetic of t) -> `model init`
    -> `compare`; returns compare's JSON."""
    scipy.io.savemat(tmp_path / "slider.mat", {"t": t, "F_over_mg": f_over_mg})
    rig = slider_rig(tmp_path)
    rig.write_text(rig.read_text().replace("noise_std = 2e-5\nlsb = 1e-5", f"noise_std = {5e-4 * M * G / K:.3g}\n"
                                           f"lsb = {1e-3 * M * G / K:.3g}", 1).replace("rate_Hz = 250.0", "rate_Hz = 500.0"))
    h5, model = tmp_path / "slider.h5", tmp_path / "model.toml"
    assert daq(["import", str(tmp_path / "slider.mat"), "--rig", str(rig), "--map", f"x1=F_over_mg*{M}*{G}/{K}",
                "--map", f"vb={drive}", "-o", str(h5)]) == 0
    assert daq(["model", "init", str(rig), "-o", str(model)]) == 0
    assert daq(["compare", str(h5), "--model", str(model), "--no-history", "--report", str(tmp_path / "cmp")]) == 0
    return json.loads((tmp_path / "cmp" / "compare.json").read_text())
