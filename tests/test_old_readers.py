"""Our recordings open in an old HDF5 reader: Octave 7.3 and h5dump, both on HDF5 1.10.8 (issue 16, decision 18).

Debian 12's ``octave`` and ``hdf5-tools`` link the system HDF5 1.10.8, the library of many MATLAB releases;
h5py bundles HDF5 2.0. Octave's ``load`` reads numeric and fixed-length string datasets and groups, but skips
every compound dataset other than a complex number with a warning (libinterp/corefcn/ls-hdf5.cc): the /events
table itself is read by h5dump 1.10.8, and Octave reads the events from /event_columns, the same table as
one plain dataset per field, written when a file is finished (closed or recovered). Before the fix
(libver="latest") HDF5 1.10.8 could not decode /events at all and Octave's load of the whole file failed.

CI installs both tools (.ci/run); without them these tests fail, they do not skip.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from daq.io import h5recover
from daq.io.interchange import Recording, write_h5
from daq.io.runfile import RunWriter, recover_run
from daq.io.stream_format import StreamMeta, make_block

ROOT = Path(__file__).resolve().parent.parent
TIMEOUT = 30.0
FORCE = StreamMeta(stream="force", channels=("fn", "ft"), units=("N", "N"), source="test", rate_hz=1000.0)
TEMP = StreamMeta(stream="temp", channels=("pad",), units=("degC",), source="test", rate_hz=10.0)

# prints "event <kind> <source>" for every row of /event_columns (fixed-length strings: one char row each)
OCTAVE_EVENTS = (
    "e = s.event_columns; for i = 1:rows(e.kind), "
    "printf('event %s %s\\n', deblank(e.kind(i, :)), deblank(e.source(i, :))); end; "
)
# prints "<stream> <dataset> <numel>" for every dataset of every stream, whatever the streams are called
OCTAVE_STREAMS = (
    "s = load(getenv('DAQ_H5')); "
    "printf('top %s\\n', strjoin(sort(fieldnames(s))', ',')); "
    "for a = sort(fieldnames(s.streams))', g = s.streams.(a{1}); "
    "for b = sort(fieldnames(g))', printf('%s %s %d\\n', a{1}, b{1}, numel(g.(b{1}))); end; end; "
    + OCTAVE_EVENTS
)
OCTAVE_SIMPLE = (
    "s = load(getenv('DAQ_H5')); "
    "printf('top %s\\n', strjoin(sort(fieldnames(s))', ',')); "
    "printf('. t %d\\n', numel(s.t)); "
    "for b = sort(fieldnames(s.channels))', printf('channels %s %d\\n', b{1}, numel(s.channels.(b{1}))); end; "
    + OCTAVE_EVENTS
)
SKIPPED_EVENTS = "warning: load: can't read 'events' (unknown datatype)"


def _tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        pytest.fail(f"{name} not found: tests/test_old_readers.py opens recordings in Octave and h5dump linked to "
                    "HDF5 1.10 and needs both (apt-get install octave hdf5-tools, as .ci/run does)", pytrace=False)
    return path


def octave(script: str, h5: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, DAQ_H5=str(h5 or ""))
    return subprocess.run([_tool("octave"), "--no-gui", "--norc", "--no-history", "-q", "--eval", script],
                          capture_output=True, text=True, timeout=TIMEOUT, env=env, cwd=ROOT)


def octave_load(h5: Path, script: str = OCTAVE_STREAMS) -> dict[tuple[str, str], int]:
    """What Octave's load(FILE) found: {(group, dataset): elements}; fails on any HDF5 error or other warning."""
    out = octave(script, h5)
    # Octave 7 prints a harmless "ignoring const execution_exception& while preparing to exit" (its bug #62515)
    stderr = [ln for ln in out.stderr.splitlines() if ln.strip() and "while preparing to exit" not in ln]
    assert out.returncode == 0 and "HDF5-DIAG" not in out.stderr, out.stderr
    assert stderr == [SKIPPED_EVENTS], out.stderr  # Octave skips compounds; nothing else may be missing
    lines = out.stdout.splitlines()
    top = lines[0]
    found: dict = {tuple(ln.split()[:2]): int(ln.split()[2]) for ln in lines[1:] if not ln.startswith("event ")}
    found[("top", "fields")] = top.removeprefix("top ")
    found["events"] = [tuple(ln.split()[1:3]) for ln in lines[1:] if ln.startswith("event ")]
    return found


def h5dump_events(h5: Path) -> list[tuple[str, str]]:
    """(kind, source) of every /events row as h5dump (HDF5 1.10) decodes them."""
    out = subprocess.run([_tool("h5dump"), "-y", "-d", "/events", str(h5)], capture_output=True, text=True,
                         timeout=TIMEOUT)
    assert out.returncode == 0 and "error" not in out.stderr.lower(), out.stderr + out.stdout
    body = out.stdout.split("DATA {", 1)[1]
    # each row: { host_time, "kind", "source", "detail", count, gap_s }
    return re.findall(r'\{\s*[^,{}]+,\s*"([^"]*)",\s*"([^"]*)",', body)


def h5py_streams(h5: Path) -> dict[tuple[str, str], int]:
    with h5py.File(h5, "r") as f:
        found = {(a, b): f["streams"][a][b].shape[0] for a in f["streams"] for b in f["streams"][a]}
        found[("top", "fields")] = "event_columns,streams"  # and /events, which Octave skips
        found["events"] = h5py_events(h5)
        return found


