"""The layers of the code, bottom to top: a module imports only its own layer and the ones below.

No driver knows whether its peer is simulated (drivers/ never imports the simulators); files
(daq/io) know nothing of sockets (daq/streaming) or of the daemon; nothing below the command
line imports it. The table is the README's "What is here" in code.

Inside a layer, and inside a package, modules import one another in one direction too: no circle of imports
(an import inside a function counts; it is still a dependency, only a later one).

Decision records: docs/decisions/0003-simulated-instruments-at-the-wire-level.md, docs/decisions/0012-layout-by-layer.md,
docs/decisions/0037-no-circles-inside-a-package.md.
"""

from __future__ import annotations

import ast
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("daq", "drivers", "sim_backends")

# bottom to top; a unit is a package (daq.x for daq's subpackages and top-level modules)
LAYERS: list[set[str]] = [
    {"daq", "daq.background", "daq.errors", "daq.strict"},
    {"daq.physics", "daq.ramps", "daq.signals"},
    {"daq.config"},
    {"daq.io", "drivers"},
    {"daq.sim", "daq.streaming"},
    {"daq.estimation", "daq.models", "sim_backends"},
    {"daq.daemon", "daq.web"},
    {"daq.analysis", "daq.bench", "daq.demo", "daq.api"},
    {"daq.cli"},
]
LEVEL = {unit: i for i, layer in enumerate(LAYERS) for unit in layer}


def _unit(module: str) -> str:
    parts = module.split(".")
    return parts[0] if parts[0] != "daq" or len(parts) == 1 else f"daq.{parts[1]}"


def _module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, root: Path = ROOT) -> set[str]:
    """Every module a file imports (relative imports resolved), at any depth of the file."""
    tree = ast.parse(path.read_text())
    me = _module_name(path, root).split(".")
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


def _runtime_imports(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """The import statements of a file at any depth (in functions too), but not under ``if TYPE_CHECKING:``:
    those never run, they only name a type for the checker."""
    found: list[ast.Import | ast.ImportFrom] = []
    todo = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            found.append(node)
        elif isinstance(node, ast.If) and ast.unparse(node.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING"):
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))
    return found


def import_graph(package_dir: Path) -> dict[str, set[str]]:
    """module -> the modules of the same package it imports, from the source (ast): imports at any depth of the
    file, relative ones resolved, those under ``if TYPE_CHECKING:`` left out. ``from p import m`` is an edge to the
    module ``p.m`` when there is one, else to ``p``; ``import a.b.c`` is an edge to ``a.b.c`` only: the implicit
    import of the package ``a.b`` is not an edge (else every ``__init__`` that imports its own modules would close
    a circle)."""
    root = package_dir.parent
    files = {_module_name(p, root): p for p in sorted(package_dir.rglob("*.py"))}

    def known(name: str) -> str:  # the longest prefix that is one of our modules ("" if none)
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name

    graph: dict[str, set[str]] = {}
    for mod, path in files.items():
        pkg = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
        edges: set[str] = set()
        for node in _runtime_imports(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                edges.update(known(a.name) for a in node.names)
                continue
            base = node.module or ""
            if node.level:
                base = ".".join(pkg[: len(pkg) - node.level + 1] + ([node.module] if node.module else []))
            edges.update(f"{base}.{a.name}" if f"{base}.{a.name}" in files else known(base) for a in node.names)
        graph[mod] = edges - {"", mod}
    return graph


def import_circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted, sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


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


def test_no_circle_of_imports_inside_a_package():
    """A circle (a -> b -> ... -> a) makes import order matter and the modules one lump: none may cut the others
    loose. daq/io had one of five modules (interchange -> frames -> importer -> runfile/plausible -> interchange)
    until the Recording and its notebook views moved to daq/io/recording.py (decision 37)."""
    circles = {pkg: import_circles(import_graph(ROOT / pkg)) for pkg in PACKAGES}
    assert not any(circles.values()), "\n".join(f"{pkg}: {' <-> '.join(c)}" for pkg, cs in circles.items() for c in cs)


# daq/models' parts, bottom to top (its __init__ says what each holds): a module imports only its own part and the
# ones below. The model files are the bottom; figures draw what any part computes.
MODEL_PARTS: list[set[str]] = [
    {"daq.models", "daq.models.spec", "daq.models.candidates", "daq.models.user_effects"},
    {"daq.models.fit"},
    {"daq.models.diagnosis"},
    {"daq.models.design"},
    {"daq.models.archive"},
    {"daq.models.figures"},
]
MODEL_PART = {part: i for i, layer in enumerate(MODEL_PARTS) for part in layer}


def _model_part(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:3])


