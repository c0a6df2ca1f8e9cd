"""The documentation against the code and against its own rules.

- docs/effects.md is the catalog as `python -m daq.cli.docs effects` writes it, and `daq model add --help` lists
  every effect: a page written beside the catalog drifts the first time an effect is added.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from daq.cli.docs import effects_markdown
from daq.physics.catalog import CATALOG

ROOT = Path(__file__).resolve().parent.parent


# --------------------------------------------------------------------------------------------- the catalog's pages


def test_effects_page_is_the_catalog():
    written = (ROOT / "docs" / "effects.md").read_text()
    assert written == effects_markdown(), "docs/effects.md is out of date: python -m daq.cli.docs effects -o docs/effects.md"


def test_effects_page_names_every_effect_and_form():
    text = (ROOT / "docs" / "effects.md").read_text()
    for name, spec in CATALOG.items():
        assert f"\n## {name}\n" in text, name
        for form in spec.form_names():
            if form:
                assert f"### {name} (`{form}`)" in text, (name, form)


def test_model_add_help_lists_the_effects():
    out = subprocess.run([sys.executable, "-m", "daq.cli.main", "model", "add", "--help"], capture_output=True,
                         text=True, check=True).stdout
    for name, spec in CATALOG.items():
        line = next((ln for ln in out.splitlines() if ln.strip().startswith(name + " ")), None)
        assert line is not None, f"{name} missing from `daq model add --help`"
        for form in spec.form_names():
            assert form in line, (name, form)
    assert "mechanics.NAME" in out and "docs/effects.md" in out


def test_daq_help_still_loads_no_numpy():
    """`daq --help` imports every cli module: the catalog listing must wait until `model add --help` asks."""
    code = "import sys, daq.cli.main; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