def h5py_events(h5: Path) -> list[tuple[str, str]]:
    with h5py.File(h5, "r") as f:
        ev = f["events"][()]
    return [(k.decode(), s.decode()) for k, s in zip(ev["kind"], ev["source"])]


def test_the_old_reader_is_octave_on_hdf5_1_10():
    """Octave and h5dump really are linked to HDF5 1.10.x (printed with -s / -rA)."""
    out = octave("printf('octave %s\\n', version); m = fileread('/proc/self/maps'); "
                 "printf('%s\\n', unique(regexp(m, '/\\S*libhdf5\\S*', 'match')){:})")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.split()
    libs = [p for p in lines[2:] if re.search(r"/libhdf5(_serial)?\.so", p)]
    assert libs, f"Octave has no libhdf5 loaded: {out.stdout}"
    versions = {re.search(rb"HDF5 library version: (\d+\.\d+\.\d+)", Path(p).read_bytes()).group(1).decode()
                for p in libs}
    h5dump = subprocess.run([_tool("h5dump"), "-V"], capture_output=True, text=True, timeout=TIMEOUT).stdout.strip()
    print(f"{lines[0]} {lines[1]} with HDF5 {', '.join(sorted(versions))} ({', '.join(libs)}); {h5dump}; "
          f"h5py {h5py.version.version} with HDF5 {h5py.version.hdf5_version}")
    assert all(v.startswith("1.10.") for v in versions), versions
    assert re.search(r"Version 1\.10\.", h5dump), h5dump


def test_a_cleanly_closed_run_file_opens_in_octave_and_h5dump_1_10(tmp_path):
    path = tmp_path / "run.h5"
    w = RunWriter().open(path, None, streams=[(FORCE, True)], start_host_time=0.0)
    t = np.arange(700) / 1000.0
    w.append(make_block(FORCE, 0, t, np.column_stack([t, -t]), device_t=t + 5.0))
    w.note("start", "clean run, détail non-ASCII")
    w.flush()
    w.append(make_block(TEMP, 0, np.arange(7) / 10.0, 20.0 + np.arange(7.0)))  # a new stream: the reopen path
    w.note("segment", "ramp 1", source="ramp")
    w.note("stop")
    w.close()
    expect = h5py_streams(path)
    assert expect[("force", "fn")] == 700 and expect[("temp", "pad")] == 7
    assert octave_load(path) == expect
    kinds = h5py_events(path)
    assert [k for k, _ in kinds] == ["start", "segment", "stop"]
    assert h5dump_events(path) == kinds


def test_a_run_file_recovered_after_kill_9_opens_in_octave_and_h5dump_1_10(tmp_path):
    path = tmp_path / "killed.h5"
    code = ("import sys, time, numpy as np\n"
            "from daq.io.runfile import RunWriter, WriterCfg\n"
            "from daq.io.stream_format import StreamMeta, make_block\n"
            "m = StreamMeta(stream='force', channels=('fn',), units=('N',), rate_hz=1000.0)\n"
            "w = RunWriter(WriterCfg(flush_s=0.01)).open(sys.argv[1], None, streams=[(m, False)])\n"
            "w.note('start', 'then kill -9')\n"
            "i = 0\n"
            "while True:\n"
            "    t = (np.arange(100) + 100 * i) / 1000.0\n"
            "    w.append(make_block(m, i, t, t))\n"
            "    i += 1\n"
            "    if i % 10 == 0:\n"
            "        w.note('tick', str(i), source='writer')\n"
            "    if i == 30:\n"
            "        w.flush()\n"
            "        print('writing', flush=True)\n"
            "    time.sleep(0.002)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, cwd=ROOT, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
        os.kill(proc.pid, signal.SIGKILL)  # mid-write: it keeps appending and flushing until then
        assert proc.wait(TIMEOUT) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(TIMEOUT)
        proc.stdout.close()
    assert h5recover.is_unclean(path)
    refused = octave("s = load(getenv('DAQ_H5'));", path)  # HDF5 1.10 refuses it too until recover()
    assert "file is already open for write" in refused.stderr, refused.stderr
    recover_run(path)
    expect = h5py_streams(path)
    assert expect[("force", "fn")] >= 3000  # flushed before it said 'writing'
    assert octave_load(path) == expect
    kinds = h5py_events(path)
    assert kinds[0] == ("start", "recorder") and ("tick", "writer") in kinds
    assert h5dump_events(path) == kinds


def test_a_simple_recording_opens_in_octave_and_h5dump_1_10(tmp_path):
    path = tmp_path / "sim.h5"
    t = np.arange(50) / 100.0
    events = [{"host_time": 0.1, "kind": "segment", "source": "ramp", "detail": "hold"},
              {"host_time": 0.3, "kind": "note", "source": "operator", "detail": "µ ≈ 0.4", "count": 2}]
    write_h5(Recording("brake-2dof", t, {"x": t, "v": np.ones(50)}, {"x": "m", "v": "m/s"}, {"software": "test"},
                       {}, events), path)
    found = octave_load(path, OCTAVE_SIMPLE)
    assert found == {("top", "fields"): "channels,event_columns,t", (".", "t"): 50, ("channels", "v"): 50,
                     ("channels", "x"): 50, "events": [("segment", "ramp"), ("note", "operator")]}
    assert h5dump_events(path) == h5py_events(path) == [("segment", "ramp"), ("note", "operator")]
