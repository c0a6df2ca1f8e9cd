"""Memory that grew through issue 29's 30-minute soak, each cause in a test of seconds (tests/long/test_soak_30min.py
judges the whole over 30 minutes).

- The page's process stepped up ~1.5 MB once per cycle of the viewer's windows (10 s, 5 min, the whole run).
  Measured (tracemalloc and glibc's mallinfo2 in the web process, and in its feed and one page on a simulated
  clock): the bytes it held stayed the same (52.1-52.4 MB in use over 28 minutes) while its heap grew 53.7 -> 58.9
  MB, a step at every whole-run view, and 3.2 MB more when the archive halved its resolution at 27 minutes. Every
  whole-run and 5-minute view copied the whole-run archive (and again to select the window), and the halving
  copied it whole, so the largest temporary grew with the run and the heap with it: glibc serves such temporaries
  from the heap once its dynamic mmap threshold has risen past them, and the heap cannot shrink back below the
  long-lived blocks allocated meanwhile. The archive is now read a slice at a time, in place (daq/web/history.py,
  ``ARCHIVE_SLICE``).
- The page's process also kept its last 2000 events as pydantic rows, 1.1 kB each, taken only as the estimator's
  one ``friction_fit`` event a second came: 0.07 MB/min for 33 minutes. They are now one array taken at once.
- Each recorder grew 0.13 MB/min: HDF5's metadata cache kept the global heap collections holding the event table's
  strings, which the writer never reads again, until it was full (1 MiB, ~3 MB of the process, after ~30 minutes
  of one event a second). The run file's cache now ages out what it does not use (daq/io/runfile.py).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np

from daq.io.stream_format import StreamMeta, make_block
from daq.web.history import ARCHIVE_CAP, EnvelopeArchive, StreamHistory

ROOT = Path(__file__).resolve().parent.parent
WIDTH = 1200  # the soak's viewer's plot width [px]
ESTIMATOR = StreamMeta(stream="estimator", channels=("F_est", "N_est", "growing", "latency", "mu_est", "slip", "v_rel"),
                       units=("N", "N", "1", "s", "1", "1", "m/s"), rate_hz=1000.0)  # the widest stream on the page


def _fill(h: StreamHistory, t0: float, t1: float, block_s: float, rng: np.random.Generator) -> None:
    """Samples of ``h``'s stream from run time t0 to t1, in blocks of ``block_s``, as the bus brings them."""
    n = round(block_s * h.meta.rate_hz)
    for a in np.arange(t0, t1, block_s):
        t = a + np.arange(n) / h.meta.rate_hz
        h.add(t, rng.standard_normal((n, len(h.meta.channels))))


def _peak_bytes(fn) -> int:
    """The most ``fn()`` allocated at once beyond what was allocated before (its answer included)."""
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        fn()
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_a_frame_and_a_halving_allocate_the_same_whatever_the_runs_length():
    """The whole-run and the 5-minute views at 5 and at 25 minutes of run: what building their columns allocates does
    not grow with the archive (before: 5 times as much at 25 minutes, the archive copied whole twice), and halving a
    full archive allocates a fraction of what the archive holds (before: a copy of all of it, 3.7 MB)."""
    rng = np.random.default_rng(0)
    h = StreamHistory(ESTIMATOR)
    peaks: dict[str, list[int]] = {"whole run": [], "5 min": []}
    t = 0.0
    for minutes in (5, 25):
        _fill(h, t, minutes * 60.0, 1.0, rng)
        t = minutes * 60.0
        for name, window in (("whole run", t), ("5 min", 300.0)):
            dt = window / WIDTH
            k_from = math.floor((t - window) / dt)
            peaks[name].append(_peak_bytes(lambda k_from=k_from, dt=dt: h.columns(k_from, dt)))
    for name, (at5, at25) in peaks.items():
        # what may grow is the answer (columns), never a copy of the archive: 25 % and 64 kB of slack
        assert at25 <= 1.25 * at5 + 65_536, f"{name} view: {at5:,d} B at 5 min, {at25:,d} B at 25 min"

    a = EnvelopeArchive(len(ESTIMATOR.channels))
    holds = a.k.nbytes + a.lo.nbytes + a.hi.nbytes
    t_full = ARCHIVE_CAP * a.w  # 27 min at 0.05 s a bucket: the next sample halves the resolution
    a.add(np.arange(0, t_full, 0.01), rng.standard_normal((round(t_full / 0.01), len(ESTIMATOR.channels))))
    assert a.n == ARCHIVE_CAP
    w = a.w
    peak = _peak_bytes(lambda: a.add(np.array([t_full + 0.01]), np.zeros((1, len(ESTIMATOR.channels)))))
    assert a.w == 2 * w and a.n == ARCHIVE_CAP // 2 + 1
    assert peak < holds / 4, f"halving a full archive allocated {peak:,d} B at once; the archive holds {holds:,d} B"