def test_the_models_parts_import_only_downwards():
    """fit below diagnosis below design below archive: a fit knows nothing of what judges it (issue 57)."""
    graph = {f"daq.{m}": {f"daq.{d}" for d in deps} for m, deps in import_graph(ROOT / "daq" / "models").items()}
    unknown = {_model_part(m) for m in graph} - set(MODEL_PART)
    assert not unknown, f"add to MODEL_PARTS: {sorted(unknown)}"
    bad = [f"{mod} imports {dep}" for mod, deps in graph.items() for dep in deps
           if MODEL_PART[_model_part(dep)] > MODEL_PART[_model_part(mod)]]
    assert not bad, "\n".join(bad)


def test_no_module_of_the_models_is_over_600_lines():
    """A module a newcomer reads in one sitting (issue 57): daq/models held 29 modules side by side, three of them
    650-830 lines, before its parts were packages."""
    long = {str(p.relative_to(ROOT)): n for p in (ROOT / "daq" / "models").rglob("*.py")
            if (n := len(p.read_text().splitlines())) > 600}
    assert not long, long


def test_the_circle_detector_finds_a_circle(tmp_path: Path):
    files = {
        "__init__.py": "from . import a\n",  # the package imports its module: not a circle (a -> pkg is implicit)
        "a.py": "from pkg.b import x\n",
        "b.py": "def x():\n    from .c import y\n    return y\n",  # inside a function: counts
        "c.py": "import pkg.a\n\ny = 1\n",  # closes a -> b -> c -> a
        "d.py": "from pkg import e\nfrom pkg.sub import m\n",
        "e.py": "from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from .d import Z\n",  # never runs
        "sub/__init__.py": "",
        "sub/m.py": "from .. import d\n",  # closes d -> sub.m -> d
    }
    for name, text in files.items():
        (tmp_path / "pkg" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "pkg" / name).write_text(text)
    graph = import_graph(tmp_path / "pkg")
    assert graph["pkg"] == {"pkg.a"} and graph["pkg.e"] == set()
    assert import_circles(graph) == [["pkg.a", "pkg.b", "pkg.c"], ["pkg.d", "pkg.sub.m"]]


# packages whose own __init__ imports these on purpose (none since the numba cache directory is set through the
# environment, 2026-11-28: daq.physics imported numba to set it)
HEAVY = ("numba", "scipy", "numpy", "h5py", "zmq", "pandas", "matplotlib", "pydantic", "starlette", "uvicorn")
HEAVY_ON_PURPOSE: dict[str, set[str]] = {}
# the entry points of the processes that simulate nothing (a daemon, with the simulated bench it starts in another
# process, a recorder, the web page's process) and what every command reads first (a config, a model file)
NO_COMPILER = ("daq.config", "daq.daemon.service", "daq.daemon.sim_bench", "daq.models.spec", "daq.streaming.recorder",
               "daq.web.process")


def _packages() -> list[str]:
    return sorted(_module_name(p) for d in PACKAGES for p in (ROOT / d).rglob("__init__.py"))


# The one exception: the top package names the loop's three steps for a notebook's ``import daq`` (daq/api), looked up
# by name when first used, so ``import daq`` and every layer below still import nothing above them.
NOTEBOOK_LOOP = {("daq", "compare"), ("daq", "diagnose"), ("daq", "propose")}


