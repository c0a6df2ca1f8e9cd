"""No driver knows whether its peer is simulated: drivers/ never imports the simulators."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def test_drivers_do_not_import_simulators():
    files = sorted((ROOT / "drivers").glob("*.py"))
    assert len(files) >= 7
    for f in files:
        bad = {m for m in _imports(f) if m.startswith(("sim_backends", "daq.sim"))}
        assert not bad, f"{f.name} imports {bad}"


def test_physics_does_not_import_io_or_instruments():
    for f in sorted((ROOT / "daq" / "physics").glob("*.py")):
        bad = {m for m in _imports(f) if m.split(".")[0] in ("serial", "can", "zmq", "h5py", "drivers")}
        assert not bad, f"{f.name} imports {bad}"
