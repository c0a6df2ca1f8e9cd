"""The recorder with real sockets, real processes and real files: kill -9, clean stop, drops, bad input.

The recorder runs as its own process (``python -m daq.streaming.recorder``); this test process
publishes on ``tcp://127.0.0.1:0``. Published values encode their row index exactly, so
the file's content is checked value for value. Before measuring, the test publishes a
``probe`` stream until the recorder says it has it (ZeroMQ's slow joiner: blocks sent
before the subscription is live are not the recorder's loss).
"""

from __future__ import annotations

import datetime as _dt
import os
import select
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import h5py
import numpy as np
import pytest

from daq.errors import InputError
from daq.io import h5recover
from daq.io.interchange import EVENT_FIELDS, FORMAT_RUN, read_h5, read_recording, write_h5
from daq.io.runfile import BlockRejected, RunWriter, WriterCfg
from daq.io.stream_format import BusEvent, StreamMeta, make_block
from daq.streaming.bus import Publisher

ROOT = Path(__file__).resolve().parent.parent
TIMEOUT = 30.0  # generous: a loaded 2-core CI machine
ROWS = 500  # rows per block
NCH = 4
DT = 1e-5  # 100 kHz rows -> 400 k values/s
META = StreamMeta(stream="ramp", channels=tuple(f"c{i}" for i in range(NCH)), units=("m", "rad", "m/s", "V"),
                  source="test", rate_hz=1.0 / DT)
PROBE = StreamMeta(stream="probe", channels=("p",), units=("",), source="test")


