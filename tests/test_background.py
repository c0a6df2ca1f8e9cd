"""daq.background.BackgroundLoop: runs, stops promptly, reports a raising step, tolerates stop() in any order."""

from __future__ import annotations

import logging
import threading
import time

from daq.background import BackgroundLoop


def _wait_for(cond, timeout: float = 2.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.001)
    return cond()


def test_the_loop_runs_in_a_named_daemon_thread_until_stopped():
    seen: list[threading.Thread] = []
    loop = BackgroundLoop(lambda: (seen.append(threading.current_thread()), time.sleep(0.001)), "bg-test")
    assert not loop.running
    loop.start()
    assert loop.running
    assert _wait_for(lambda: len(seen) >= 5)
    loop.stop(timeout=2.0)
    assert not loop.running
    th = seen[0]
    assert th is not threading.current_thread() and th.name == "bg-test" and th.daemon
    assert not th.is_alive()
    n = len(seen)
    time.sleep(0.02)
    assert len(seen) == n  # nothing runs after stop()


def test_an_interval_loop_waits_first_and_stops_mid_wait():
    calls: list[float] = []
    loop = BackgroundLoop(lambda: calls.append(time.monotonic()), "bg-interval", interval=0.05)
    t0 = time.monotonic()
    loop.start()
    assert _wait_for(lambda: len(calls) >= 3)
    assert calls[0] - t0 >= 0.045  # the first step comes after one interval, as in `while not stop.wait(s)`
    loop.stop(timeout=2.0)
    long = BackgroundLoop(lambda: calls.append(time.monotonic()), "bg-long", interval=60.0).start()
    t1 = time.monotonic()
    long.stop(timeout=5.0)
    assert time.monotonic() - t1 < 0.5  # stop() ends the wait at once, not after the interval


def test_a_raising_step_is_reported_and_ends_the_loop():
    errors: list[Exception] = []
    calls = []

    def step() -> None:
        calls.append(1)
        if len(calls) == 3:
            raise ValueError("boom")

    loop = BackgroundLoop(step, "bg-raise", on_error=errors.append).start()
    assert _wait_for(lambda: errors)
    assert isinstance(errors[0], ValueError) and str(errors[0]) == "boom"
    time.sleep(0.02)
    assert len(calls) == 3  # the loop ended with the error
    assert loop.running  # until stop(), which is still safe
    loop.stop(timeout=1.0)
    assert not loop.running


def test_a_raising_step_without_a_callback_is_logged(caplog):
    def step() -> None:
        raise RuntimeError("not swallowed")

    with caplog.at_level(logging.ERROR, logger="daq.background"):
        loop = BackgroundLoop(step, "bg-log").start()
        assert _wait_for(lambda: caplog.records)
        loop.stop(timeout=1.0)
    rec = caplog.records[0]
    assert "bg-log" in rec.getMessage()
    assert rec.exc_info is not None and isinstance(rec.exc_info[1], RuntimeError)


def test_stop_before_start_and_twice_is_safe_and_the_loop_restarts():
    calls = []
    loop = BackgroundLoop(lambda: (calls.append(1), time.sleep(0.001)), "bg-restart")
    loop.stop()
    loop.stop(timeout=0.1)
    loop.start()  # its own Event, set by the stop() above, is cleared: the loop runs
    assert _wait_for(lambda: calls)
    loop.stop(timeout=2.0)
    loop.stop(timeout=2.0)
    n = len(calls)
    loop.start()
    assert _wait_for(lambda: len(calls) > n)
    loop.stop(timeout=2.0)


def test_start_while_running_starts_no_second_thread():
    threads: set[int] = set()
    loop = BackgroundLoop(lambda: (threads.add(threading.get_ident()), time.sleep(0.001)), "bg-once")
    loop.start()
    loop.start()
    assert _wait_for(lambda: threads)
    time.sleep(0.02)
    loop.stop(timeout=2.0)
    assert len(threads) == 1


def test_a_shared_event_is_not_cleared_by_start_and_stop_sets_it_for_all():
    shared = threading.Event()
    a_calls, b_calls = [], []
    a = BackgroundLoop(lambda: a_calls.append(1), "bg-a", interval=0.005, stop=shared).start()
    b = BackgroundLoop(lambda: b_calls.append(1), "bg-b", interval=0.005, stop=shared).start()
    assert _wait_for(lambda: a_calls and b_calls)
    a.stop(timeout=2.0)
    assert shared.is_set()
    b.stop(timeout=2.0)
    shared_set_before = BackgroundLoop(lambda: a_calls.append(1), "bg-c", interval=0.001, stop=shared)
    n = len(a_calls)
    shared_set_before.start()  # the caller's Event stays set: the loop ends at once
    time.sleep(0.02)
    shared_set_before.stop(timeout=1.0)
    assert len(a_calls) == n
