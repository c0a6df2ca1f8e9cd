"""The layers of the code, bottom to top: a module imports only its own layer and the ones below.

No driver knows whether its peer is simulated (drivers/ never imports the simulators); files
(daq/io) know nothing of sockets (daq/streaming) or of the daemon; nothing below the command
line imports it. The table is the README's "What is here" in code.

Decision records: docs/decisions/0003-simulated-instruments-at-the-wire-level.md, docs/decisions/0012-layout-by-layer.md.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("daq", "drivers", "sim_backends")

# bottom to top; a unit is a package (daq.x for daq's subpackages and top-level modules)
LAYERS: list[set[str]] = [
    {"daq", "daq.errors"},
    {"daq.physics", "daq.ramps", "daq.signals"},
    {"daq.config"},
    {"daq.io", "drivers"},
    {"daq.sim", "daq.streaming"},
    {"daq.estimation", "daq.models", "sim_backends"},
    {"daq.daemon", "daq.web"},
    {"daq.analysis", "daq.bench", "daq.demo"},
    {"daq.cli"},
]
LEVEL = {unit: i for i, layer in enumerate(LAYERS) for unit in layer}


def _unit(module: str) -> str:
    parts = module.split(".")
    return parts[0] if parts[0] != "daq" or len(parts) == 1 else f"daq.{parts[1]}"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Every module a file imports (relative imports resolved), at any depth of the file."""
    tree = ast.parse(path.read_text())
    me = _module_name(path).split(".")
    pkg = me if path.name == "__init__.py" else me[:-1]
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - node.level + 1]
                names.add(".".join(base + ([node.module] if node.module else [])))
            elif node.module:
                names.add(node.module)
    return names


def _sources() -> list[Path]:
    return sorted(p for d in PACKAGES for p in (ROOT / d).rglob("*.py"))


def test_every_package_has_a_layer():
    units = {_unit(_module_name(p)) for p in _sources()}
    assert units <= set(LEVEL), f"add to LAYERS: {sorted(units - set(LEVEL))}"


def test_no_module_imports_a_layer_above_its_own():
    bad = []
    for path in _sources():
        mine = LEVEL[_unit(_module_name(path))]
        for name in _imports(path):
            if name.split(".")[0] not in PACKAGES:
                continue
            if LEVEL[_unit(name)] > mine:
                bad.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not bad, "\n".join(bad)


def test_io_is_below_streaming_and_the_daemon():
    for path in sorted((ROOT / "daq" / "io").glob("*.py")):
        bad = {m for m in _imports(path) if m.startswith(("daq.streaming", "daq.daemon", "daq.models", "zmq"))}
        assert not bad, f"{path.name} imports {bad}"


def test_drivers_do_not_import_simulators_or_the_daemon():
    files = sorted((ROOT / "drivers").glob("*.py"))
    assert len(files) >= 7
    for f in files:
        bad = {m for m in _imports(f) if m.startswith(("sim_backends", "daq.sim", "daq.daemon", "daq.streaming"))}
        assert not bad, f"{f.name} imports {bad}"


def test_nothing_below_the_command_line_imports_it():
    for path in _sources():
        if _unit(_module_name(path)) == "daq.cli":
            continue
        bad = {m for m in _imports(path) if m == "daq.cli" or m.startswith("daq.cli.")}
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"


def test_physics_does_not_import_io_or_instruments():
    for f in sorted((ROOT / "daq" / "physics").glob("*.py")):
        bad = {m for m in _imports(f) if m.split(".")[0] in ("serial", "can", "zmq", "h5py", "drivers")}
        assert not bad, f"{f.name} imports {bad}"


def test_at_most_eight_modules_directly_in_daq():
    mods = sorted(p.name for p in (ROOT / "daq").glob("*.py"))
    assert len(mods) <= 8, mods