# ----------------------------------------------------------------------------- the recorder's file

FIT_EVENT = json.dumps({"rig": "brake-2dof", "t_start": 37432.38662109513, "t_end": 37442.38563031583,  # as recorded
                        "n_points": 2433, "params": {"mu0": 0.5122372949771622, "gamma": 3.1344084754635984,
                                                     "alpha": 200.0, "beta": 0.7, "D": 0.0},
                        "free": ["mu0", "gamma"], "stderr": {"mu0": 0.004878897858923113, "gamma": 0.054739838689094836},
                        "rms": 0.007370282385780577, "success": True,
                        "message": "`ftol` termination condition is satisfied.", "seconds": 0.0037560769997071475},
                       separators=(",", ":"))


def test_a_recording_holds_the_same_metadata_however_many_events_it_writes(tmp_path):
    """The recorder's file side at the soak's pace: a flush every 0.25 s, a ``friction_fit`` event every second, a
    1 kHz stream. HDF5's metadata cache holds the file's working set, not every event's strings: 2000 events (33
    minutes of a ramp) leave it under 0.3 MB and the process's allocated bytes within 0.3 MB of where they were
    after 500 (measured: 0.13 MB, +0.015 MB). Before, the cache kept the events' global heap collections until it
    was full: 1.0 MB after 2000 events and +2.6 MB allocated from event 500 to 2000 (the 30-minute soak's
    recorders grew 0.13 MB/min)."""
    import ctypes
    import gc

    from daq.io.runfile import RunWriter
    from daq.io.stream_format import BusEvent

    class MallInfo2(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                   "fsmblks", "uordblks", "fordblks", "keepcost")]

    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = MallInfo2
    meta = STREAMS[1][0]  # laser_serial, 1 kHz
    w = RunWriter().open(tmp_path / "run.h5", None, streams=[(meta, False)])
    rng = np.random.default_rng(0)
    in_use: dict[int, float] = {}
    try:
        for i in range(4 * 2000):
            t = i * 0.25 + np.arange(250) / 1000
            w.append(make_block(meta, i, t, rng.standard_normal((250, 2))))
            if i % 4 == 0:
                w.event(BusEvent(kind="friction_fit", source="estimator", host_time=t[0], detail=FIT_EVENT))
            w.flush()
            if (i + 1) % 2000 == 0:
                gc.collect()
                in_use[(i + 1) // 4] = libc.mallinfo2().uordblks / 1e6
        cache_mb = w.f.id.get_mdc_size()[2] / 1e6
    finally:
        w.close()
    grew = in_use[2000] - in_use[500]
    assert cache_mb < 0.3 and grew < 0.3, f"metadata cache {cache_mb:.2f} MB; allocated bytes {in_use} MB by events"


def test_the_pages_events_take_their_memory_at_once():
    """The page's process keeps the last 2000 events for pages. As a deque of EventRow they took 1.1 kB each only as
    they came (a ``friction_fit`` event's 405-character detail): 2.3 MB over the 33 minutes that 2000 of the
    estimator's one event a second take, 0.07 MB/min. Now 2000 more events allocate nothing that stays, and a page
    still gets them in order, with what it missed counted."""
    import gc

    from daq.io.stream_format import BusEvent
    from daq.web.feed import EVENT_RING, BusFeed, ClientSession

    feed = BusFeed(["tcp://127.0.0.1:9"], 1000, origin=0.0)  # its bus is never read here
    page = ClientSession(feed, max_unacked=1)
    events = [BusEvent(kind="friction_fit", source="estimator", host_time=float(i), detail=FIT_EVENT)
              for i in range(2 * EVENT_RING)]
    feed.add_event(BusEvent(kind="note", source="operator", host_time=0.5, detail="pad\x00 ok é", count=2))
    new, missed = page._new_events()
    assert [e.model_dump() for e in new] == [{"seq": 1, "t": 0.5, "kind": "note", "source": "operator",
                                              "detail": "pad\x00 ok é", "count": 2}] and missed == 0
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        for ev in events:
            feed.add_event(ev)
        kept = tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()
    assert kept < 50_000, f"{2 * EVENT_RING} events kept {kept:,d} B beyond the ring"
    new, missed = page._new_events()  # 4000 came since its last frame: the oldest 2000 are gone
    assert missed == EVENT_RING and new[0].seq == EVENT_RING + 2 and new[0].detail == FIT_EVENT
    assert [e.seq for e in new] == list(range(EVENT_RING + 2, EVENT_RING + 2 + len(new)))


# ----------------------------------------------------------------------------- the page's process, simulated clock

STREAMS = (  # the soak's streams as the page gets them (rates and channels of brake-2dof's), block length [s]
    (ESTIMATOR, 0.1),
    (StreamMeta(stream="laser_serial", channels=("x1", "phi"), units=("m", "rad"), rate_hz=1000.0), 0.1),
    (StreamMeta(stream="motor", channels=("vb", "vb_set"), units=("m/s", "m/s"), rate_hz=100.0), 0.1),
    (StreamMeta(stream="thermocouple", channels=("temp",), units=("C",), rate_hz=10.0), 0.1),
)
VIEWS = (10.0, 300.0, 0.0)  # the soak's viewer's windows, one a minute (0: the whole run)


def page_cycles(minutes: float, frame_s: float = 0.1, change_s: float = 60.0) -> list[dict[str, float]]:
    """The web process's feed and one page on a simulated clock (run in a process of its own): the soak's streams
    arrive, the page takes a frame every ``frame_s`` (its JSON made, acknowledged), and changes its window every
    ``change_s`` as the soak's viewer does. After each whole-run view: RSS, glibc's heap and bytes in use, objects."""
    import ctypes
    import gc

    from daq.daemon.soak import _rss_mb
    from daq.web.feed import BusFeed, ClientSession
    from daq.web.messages import View

    class MallInfo2(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                   "fsmblks", "uordblks", "fordblks", "keepcost")]

    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = MallInfo2

    class SimulatedFeed(BusFeed):  # blocks handed in by the loop below; the bus itself is never read
        clock = 0.0

        def now(self) -> float:
            return self.clock

    feed = SimulatedFeed(["tcp://127.0.0.1:9"], 1000, origin=0.0)
    page = ClientSession(feed, max_unacked=1)
    rng = np.random.default_rng(0)
    seq = {m.stream: 0 for m, _ in STREAMS}
    k, t, rows = 0, 0.0, []
    page.set_view(View(type="view", window_s=VIEWS[0], width=WIDTH))
    next_change = change_s
    while t < minutes * 60:
        for meta, block_s in STREAMS:  # blocks that end within (t, t + frame_s]
            n = round(block_s * meta.rate_hz)
            for i in range(round(t / block_s), round((t + frame_s) / block_s)):
                tt = (i * n + np.arange(n)) / meta.rate_hz
                feed._take(make_block(meta, seq[meta.stream], tt, rng.standard_normal((n, len(meta.channels)))))
                seq[meta.stream] += 1
        t = feed.clock = t + frame_s
        whole_run_view = False
        if t >= next_change:
            k += 1
            page.set_view(View(type="view", window_s=VIEWS[k % len(VIEWS)], width=WIDTH))
            next_change += change_s
            whole_run_view = VIEWS[k % len(VIEWS)] == 0.0
        frame = page.frame()
        if frame is not None:
            frame.model_dump_json()
            page.ack(frame.seq)
        if whole_run_view:
            gc.collect()
            mi = libc.mallinfo2()
            rows.append({"minute": round(t / 60, 2), "rss_mb": _rss_mb(os.getpid()), "heap_mb": mi.arena / 1e6,
                         "in_use_mb": mi.uordblks / 1e6, "objects": len(gc.get_objects())})
    return rows


