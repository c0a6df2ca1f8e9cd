"""The simulated rig in real time (sim_backends/realtime.py): when the physics runs behind the wall clock, as it
does on a loaded machine, a motor command still acts at the simulated instant its wall-clock time stands for."""

from __future__ import annotations

import threading
import time

import numpy as np
from helpers import wait_for

from sim_backends.realtime import RealtimeRig, Tick


def test_a_command_sent_while_the_physics_is_late_acts_at_its_own_instant(brake_cfg):
    rig = RealtimeRig(brake_cfg)
    ticks: list[Tick] = []
    stall = threading.Event()

    def listener(tick: Tick) -> None:  # a slow subscriber: the physics thread falls behind, as under load
        ticks.append(tick)
        if stall.is_set():
            stall.clear()
            time.sleep(0.4)

    rig.subscribe(listener)
    rig.start()
    try:
        wait_for(lambda: rig.t > 0.2, 10.0, "the rig running")
        stall.set()
        time.sleep(0.2)  # the physics thread sleeps in the listener
        sent = (time.monotonic() - rig.wall0) * rig.time_scale
        behind = sent - rig.t
        rig.set_drive(0.1)
        wait_for(lambda: rig.t > sent + 0.2, 10.0, "the physics past the command")
    finally:
        rig.stop()
    t = np.concatenate([k.t for k in ticks])
    v = np.concatenate([k.truth["v_drive"] for k in ticks])
    first_moving = t[np.argmax(v > 0)]
    assert behind > 0.1, behind  # the command came while the physics was well behind
    # it acts from its own instant (the sample after it), not from the late physics' next tick (behind earlier)
    assert sent < first_moving <= sent + 1.5 / rig.rate, (sent, first_moving, behind)
    assert rig.behind_max_s >= behind - 0.02
    # after it, the regulator's limiter: the speed rises at the rig's acceleration limit
    a = brake_cfg.drive.max_accel_m_per_s2
    k = (t > first_moving) & (t < first_moving + 0.05)
    assert np.allclose(v[k], np.minimum(a * (t[k] - sent), 0.1), atol=a / rig.rate)


def test_stepped_by_a_caller_a_command_acts_from_the_next_step_and_the_limiter_holds(brake_cfg):
    rig = RealtimeRig(brake_cfg)
    rig.step(0.1)
    rig.set_drive(0.05, accel=1.0)
    tick = rig.step(0.1)
    v = tick.truth["v_drive"]
    assert np.allclose(v, np.minimum(1.0 * (tick.t - 0.1), 0.05), atol=1e-9)
    rig.set_drive(0.0, accel=0.5)  # a second command reverses it from where the first left the drive
    tick = rig.step(0.2)
    assert np.allclose(tick.truth["v_drive"], np.maximum(0.05 - 0.5 * (tick.t - 0.2), 0.0), atol=1e-9)
    assert rig.behind_max_s == 0.0  # nobody ran it against the wall clock
