"""docs/tutorial.md runs as written, and shows what it runs to: so it cannot drift from the code.

The test reads the page's fenced blocks in order and runs every ``sh`` and ``python`` block, line by line as a reader
types them, in a folder laid out like a clone (``docs`` and ``tests`` beside the tutorial's folder). What it does
not run, and why:

- step 0's install lines (``make env``, ``source``, ``daq warm``): the suite's own environment is that;
- a block whose line above is ``<!-- not run by tests/test_tutorial.py: WHY -->`` (the page says why: the proposed
  run's recording, which repeats step 1's commands, and three steps that each cost more CPU than the rest of the
  page; tests/test_api.py and tests/test_diagnose_multi.py cover those).

Two substitutions keep it beside the other tests: ``daq daemon`` gets ports the OS picks (``--control``/``--bus``
port 0) and its own device folder, and every ``daq ctl`` the endpoint it reports; ``kill %1`` is SIGTERM to it.

Then each figure the page shows is checked against what the run printed or wrote, within the tolerance the page
states beside it; and the page's own figures are held to the same tolerances, so a page edited to other numbers
fails too. CPU: about 70 s (a recording of ~10 s through the daemon, three compares, a diagnosis, a proposal over
24 programmes, an import of a lab file).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from helpers import end_bench, read_ready, stop_daemon

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "tutorial.md"
NOT_RUN = "<!-- not run by tests/test_tutorial.py"
SETUP = ("make env", "source .venv/bin/activate", "daq warm")  # step 0: the suite's environment is that
READY_S = 180.0  # a loaded CI machine may load the kernels' cache slowly


@dataclass
class Block:
    lang: str
    text: str
    run: bool
    before: str = ""  # the paragraph above the block (a toml block's file: "Edit `FILE` so that ...")


def blocks(page: str) -> list[Block]:
    """The page's fenced blocks in order; ``run`` is False under a NOT_RUN comment."""
    found, lines = [], page.splitlines()
    i = 0
    while i < len(lines):
        m = re.match(r"^```(\w*)\s*$", lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while not lines[j].startswith("```"):
            j += 1
        run = not (i > 0 and lines[i - 1].startswith(NOT_RUN))
        found.append(Block(m.group(1), "\n".join(lines[i + 1:j]), run, "\n".join(lines[max(0, i - 3):i])))
        i = j + 1
    return found


def commands(text: str) -> list[str]:
    """A shell block's commands: one a line, comments and blank lines left out."""
    out = []
    for line in text.splitlines():
        line = re.sub(r"(^|\s{2,})#.*$", "", line).strip()
        if line:
            out.append(line)
    return out


@dataclass
class Reader:
    """Types the page's commands: a working folder, a daemon in the background, what each command printed."""

    home: Path
    cwd: Path
    printed: dict[str, str] = field(default_factory=dict)
    daemon: subprocess.Popen | None = None
    endpoint: str = ""
    benches: list[tuple[int, str]] = field(default_factory=list)

    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"  # `daq` as after `source`
        return env

    def sh(self, line: str) -> None:
        if line in SETUP:
            return
        if " && " in line:
            for part in line.split(" && "):
                self.sh(part.strip())
            return
        words = shlex.split(line)
        if words[0] == "cd":
            self.cwd = (self.cwd / words[1]).resolve()
            return
        if words[:2] == ["daq", "daemon"] and words[-1] == "&":
            return self.start_daemon(words[:-1])
        if line == "kill %1":
            return self.stop_daemon()
        if words[:2] == ["daq", "ctl"]:
            assert self.daemon is not None, f"{line}: no daemon running"
            line = line.replace("daq ctl", f"daq ctl --endpoint {self.endpoint}", 1)
        done = subprocess.run(line, shell=True, cwd=self.cwd, env=self.env(), capture_output=True, text=True,
                              timeout=600)
        self.printed[line] = done.stdout + done.stderr
        assert done.returncode == 0, f"`{line}` exited {done.returncode}:\n{done.stdout}\n{done.stderr}"

    def python(self, code: str) -> None:
        script = self.cwd / "tutorial_block.py"
        script.write_text(code)
        done = subprocess.run([sys.executable, str(script)], cwd=self.cwd, env=self.env(), capture_output=True,
                              text=True, timeout=600)
        self.printed[code] = done.stdout + done.stderr
        assert done.returncode == 0, f"python block failed:\n{done.stdout}\n{done.stderr}"

    def edit(self, block: Block) -> None:
        """A reader's edit of a file: each ``key = value`` of the block replaces that key's first line in the
        section a ``# [section]`` comment above it names (the rest of the line, its comment, stays)."""
        m = re.search(r"Edit `([^`]+)`", block.before)
        assert m, "a toml block must follow 'Edit `FILE` ...'"
        path = self.cwd / m.group(1)
        text, section = path.read_text(), ""
        for raw in block.text.splitlines():
            head = re.match(r"#\s*\[([^\]]+)\]", raw.strip())
            if head:
                section = head.group(1)
                continue
            line = commands(raw)
            if not line:
                continue
            key, value = (part.strip() for part in line[0].split("=", 1))
            start = text.index(f"\n[{section}]")
            found = re.compile(rf"^{re.escape(key)} = [^#\n]*?(?=\s*(#|$))", re.MULTILINE).search(text, start)
            assert found, f"{path.name}: no {key} in [{section}]"
            text = text[:found.start()] + f"{key} = {value}" + text[found.end():]
        path.write_text(text)

    def start_daemon(self, words: list[str]) -> None:
        assert self.daemon is None, "a second daemon while the first runs"
        args = [*words[1:], "--control", "tcp://127.0.0.1:0", "--bus", "tcp://127.0.0.1:0",
                "--workdir", str(self.home / "devices")]
        self.daemon = subprocess.Popen([sys.executable, "-m", "daq.cli", *args], cwd=self.cwd, env=self.env(),
                                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        err: list[str] = []
        threading.Thread(target=lambda: err.extend(self.daemon.stderr), daemon=True).start()
        fields = read_ready(self.daemon, READY_S, hint=f" (stderr: {''.join(err)[-2000:]})")
        threading.Thread(target=lambda: list(self.daemon.stdout), daemon=True).start()
        self.endpoint = fields["control"]
        self.benches.append((int(fields["sim_bench_pid"]), fields["sim_control"]))

    def stop_daemon(self) -> None:
        assert self.daemon is not None, "kill %1 with no daemon running"
        stop_daemon(self.daemon)
        self.daemon = None

    def close(self) -> None:
        if self.daemon is not None:
            self.stop_daemon()
        for pid, control in self.benches:  # a simulated bench outlives its daemon by design
            end_bench(pid, control, ask_s=2.0, wait_s=10.0)

    def output(self, fragment: str) -> str:
        """What the command (or python block) containing ``fragment`` printed."""
        hits = [out for cmd, out in self.printed.items() if fragment in cmd]
        assert len(hits) == 1, f"{len(hits)} commands contain {fragment!r}"
        return hits[0]


@pytest.fixture(scope="module")
def walked(tmp_path_factory):
    """The page's commands run in a clone's layout; the reader with everything printed and written."""
    home = tmp_path_factory.mktemp("clone")
    for name in ("docs", "tests"):
        (home / name).symlink_to(ROOT / name)
    reader = Reader(home, home)
    try:
        for b in blocks(PAGE.read_text()):
            if not b.run:
                continue
            if b.lang == "sh":
                for line in commands(b.text):
                    reader.sh(line)
            elif b.lang == "python":
                reader.python(b.text)
            elif b.lang == "toml":
                reader.edit(b)
    finally:
        reader.close()
    return reader


def json_of(reader: Reader, path: str) -> dict:
    return json.loads((reader.cwd / path).read_text())


PAGE_TEXT = PAGE.read_text()


def shown(pattern: str) -> tuple[float, ...]:
    """The numbers the page shows where ``pattern`` (a regex with groups) matches its text."""
    m = re.search(pattern, PAGE_TEXT)
    assert m, f"the tutorial no longer shows {pattern!r}"
    return tuple(float(g) for g in m.groups())


# --------------------------------------------------------------------------------------------- the page's figures


def test_the_page_is_what_the_test_runs():
    runs = [b for b in blocks(PAGE_TEXT) if b.run]
    assert {b.lang for b in runs} <= {"sh", "python", "text", "toml"}
    skipped = [b for b in blocks(PAGE_TEXT) if not b.run]
    assert len(skipped) == 4, "a block left out of the test must say why, and stay few"


# each check applies to the figure the page shows and to the one the run gives: (name, within its tolerance)
def baseline_compare_ok(error: float, floor: float) -> bool:
    return 5e-5 <= error <= 3e-4 and 4e-6 <= floor <= 7e-6  # stated in step 2


def at_the_floor(error: float, floor: float) -> bool:
    return error <= 1.3 * floor  # the page's own figures (steps 4 and 8), from a quiet machine


def most_excess_gone(error: float, floor: float, before: dict) -> bool:
    """Step 4's check, stated there: at least 70 % of step 2's excess gone (a busy machine's record keeps timing
    jitter its floor does not hold: 3-5x the floor seen, against 1.3x on a quiet one)."""
    return error - floor <= 0.3 * (before["error"] - before["noise_floor"])


@pytest.mark.slow
def test_step_2_the_baseline_model_is_far_from_its_floor(walked):
    assert baseline_compare_ok(*shown(r"error ([\d.e-]+) m on held-out windows \(noise floor ([\d.e-]+); all windows "
                                      r"0\.0001172"))
    res = json_of(walked, "cmp/compare.json")
    assert baseline_compare_ok(res["error"], res["noise_floor"]), (res["error"], res["noise_floor"])
    assert (walked.cwd / "cmp" / "compare.png").stat().st_size > 50_000


@pytest.mark.slow
def test_step_3_diagnose_names_the_hidden_effect(walked):
    assert "The model misses 'accel-sign (relative)'" in PAGE_TEXT and shown(r"It removes (\d+)% of the excess")[0] >= 80
    res = json_of(walked, "diag/diagnose.json")
    best = max((c for c in res["candidates"] if c["reduction"] is not None), key=lambda c: c["reduction"])
    assert best["effect"] == "accel-sign" and best["reduction"] >= 0.8, res["summary"]
    if res["missing_effect_found"]:  # named on a quiet machine; a busy one's record may be too short to (the page)
        assert res["named"][0].startswith("accel-sign (") and res["final_reduction"] >= 0.8, res["summary"]


@pytest.mark.slow
def test_step_4_the_model_with_it_reaches_the_floor(walked):
    assert at_the_floor(*shown(r"error ([\d.e-]+) m on held-out windows \(noise floor ([\d.e-]+); all windows 5\.5"))
    res = json_of(walked, "cmp2/compare.json")
    before = json_of(walked, "cmp/compare.json")
    assert "accel-sign" in res["model"] and most_excess_gone(res["error"], res["noise_floor"], before), res["error"]
    assert (walked.cwd / "history.png").stat().st_size > 10_000


@pytest.mark.slow
def test_step_5_the_proposal_is_scored_and_written(walked):
    """Whether the best 10 s run decides depends on the record (z 0.6-3.4 seen): the page says so, and the test
    holds what does not: the whole family scored, the best written as a ramp file, its z against the rival."""
    assert "  decides; separation" in PAGE_TEXT and "does not decide" in PAGE_TEXT
    res = json_of(walked, "next.json")
    assert len(res["scored"]) == res["family_size"] == 24, res["family_size"]
    assert {p["truth"] for p in res["pairs"]} == {"nothing more", "stick-time (log)"}
    assert res["decides"] == (res["z"] >= 2.33) and res["separation"] > 0
    assert (walked.cwd / "next.toml").read_text().splitlines()[0] == f"# {res['programme']}: varies " + \
        ", ".join(res["varies"]) + f"; {res['duration_s']:.1f} s"
    assert (walked.cwd / "next.png").stat().st_size > 20_000


@pytest.mark.slow
def test_step_7_the_record_is_archived(walked):
    listed = walked.output("daq archive list")
    assert "brake-2dof" in listed and "runs/first.h5" in listed, listed
    assert "recordings in" in walked.output("daq archive scan runs")


@pytest.mark.slow
def test_step_8_python_gives_the_commands_numbers(walked):
    assert at_the_floor(*shown(r"\nerror ([\d.e-]+) m \(noise floor ([\d.e-]+)\), brake-2dof"))
    out = walked.output("daq.compare(rec")
    m = re.search(r"^error ([\d.e-]+) m \(noise floor ([\d.e-]+)\), brake-2dof", out, re.MULTILINE)
    assert m and most_excess_gone(float(m.group(1)), float(m.group(2)), json_of(walked, "cmp/compare.json")), out
    assert (walked.cwd / "compare.png").stat().st_size > 50_000


@pytest.mark.slow
def test_step_9_the_lab_file_through_import_map(walked):
    spikes, = shown(r"repaired \(single samples and bursts of up to 3; the cubic through the samples beside them\): "
                    r"x1 (\d+)")
    error, floor = shown(r"error ([\d.e-]+) m on held-out windows \(noise floor ([\d.e-]+); all windows 1\.03")
    line, = shown(r"record ([\d.]+) Hz, model")
    res = json_of(walked, "cmp-slider/compare.json")
    assert res["outliers"]["x1"] == spikes == 36
    assert res["error"] == pytest.approx(error, rel=0.05) and res["noise_floor"] == pytest.approx(floor, rel=0.05)
    assert res["motion"]["line_Hz_record"] == pytest.approx(line, abs=0.5)


def test_step_9_the_rig_file_edit_is_the_one_shown():
    """The lines the page tells a reader to change are keys `daq rig init belt-ndof` writes, in its sections."""
    from daq.config import rig_path

    block = next(b.text for b in blocks(PAGE_TEXT) if b.lang == "toml")
    template = rig_path("belt-ndof").read_text()
    for line in commands(block):
        key = line.split("=")[0].strip()
        assert re.search(rf"^{re.escape(key)} = ", template, re.MULTILINE), key
