"""The daemon against a simulated rig: a ramp runs, the recording holds every channel and the ramp's events."""

from __future__ import annotations

import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from daq.daemon import Daemon, DaemonCfg
from daq.errors import InputError
from daq.io.interchange import read_recording

RAMP = """start_m_per_s = 0.0
[[segment]]
kind = "linear"
duration_s = 0.5
to_m_per_s = 0.15
[[segment]]
kind = "hold"
duration_s = 1.0
[[segment]]
kind = "linear"
duration_s = 0.5
to_m_per_s = 0.0
"""


@pytest.fixture()
def daemon(tmp_path):
    d = Daemon(DaemonCfg(rig="brake-2dof", sim=True, workdir=tmp_path / "dev", data_dir=tmp_path / "data",
                         bus_endpoint="tcp://127.0.0.1:0", estimator_endpoint="tcp://127.0.0.1:0")).start()
    yield d
    d.shutdown()


def test_ramp_is_recorded_with_every_channel_and_its_events(daemon, tmp_path):
    ramp = tmp_path / "ramp.toml"
    ramp.write_text(RAMP)
    path = Path(daemon.handle_record_start({})["recording"])
    time.sleep(0.3)
    daemon.handle_ramp({"file": str(ramp)})
    assert daemon.runner.join(15)
    daemon.handle_note({"text": "after the ramp"})
    time.sleep(0.5)
    status = daemon.handle_status({})
    assert status["ramp"]["fraction"] == pytest.approx(1.0)
    daemon.handle_record_stop({})
    rec = read_recording(path)
    assert {"x1", "phi", "vb", "vb_set", "temp"} <= set(rec.channels)
    vb_set = rec.channels["vb_set"]
    assert np.nanmax(vb_set) == pytest.approx(0.15, abs=1e-3)  # the commanded speed, recorded beside vb
    assert np.nanmax(rec.channels["vb"]) > 0.14
    with h5py.File(path) as f:  # closed cleanly: a plain open works
        kinds = [k.decode() if isinstance(k, bytes) else k for k in f["events"]["kind"]]
        t = f["streams/laser_serial/t"][()]
        dev = f["streams/laser_serial/device_t"][()]
        rate = f["streams/laser_serial"].attrs["rate_hz"]
        f_est = f["streams/estimator/F_est"][()]
    assert kinds.count("ramp_segment") >= 6 and "ramp_finished" in kinds and "note" in kinds
    assert "lost_frames" not in kinds and "lost_blocks" not in kinds
    assert np.max(np.diff(dev)) < 1.5 / rate  # not one frame missing from the laser's stream (device clock)
    assert f_est.size > 100 and np.isfinite(f_est).mean() > 0.5  # the estimator (own process) is in the file
    assert np.max(np.diff(t)) < 1.0  # and it reached the host steadily (reads are batched, so host t is bursty)


def test_ramp_beyond_limits_refused_before_motion(daemon, tmp_path):
    ramp = tmp_path / "fast.toml"
    ramp.write_text('start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 0.1\nto_m_per_s = 0.4\n')
    with pytest.raises(InputError, match="acceleration"):
        daemon.handle_ramp({"file": str(ramp)})
    time.sleep(0.3)
    sim = daemon.sim.status()
    assert sim["belt_speed"] == 0.0 and sim["motor_state"] == "DISABLED" and sim["setpoint"] == 0.0  # never enabled