def test_every_package_says_what_it_exports():
    """Each package's ``__all__`` (issue 30) names objects of its own tree, no higher in the layers than the package
    (``daq`` is the bottom layer: it may not export ``daq.config``'s names), none under a submodule's name unless
    it is that submodule: importing the submodule would rebind the name to it."""
    import importlib
    import inspect

    bad = []
    for name in _packages():
        pkg = importlib.import_module(name)
        exported = getattr(pkg, "__all__", None)
        if not exported:
            bad.append(f"{name}: no __all__")
            continue
        submodules = {p.stem for p in Path(pkg.__file__).parent.glob("*.py")} | {
            p.parent.name for p in Path(pkg.__file__).parent.glob("*/__init__.py")
        }
        for attr in exported:
            value = getattr(pkg, attr)  # an AttributeError or ImportError here is a broken entry
            assert attr in dir(pkg), f"{name}.{attr} missing from dir()"
            if inspect.ismodule(value):
                where = value.__name__
            elif inspect.isclass(value) or inspect.isfunction(value):
                where = value.__module__
            else:
                where = None  # a constant: no __module__ of its own
            if where is not None and where != name and not where.startswith(f"{name}."):
                bad.append(f"{name}.{attr} is defined in {where}")
            elif where is not None and LEVEL[_unit(where)] > LEVEL[_unit(name)] and (name, attr) not in NOTEBOOK_LOOP:
                bad.append(f"{name}.{attr} comes from {where}, a layer above {name}")
            if attr in submodules and not inspect.ismodule(value):
                bad.append(f"{name}.{attr} is also a submodule's name")
    assert not bad, "\n".join(bad)


def _loaded_by(name: str) -> set[str]:
    """The modules a fresh interpreter holds after ``import name`` (from the repository)."""
    import json
    import subprocess
    import sys

    code = f"import json, sys; import {name}; print(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    return set(json.loads(out.stdout))


def test_importing_a_package_imports_none_of_its_exports():
    """``import daq.models`` alone loads the package's ``__init__`` and those above it, nothing more of ours: its
    exports are imported when first used (PEP 562), so light processes (the web page's, ``daq --help``) still import
    no numba, scipy or numpy. Measured before issue 30: only daq.physics imported any of HEAVY (numba, by design)."""
    bad = []
    for name in _packages():
        loaded = _loaded_by(name)
        ours = {m for m in loaded if m.split(".")[0] in PACKAGES}
        parts = name.split(".")
        expected = {".".join(parts[: i + 1]) for i in range(len(parts))} | {"daq"}
        if ours != expected:
            bad.append(f"import {name} also imports {sorted(ours - expected)}")
        heavy = {m for m in HEAVY if m in loaded} - HEAVY_ON_PURPOSE.get(name, set())
        if heavy:
            bad.append(f"import {name} imports {sorted(heavy)}")
    assert not bad, "\n".join(bad)


def test_the_processes_that_simulate_nothing_import_no_compiler():
    """A config names its effects, so each process that reads one imports the catalog; those that never simulate
    must not pay for numba or scipy on the way (0.4-0.5 s of CPU each on a 2-core machine, measured with ``python -X
    importtime``: the catalog sat beside the compiled terms and daq.physics imported numba to set its cache). Every
    daemon, recorder and web process of the suite paid it. And a process that compiles still finds this tree's
    cache: the directory set before numba was imported."""
    import subprocess
    import sys

    import daq.physics

    for name in NO_COMPILER:
        heavy = {"numba", "scipy", "matplotlib"} & _loaded_by(name)
        assert not heavy, f"import {name} imports {sorted(heavy)}"
    code = "import daq.physics.brake2dof, numba; print(numba.config.CACHE_DIR)"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True, env=env)
    assert out.stdout.strip() == str(daq.physics._cache_dir())