def rows(k0: int, n: int, t0: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows k0..k0+n-1: t = t0 + k DT, channel c holds k*NCH + c (exact in float64)."""
    k = np.arange(k0, k0 + n)
    return t0 + k * DT, (k[:, None] * NCH + np.arange(NCH)[None, :]).astype(np.float64)


class RecorderProc:
    """A recorder subprocess with line-wise access to its stdout and its stderr kept in a file."""

    def __init__(self, tmp_path: Path, endpoint: str, out: Path, *extra: str) -> None:
        self.err_path = tmp_path / f"{out.stem}.stderr"
        self._err = open(self.err_path, "w")
        self.proc = subprocess.Popen([sys.executable, "-m", "daq.streaming.recorder", "--endpoint", endpoint,
                                      "--rig", "brake-2dof", "-o", str(out), *extra],
                                     stdout=subprocess.PIPE, stderr=self._err, cwd=ROOT, bufsize=0)
        self._buf = b""
        self.lines: list[str] = []

    def stderr(self) -> str:
        self._err.flush()
        return self.err_path.read_text()

    def _next_line(self, timeout: float) -> str | None:
        """One stdout line, or None if none came within timeout (unbuffered: select sees every byte)."""
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.proc.stdout], [], [], left)[0]:
                return None
            chunk = os.read(self.proc.stdout.fileno(), 4096)
            if not chunk:
                raise AssertionError(f"recorder exited (rc={self.proc.wait(TIMEOUT)}): {self.stderr()}")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        self.lines.append(line.decode())
        return self.lines[-1]

    def wait_line(self, prefix: str, timeout: float = TIMEOUT, pub: Publisher | None = None) -> str:
        """Wait for a stdout line starting with prefix; meanwhile publish probe blocks if ``pub`` is given."""
        deadline = time.monotonic() + timeout
        k = 0
        while time.monotonic() < deadline:
            if pub is not None:
                pub.publish(PROBE, np.array([time.monotonic()]), np.array([[float(k)]]))
                k += 1
            line = self._next_line(0.02)
            if line is not None and line.startswith(prefix):
                return line
        raise AssertionError(f"no {prefix!r} line from the recorder (rc={self.proc.poll()}): {self.stderr()}")

    def start(self, pub: Publisher) -> None:
        self.wait_line("ready")
        self.wait_line("stream probe", pub=pub)

    def terminate(self) -> int:
        self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(TIMEOUT)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(TIMEOUT)
        self.proc.stdout.close()
        self._err.close()


@pytest.fixture
def pub():
    p = Publisher("tcp://127.0.0.1:0", sndhwm=100_000)
    yield p
    p.close()


@pytest.fixture
def recorder(tmp_path, pub):
    procs: list[RecorderProc] = []

    def start(out: Path, *extra: str, via: Publisher | None = None) -> RecorderProc:
        rp = RecorderProc(tmp_path, (via or pub).endpoint, out, *extra)
        procs.append(rp)
        rp.start(via or pub)
        return rp

    yield start
    for rp in procs:
        rp.close()


def wait_rows(path: Path, stream: str, n: int, timeout: float = TIMEOUT) -> None:
    """Read the live file (SWMR) until ``stream`` holds n rows."""
    deadline = time.monotonic() + timeout
    have = -1
    while time.monotonic() < deadline:
        try:
            with h5py.File(path, "r", swmr=True) as f:
                if stream in f["streams"]:
                    have = f["streams"][stream]["t"].shape[0]
                    if have >= n:
                        return
        except (OSError, KeyError, RuntimeError, ValueError):
            pass  # the recorder is reopening to add a stream
        time.sleep(0.05)
    raise AssertionError(f"{stream}: {have} rows after {timeout} s, expected {n}")


def event_table(f: h5py.File) -> dict[str, list]:
    """The /events table as columns, the way pandas.DataFrame(dict) would take them."""
    ds = f["events"]
    assert ds.dtype.names == EVENT_FIELDS
    cols = {name: ds.fields(name)[()] for name in ds.dtype.names}
    return {k: [x.decode() if isinstance(x, bytes) else x for x in v] for k, v in cols.items()}


# ---------------------------------------------------------------- crash safety


@pytest.mark.slow
def test_kill_9_leaves_a_readable_file_missing_at_most_the_last_second(tmp_path, pub, recorder):
    out = tmp_path / "run.h5"
    rp = recorder(out, "--flush-s", "0.25")
    t0 = time.monotonic()
    log: list[tuple[float, int]] = []  # (monotonic time after the send, rows sent so far)
    k = 0
    while time.monotonic() - t0 < 3.0:
        target = t0 + k * DT
        if (wait := target - time.monotonic()) > 0:
            time.sleep(wait)
        t, data = rows(k, ROWS, t0)
        pub.publish(META, t, data)
        k += ROWS
        log.append((time.monotonic(), k))
    kill_time = time.monotonic()
    os.kill(rp.proc.pid, signal.SIGKILL)
    assert rp.proc.wait(TIMEOUT) == -signal.SIGKILL

    assert h5recover.is_unclean(out)
    with pytest.raises(OSError, match="already open for write"):
        h5py.File(out, "r")

    rec = read_recording(out)  # opens the unclean file without any extra step
    n = rec.t.size
    sent_by_deadline = max((rows_ for when, rows_ in log if when <= kill_time - 1.0), default=0)
    assert sent_by_deadline > 100_000  # the run did publish for more than a second
    assert sent_by_deadline <= n <= k
    t_exp, data_exp = rows(0, n, t0)
    for c in range(NCH):
        np.testing.assert_array_equal(rec.channels[f"c{c}"], data_exp[:, c])  # no holes, no extra
    np.testing.assert_array_equal(rec.t, t_exp - rec.meta["start_host_time"])
    assert rec.units["c1"] == "rad" and rec.rig == "brake-2dof"
    assert rec.meta["time_base"] == "ramp"
    assert np.all(np.isnan(rec.channels["p"]))  # the probe stream ended before the ramp began: outside its span

    h5recover.recover(out)
    assert not h5recover.is_unclean(out)
    with h5py.File(out, "r") as f:  # a plain open now works
        g = f["streams/ramp"]
        cols = {name: g[name][()] for name in ("t", *META.channels)}
        assert {len(v) for v in cols.values()} == {n}
        np.testing.assert_array_equal(cols["t"], t_exp)
        assert [g[c].attrs["unit"] for c in META.channels] == list(META.units)
        assert list(g.attrs["channels"]) == list(META.channels) and g.attrs["source"] == "test"
        assert f.attrs["format"] == FORMAT_RUN
        assert f.attrs["software"].startswith("friction-daq ")
        assert _dt.datetime.fromisoformat(f.attrs["created"]).tzinfo is not None
        assert tomllib.loads(f.attrs["rig_config"])["rig"] == "brake-2dof"
        ev = event_table(f)
        assert ev["kind"][0] == "start" and "stop" not in ev["kind"]


def test_read_h5_opens_a_file_killed_outside_swmr_mode(tmp_path):
    out = tmp_path / "plain.h5"
    code = ("import h5py, numpy as np, os, signal, sys\n"
            "f = h5py.File(sys.argv[1], 'w', libver='latest')\n"
            "f.create_dataset('t', data=np.arange(5.0))\n"
            "f.create_group('channels').create_dataset('x1', data=np.arange(5.0) * 2)\n"
            "f.flush(); os.kill(os.getpid(), signal.SIGKILL)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(out)], timeout=TIMEOUT)
    assert proc.returncode == -signal.SIGKILL
    assert h5recover.is_unclean(out)
    with pytest.raises(OSError):
        h5py.File(out, "r", swmr=True)  # not written in SWMR mode
    before = out.read_bytes()
    rec = read_h5(out)
    np.testing.assert_array_equal(rec.channels["x1"], np.arange(5.0) * 2)
    assert out.read_bytes() == before  # reading never modifies the file


# ---------------------------------------------------------------- clean stop, events


def test_sigterm_closes_cleanly_with_all_data_and_bus_events(tmp_path, pub, recorder):
    out = tmp_path / "run.h5"
    ramp = tmp_path / "ramp.toml"
    ramp.write_text('name = "hold"\nstart_m_per_s = 0.1\n[[segment]]\nkind = "hold"\nduration_s = 2.0\n')
    rp = recorder(out, "--ramp", str(ramp), "--note", "pad 3, new belt")
    t0 = time.monotonic()
    pub.event("ramp_segment", "daemon", "hold 0.1 m/s for 2 s", count=0)
    n_blocks = 20
    for b in range(n_blocks):
        t, data = rows(b * ROWS, ROWS, t0)
        pub.publish(META, t, data, device_t=t - t0)
        if b == 5:
            pub.event("gap", "can", "x1: no frames", gap_s=0.125)
    pub.event("note", "operator", "squeal audible")
    wait_rows(out, "ramp", n_blocks * ROWS)
    assert rp.terminate() == 0
    assert not h5recover.is_unclean(out)
    with h5py.File(out, "r") as f:
        g = f["streams/ramp"]
        t_exp, data_exp = rows(0, n_blocks * ROWS, t0)
        np.testing.assert_array_equal(g["t"][()], t_exp)
        np.testing.assert_array_equal(g["device_t"][()], t_exp - t0)
        np.testing.assert_array_equal(g["c3"][()], data_exp[:, 3])
        assert f.attrs["ramp"] == ramp.read_text()
        ev = event_table(f)
    kinds = ev["kind"]
    assert kinds[0] == "start" and kinds[-1] == "stop"
    row = {k: kinds.index(k) for k in ("note", "ramp_segment", "gap")}
    assert ev["source"][row["gap"]] == "can" and ev["gap_s"][row["gap"]] == 0.125
    assert ev["count"][row["gap"]] == -1
    assert ev["detail"][row["ramp_segment"]] == "hold 0.1 m/s for 2 s" and ev["count"][row["ramp_segment"]] == 0
    assert np.isnan(ev["gap_s"][row["ramp_segment"]])
    notes = [d for k, s, d in zip(kinds, ev["source"], ev["detail"]) if k == "note"]
    assert notes == ["pad 3, new belt", "squeal audible"]
    assert "lost_blocks" not in kinds
    rec = read_recording(out)
    assert [e["kind"] for e in rec.events] == kinds
    assert rec.events[row["gap"]]["gap_s"] == 0.125 and rec.events[row["gap"]]["count"] is None
    assert "closed" in rp.stderr()


@pytest.fixture
def tiny_pub():
    p = Publisher("tcp://127.0.0.1:0", sndhwm=1)  # a bound socket's HWM is fixed at bind time
    yield p
    p.close()


@pytest.mark.slow
def test_drops_are_counted_in_the_event_table(tmp_path, recorder, tiny_pub):
    """A stopped recorder with a one-message queue: every dropped block appears in a lost_blocks event."""
    pub = tiny_pub
    out = tmp_path / "drop.h5"
    rp = recorder(out, "--rcvhwm", "1", via=pub)
    big = StreamMeta(stream="burst", channels=("a", "b"), units=("m", "m"), source="test")
    n_rows = 50_000  # 800 kB per block

    def send(seq: int) -> None:
        t = seq + np.arange(n_rows) / n_rows
        pub.publish(big, t, np.full((n_rows, 2), float(seq)))

    # With a one-message send queue the first burst block can itself be dropped behind a probe block
    # still queued: send until the recorder has seen the stream (blocks lost before the first one a
    # subscriber sees cannot be known to it, so counting starts at the first block received).
    seq = 0
    deadline = time.monotonic() + TIMEOUT
    while True:
        send(seq)
        seq += 1
        line = rp._next_line(0.2)
        if line is not None and line.startswith("stream burst"):
            break
        assert time.monotonic() < deadline, f"the recorder never saw the burst stream: {rp.stderr()}"
    os.kill(rp.proc.pid, signal.SIGSTOP)  # the recorder stalls: queues fill, the PUB drops
    try:
        n_burst = seq + 300
        for seq in range(seq, n_burst + 1):
            send(seq)
    finally:
        os.kill(rp.proc.pid, signal.SIGCONT)
    seq = n_burst + 1
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:  # a block after the burst must get through: it reveals the drops
        send(seq)
        seq += 1
        try:
            with h5py.File(out, "r", swmr=True) as f:
                last = f["streams/burst/a"][-1]
            if last > n_burst:
                break
        except (OSError, KeyError, RuntimeError, ValueError, IndexError):
            pass
        time.sleep(0.2)
    assert rp.terminate() == 0
    with h5py.File(out, "r") as f:
        a = f["streams/burst/a"][()]
        ev = event_table(f)
    seqs = a.reshape(-1, n_rows)[:, 0]
    assert np.all(a.reshape(-1, n_rows) == seqs[:, None])  # whole blocks only
    assert np.all(np.diff(seqs) > 0)
    lost = [(c, s, d) for k, c, s, d in zip(ev["kind"], ev["count"], ev["source"], ev["detail"]) if k == "lost_blocks"]
    assert lost and all(s == "recorder" for _, s, _ in lost)
    lost = [x for x in lost if x[2].startswith("burst:")]  # a probe block queued at the start may be dropped too
    assert sum(c for c, _, _ in lost) == int(seqs[-1] - seqs[0]) + 1 - seqs.size > 0


def test_malformed_and_unstorable_messages_are_logged_not_fatal(tmp_path, recorder, pub):
    out = tmp_path / "bad.h5"
    rp = recorder(out)
    t0 = time.monotonic()
    t, data = rows(0, ROWS, t0)
    pub.publish(META, t, data)
    header = make_block(META, 1, t, data).header.model_dump_json().encode()
    bad = [[b"S:ramp", b"{not json", b"", b""],
           [b"S:ramp", header, t.tobytes(), data[:10].tobytes()],  # payload shorter than the header says
           [b"S:ramp", b"only two parts"],
           [b"E:daemon", b'{"kind": "note"}']]  # event without its required fields
    for parts in bad:
        pub.sock.send_multipart(parts)
    two = StreamMeta(stream="ramp", channels=("c0", "c1"), units=("m", "rad"))
    pub.publish(two, t, data[:, :2])  # the stream changes shape mid-run
    pub.publish(StreamMeta(stream="odd", channels=("x", "y"), units=("m",)), t, data[:, :2])  # 1 unit, 2 channels
    pub.publish(StreamMeta(stream="odd2", channels=("t",), units=("s",)), t, data[:, :1])  # would clash with t
    pub.publish(StreamMeta(stream="odd3", channels=("a/b",), units=("m",)), t, data[:, :1])
    t2, data2 = rows(ROWS, ROWS, t0)
    pub.publish(META, t2, data2)
    wait_rows(out, "ramp", 2 * ROWS)
    assert rp.terminate() == 0
    with h5py.File(out, "r") as f:
        assert set(f["streams"]) == {"probe", "ramp"}
        np.testing.assert_array_equal(f["streams/ramp/c2"][()], rows(0, 2 * ROWS, t0)[1][:, 2])
        ev = event_table(f)
    assert ev["kind"].count("malformed") == 4
    rejected = [d for k, d in zip(ev["kind"], ev["detail"]) if k == "rejected"]
    assert len(rejected) == 4
    assert "changed mid-run" in rejected[0] and "1 units for 2 channels" in rejected[1]
    assert "'t'" in rejected[2] and "'a/b'" in rejected[3]


# ---------------------------------------------------------------- the writer and the reader, in process


def test_streams_merge_onto_the_fastest_time_base(tmp_path):
    out = tmp_path / "merge.h5"
    fast = StreamMeta(stream="can", channels=("x1", "phi"), units=("m", "rad"), rate_hz=1000.0)
    slow = StreamMeta(stream="motor", channels=("vb", "vb_set"), units=("m/s", "m/s"), rate_hz=100.0)
    temp = StreamMeta(stream="thermo", channels=("temp",), units=("degC",), dtype="float32")
    w = RunWriter(WriterCfg(flush_s=1.0)).open(out, None, "", {"operator": "test"}, start_host_time=100.0)
    tf = 100.0 + np.arange(3000) / 1000.0  # 0 .. 2.999 s
    w.append(make_block(fast, 0, tf[:1500], np.column_stack([tf[:1500], -tf[:1500]])))
    w.flush()  # the next streams appear after a flush: the writer reopens to add them
    ts = 100.5 + np.arange(100) / 100.0  # 0.5 .. 1.49 s, then a hole, then 2.0 .. 2.49
    ts = np.concatenate([ts, 102.0 + np.arange(50) / 100.0])
    w.append(make_block(slow, 0, ts, np.column_stack([2 * ts, np.full(ts.size, 0.17)]), device_t=ts - 100.0))
    w.append(make_block(temp, 0, np.array([100.0, 103.0]), np.array([[20.0], [23.0]])))
    w.append(make_block(fast, 1, tf[1500:], np.column_stack([tf[1500:], -tf[1500:]])))
    w.event(BusEvent(kind="gap", source="motor", host_time=101.5, gap_s=0.5))
    w.close()

    rec = read_h5(out)
    assert list(rec.channels) == ["x1", "phi", "vb", "vb_set", "temp"]
    np.testing.assert_allclose(rec.t, tf - 100.0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rec.channels["x1"], tf)
    vb = rec.channels["vb"]
    edge = np.min(np.abs(rec.t[:, None] - np.array([0.5, 1.49, 2.0, 2.49])[None, :]), axis=1) < 1e-6
    span = (rec.t > 0.5) & (rec.t < 2.49) & ~edge
    hole = (rec.t > 1.49) & (rec.t < 2.0) & ~edge
    assert np.all(np.isnan(vb[~span & ~edge])) and np.all(np.isnan(vb[hole]))
    assert np.sum(span & ~hole) > 1000
    np.testing.assert_allclose(vb[span & ~hole], 2 * tf[span & ~hole], rtol=1e-12)
    np.testing.assert_allclose(rec.channels["temp"], 20.0 + rec.t, rtol=1e-6)  # linear between its two samples
    assert rec.units == {"x1": "m", "phi": "rad", "vb": "m/s", "vb_set": "m/s", "temp": "degC"}
    assert rec.meta["operator"] == "test" and rec.meta["streams"]["thermo"]["dtype"] == "float32"
    assert rec.events == [{"t": 1.5, "host_time": 101.5, "kind": "gap", "source": "motor", "detail": "",
                           "count": None, "gap_s": 0.5}]
    with h5py.File(out, "r") as f:
        assert f["streams/motor/device_t"].shape == (150,) and f["streams/thermo/temp"].dtype == np.float32
    # a merged recording written as a simple file keeps its events
    write_h5(rec, tmp_path / "simple.h5")
    back = read_h5(tmp_path / "simple.h5")
    assert back.events == rec.events
    np.testing.assert_array_equal(back.channels["vb"], vb)


def test_a_new_stream_appears_while_another_process_reads_the_file(tmp_path):
    """A reader holding the growing file (HDF5 file lock) must not stop the writer from adding a stream."""
    out = tmp_path / "live.h5"
    a = StreamMeta(stream="a", channels=("x1",), units=("m",))
    b = StreamMeta(stream="b", channels=("vb",), units=("m/s",))
    w = RunWriter().open(out, None)
    w.append(make_block(a, 0, np.arange(3.0), np.arange(3.0)))
    w.flush()
    code = ("import h5py, sys\n"
            "f = h5py.File(sys.argv[1], 'r', swmr=True)\n"
            "print(f['streams/a/x1'].shape[0], flush=True)\n"
            "sys.stdin.read()\n")
    reader = subprocess.Popen([sys.executable, "-c", code, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert reader.stdout.readline().strip() == "3"  # the reader has the file open
        w.append(make_block(b, 0, np.arange(2.0), np.array([0.1, 0.2])))
        w.append(make_block(a, 1, np.arange(3.0, 5.0), np.arange(3.0, 5.0)))
        w.flush()  # needs the reopen
        w.close()
    finally:
        reader.communicate("", timeout=TIMEOUT)
    with h5py.File(out, "r") as f:
        np.testing.assert_array_equal(f["streams/a/x1"][()], np.arange(5.0))
        np.testing.assert_array_equal(f["streams/b/vb"][()], [0.1, 0.2])


def test_writer_rejects_blocks_it_cannot_store(tmp_path):
    w = RunWriter().open(tmp_path / "r.h5", None)
    meta = StreamMeta(stream="s", channels=("a",), units=("m",))
    w.append(make_block(meta, 0, np.arange(3.0), np.arange(3.0)))
    with pytest.raises(BlockRejected, match="changed mid-run"):
        w.append(make_block(meta.model_copy(update={"units": ("mm",)}), 1, np.arange(3.0), np.arange(3.0)))
    with pytest.raises(BlockRejected, match="device_t"):
        w.append(make_block(meta, 2, np.arange(3.0), np.arange(3.0), device_t=np.arange(3.0)))
    with pytest.raises(BlockRejected, match="duplicate"):
        w.append(make_block(StreamMeta(stream="d", channels=("a", "a"), units=("m", "m")), 0,
                            np.arange(2.0), np.zeros((2, 2))))
    w.close()
    with h5py.File(tmp_path / "r.h5", "r") as f:
        np.testing.assert_array_equal(f["streams/s/a"][()], np.arange(3.0))


def test_empty_run_file_is_an_input_error(tmp_path):
    RunWriter().open(tmp_path / "empty.h5", None).close()
    with pytest.raises(InputError) as info:
        read_h5(tmp_path / "empty.h5")
    assert (info.value.field, info.value.message) == ("streams", "no samples recorded")


def test_recorder_refuses_an_existing_output(tmp_path):
    out = tmp_path / "run.h5"
    out.write_bytes(b"precious")
    proc = subprocess.run([sys.executable, "-m", "daq.streaming.recorder", "--rig", "brake-2dof", "-o", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"{out}: -o: exists (use --force to overwrite)"
    assert out.read_bytes() == b"precious"


# ---------------------------------------------------------------- h5recover


def test_lookup3_matches_the_reference_vectors():
    # from Bob Jenkins' lookup3.c driver5()
    assert h5recover.lookup3(b"") == 0xDEADBEEF
    assert h5recover.lookup3(b"", 0xDEADBEEF) == 0xBD5B7DDE
    assert h5recover.lookup3(b"Four score and seven years ago") == 0x17770551
    assert h5recover.lookup3(b"Four score and seven years ago", 1) == 0xCD628161


def test_recover_is_a_no_op_on_a_clean_file(tmp_path):
    path = tmp_path / "clean.h5"
    with h5py.File(path, "w", libver="latest") as f:
        f["x"] = np.arange(3)
    before = path.read_bytes()
    assert not h5recover.is_unclean(path)
    h5recover.recover(path)
    assert path.read_bytes() == before


def test_recover_refuses_an_old_superblock(tmp_path):
    path = tmp_path / "v0.h5"
    with h5py.File(path, "w", libver="earliest") as f:
        f["x"] = np.arange(3)
    assert not h5recover.is_unclean(path)
    with pytest.raises(InputError) as info:
        h5recover.recover(path)
    assert info.value.field == "superblock" and "version 0" in info.value.message
    assert "\n" not in str(info.value)


def _unclean_file(path: Path) -> None:
    code = ("import h5py, os, signal, sys\n"
            "f = h5py.File(sys.argv[1], 'w', libver='latest'); f['x'] = [1.0, 2.0]; f.swmr_mode = True\n"
            "f.flush(); os.kill(os.getpid(), signal.SIGKILL)\n")
    subprocess.run([sys.executable, "-c", code, str(path)], timeout=TIMEOUT)


def test_recover_refuses_a_checksum_mismatch_and_leaves_the_file_alone(tmp_path):
    path = tmp_path / "bad.h5"
    _unclean_file(path)
    assert h5recover.is_unclean(path)
    raw = bytearray(path.read_bytes())
    raw[20] ^= 0xFF  # inside the base/extension addresses, covered by the checksum
    path.write_bytes(bytes(raw))
    with pytest.raises(InputError) as info:
        h5recover.recover(path)
    assert info.value.field == "superblock" and "checksum mismatch" in info.value.message
    assert path.read_bytes() == bytes(raw)


def test_recover_refuses_a_file_that_is_not_hdf5(tmp_path):
    path = tmp_path / "x.h5"
    path.write_text("t,x\n0,1\n")
    assert not h5recover.is_unclean(path)
    with pytest.raises(InputError) as info:
        h5recover.recover(path)
    assert info.value.field == "superblock" and "not an HDF5 file" in info.value.message


def test_recover_changes_only_the_flag_and_checksum(tmp_path):
    path = tmp_path / "u.h5"
    _unclean_file(path)
    before = path.read_bytes()
    h5recover.recover(path)
    after = path.read_bytes()
    so = before[9]
    changed = [i for i in range(len(before)) if before[i] != after[i]]
    assert changed and set(changed) <= {11, *range(12 + 4 * so, 16 + 4 * so)}
    assert after[11] == 0
    with h5py.File(path, "r") as f:
        assert f["x"][()].tolist() == [1.0, 2.0]


def test_a_derived_stream_at_the_same_rate_never_becomes_the_time_base(tmp_path):
    """The estimator publishes one estimate per laser sample with jittered host stamps; if it won the time
    base by a hair, every measured channel would be interpolated at jittered instants (seen in the demo)."""
    out = tmp_path / "base.h5"
    laser = StreamMeta(stream="laser_serial", channels=("x1",), units=("m",), rate_hz=1000.0)
    est = StreamMeta(stream="estimator", channels=("F_est",), units=("N",), rate_hz=1000.0)
    w = RunWriter(WriterCfg(flush_s=1.0)).open(out, None, "", {}, start_host_time=100.0)
    tl = 100.0 + np.arange(2000) / 1000.0
    te = 100.0003 + np.arange(2001) / 1000.2 + np.random.default_rng(0).uniform(0, 3e-4, 2001)  # a hair faster
    w.append(make_block(laser, 0, tl, tl[:, None] * 2.0, device_t=tl - 100.0))
    w.append(make_block(est, 0, te, np.ones((te.size, 1))))
    w.close()
    rec = read_h5(out)
    assert rec.meta["time_base"] == "laser_serial"
    np.testing.assert_array_equal(rec.channels["x1"], tl * 2.0)  # measured samples untouched, not interpolated