def test_window_changes_leave_the_page_process_flat():
    """20 simulated minutes of the soak's streams and viewer (a whole-run view every 3 minutes) in a process of its
    own: after the first cycle, RSS and glibc's heap gain less than 1 MB and the objects held stay the same. Before,
    the heap grew 4.3 MB (50.7 -> 55.0 MB) from minute 5 to 20, RSS 4.2 MB, while the bytes in use stayed flat:
    the high-water of the archive's copies, not objects kept."""
    code = ("import json, sys; sys.path.insert(0, sys.argv[1]); from test_soak_memory import page_cycles; "
            "print(json.dumps(page_cycles(20.0)))")
    r = subprocess.run([sys.executable, "-c", code, str(ROOT / "tests")], cwd=ROOT, capture_output=True, text=True,
                       timeout=600, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    rows = json.loads(r.stdout.strip().splitlines()[-1])
    print("\n".join(json.dumps(row) for row in rows))
    first, last = rows[0], rows[-1]
    assert first["minute"] < 3 and last["minute"] > 19, rows
    after = [row for row in rows if row["minute"] > 4]  # each whole-run view from the second on
    grew = {key: max(row[key] for row in after) - after[0][key] for key in ("rss_mb", "heap_mb", "in_use_mb")}
    assert grew["rss_mb"] < 1.0 and grew["heap_mb"] < 1.0 and grew["in_use_mb"] < 0.5, (grew, rows)
    assert max(row["objects"] for row in after) - min(row["objects"] for row in after) < 1000, rows


def test_the_page_process_imports_nothing_it_does_not_use():
    """The page's process took FloatRing from daq/signals.py, whose scipy imports made it 69 MB larger before any
    data arrived (125 MB instead of 57 MB): scipy is imported where it is used."""
    code = "import sys, daq.web.server; print(sorted(m for m in ('scipy', 'numba', 'h5py', 'matplotlib') if m in sys.modules))"
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "[]", r.stdout


def test_the_long_running_processes_map_large_blocks_on_their_own_whatever_they_freed_before():
    """glibc raises its mmap threshold to the largest block freed, after which the page's large temporaries (a reset
    view's JSON, a copy of a latency ring) come from the heap, whose resident pages then follow the high-water mark
    of the process. The page's process and each recorder fix the threshold (daq/streaming/heap.py): after a 1 MiB
    block is freed, a 512 KiB one is still mapped on its own (unmapped when freed). Without it, it came from the
    heap."""
    code = """
import ctypes, sys, threading, time
from daq.streaming.heap import keep_the_heap_to_what_is_held
class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                                               "uordblks", "fordblks", "keepcost")]
libc = ctypes.CDLL(None)
libc.mallinfo2.restype = MallInfo2
libc.malloc.restype, libc.malloc.argtypes, libc.free.argtypes = ctypes.c_void_p, [ctypes.c_size_t], [ctypes.c_void_p]
stop = threading.Event()
if sys.argv[1] == "page":
    threading.Thread(target=keep_the_heap_to_what_is_held, args=(stop, 0.05), daemon=True).start()
    time.sleep(0.2)
libc.free(libc.malloc(1 << 20))
before = libc.mallinfo2().hblks
block = libc.malloc(512 << 10)
print(libc.mallinfo2().hblks - before)
libc.free(block)
stop.set()
"""
    mapped = {}
    clean = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}  # glibc's default: no tunables set
    for how in ("page", "glibc's default"):
        r = subprocess.run([sys.executable, "-c", code, how], cwd=ROOT, capture_output=True, text=True, timeout=120,
                           check=False, env=clean)
        assert r.returncode == 0, r.stderr[-2000:]
        mapped[how] = int(r.stdout.strip())
    assert mapped == {"page": 1, "glibc's default": 0}, mapped
