"""The daemon as a library (what ``daq demo`` calls): a simulated bench, one ramp, recorded, with progress."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from daq.daemon.service import BenchProgress, run_sim_ramp
from daq.errors import InputError
from daq.io.interchange import read_recording
from daq.ramps import seed_ramp

from helpers import ramp_text

RAMP = ramp_text(1.0)


@pytest.mark.slow
def test_run_sim_ramp_records_every_channel_the_estimator_and_reports_progress(tmp_path):
    seen: list[BenchProgress] = []
    out = run_sim_ramp("brake-2dof", seed_ramp(0.17, 45.0), tmp_path / "seed.h5", ramp_time_scale=3.0 / 45.0,
                       effects=["stick-time"], progress=seen.append, workdir=tmp_path / "work")
    assert out == tmp_path / "seed.h5"
    rec = read_recording(out)
    assert {"x1", "phi", "vb", "vb_set", "temp"} <= set(rec.channels)
    assert np.nanmax(rec.channels["vb_set"]) == pytest.approx(0.17, abs=1e-3)  # the seed ramp's V0, commanded
    with h5py.File(out) as f:  # closed cleanly: a plain open works
        kinds = [k.decode() if isinstance(k, bytes) else k for k in f["events"]["kind"]]
        dev = f["streams/laser_serial/device_t"][()]
        rate = f["streams/laser_serial"].attrs["rate_hz"]
        f_est = f["streams/estimator/F_est"][()]
    assert "ramp_finished" in kinds and "lost_frames" not in kinds and "lost_blocks" not in kinds
    assert np.max(np.diff(dev)) < 1.5 / rate  # not one frame missing from the laser's stream (device clock)
    assert f_est.size > 1000  # the estimator (its own process) is in the file
    assert seen and seen[-1].state == "finished" and seen[-1].fraction == pytest.approx(1.0)
    running = [p for p in seen if p.state == "running"]
    assert len(running) >= 5  # a few per second over the 3 s programme
    assert max(p.belt_speed or 0.0 for p in running) > 0.15  # the measured belt speed, near V0 early on
    assert any(p.friction_N is not None for p in running)  # and the estimator's friction


def test_run_sim_ramp_refuses_a_ramp_beyond_limits_before_starting_anything(tmp_path):
    ramp = tmp_path / "fast.toml"
    ramp.write_text('start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 0.1\nto_m_per_s = 0.4\n')
    with pytest.raises(InputError, match="acceleration"):
        run_sim_ramp("brake-2dof", ramp, tmp_path / "never.h5", workdir=tmp_path / "work")
    assert not (tmp_path / "never.h5").exists() and not (tmp_path / "work").exists()
    with pytest.raises(InputError, match="unknown effect"):
        run_sim_ramp("brake-2dof", seed_ramp(0.17, 45.0), tmp_path / "never.h5", effects=["warp-drive"])
