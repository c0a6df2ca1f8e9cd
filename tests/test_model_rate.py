"""A model's rate (issue 14, long records): records sampled faster than the model steps are block-averaged.

What could fail: the averaging itself (noise must fall by sqrt(q), the declared noise with it, spikes counted
at the file's samples), the coarser step of the belt model (a window's prediction must not move by more than a
fraction of the averaged noise: a convergence check against the config's 0.5 ms step), and the two guards
that made a belt fit hang (a belt lag far shorter than the step; a contact switching every step).
Decision record: docs/decisions/0023-a-model-rate-for-long-records.md.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from daq.config import load_rig
from daq.io.interchange import Recording
from daq.models.fit.data import rig_data
from daq.models.fit.session import Session
from daq.models.spec import seed_model
from daq.physics import beltndof
from daq.physics.effects import E
from daq.signals import block_mean
from daq.sim.effectset import environment_vector
from daq.sim.rigs import make_sim
from daq.sim.run import simulate as simulate_rig


def test_block_means_lower_white_noise_by_the_root_of_the_block():
    rng = np.random.default_rng(1)
    x = rng.normal(0.0, 1.0, 60_001)
    y = block_mean(x, 6)
    assert y.size == 10_000  # the trailing partial block is dropped
    assert abs(np.std(y) * math.sqrt(6) - 1.0) < 0.03
    ramp = np.arange(12.0)
    assert np.array_equal(block_mean(ramp, 4), [1.5, 5.5, 9.5])  # a line is read at each block's centre


def test_a_2khz_belt_record_is_compared_as_block_means_one_per_model_step():
    cfg = load_rig("belt-ndof")
    rec = simulate_rig(cfg, duration=6.0, rate=2000.0, seed=2)
    x = rec.channels["x1"].copy()
    spikes = np.array([1000, 4321, 9000])
    x[spikes] += 3e-3  # 150 noise levels
    rec = Recording(rec.rig, rec.t, {**rec.channels, "x1": x}, rec.units, rec.meta)
    rd = rig_data(cfg)
    step = rd.model_step()
    q = int(2000.0 * step)
    assert cfg.integrator.dt_s < step < 0.01 and q >= 2
    m = rd.prepare(rec, "fast")
    assert m.averaged == q and m.rate == pytest.approx(2000.0 / q)
    assert m.n == rec.t.size // q and m.recording.t.size == m.n
    assert m.recording.meta["averaged"] == q
    assert sorted(m.outliers["x1"].tolist()) == spikes.tolist()  # counted at the file's samples
    ch = cfg.channels["x1"]
    declared = math.sqrt(ch.noise_std**2 + ch.lsb**2 / 12.0)
    assert m.sigma["x1"] <= declared / math.sqrt(q) * (1 + 1e-12)
    # the record's own rate when it is already at or below one sample per step
    slow = rd.prepare(simulate_rig(cfg, duration=6.0, seed=2), "slow")
    assert slow.averaged == 1 and slow.rate == pytest.approx(cfg.sensors.rate_Hz)


def test_brake_and_drum_records_at_khz_rates_are_not_averaged():
    for rig in ("brake-2dof", "drum-pendulum"):
        cfg = load_rig(rig)
        m = rig_data(cfg).prepare(simulate_rig(cfg, duration=3.0, rate=1000.0, seed=1), rig)
        assert m.averaged == 1 and m.rate == pytest.approx(1000.0)


def test_the_belt_models_step_moves_no_window_by_a_fifth_of_the_averaged_noise():
    """Convergence: every fit window of a 2 kHz record simulated at the model's step and at the config's 0.5 ms."""
    cfg = load_rig("belt-ndof")
    rec = simulate_rig(cfg, duration=20.0, rate=2000.0, seed=4)
    s = Session(rec, "fast", cfg)
    pr = s.problem(seed_model("belt-ndof"))
    assert pr.n_sub == 1
    fw = s.win.select(False)
    values = pr.builder.base_values
    coarse = pr.shoot(values, fw).pred["x1"]
    fine_sub = int(round(pr.h / cfg.integrator.dt_s))
    pr.n_sub, pr.h = fine_sub, pr.h / fine_sub
    fine = pr.shoot(values, fw).pred["x1"]
    assert fine_sub >= 5
    assert np.ptp(fine) > 1e-2  # stick-slip of several cm: the windows move
    assert np.max(np.abs(coarse - fine)) < 0.2 * s.m.sigma["x1"], (np.max(np.abs(coarse - fine)), s.m.sigma["x1"])


def test_a_belt_lag_shorter_than_the_step_is_integrated_as_none():
    cfg = load_rig("belt-ndof")
    e = environment_vector(cfg)
    runs = []
    for tau in (0.0, 5e-7):
        e_tau = e.copy()
        e_tau[E.VB_TAU] = tau
        sim = make_sim(cfg, e_tau)
        s0 = sim.initial_state(0.2)
        rt, rv = np.array([0.0, 100.0]), np.array([0.2, 0.2])
        runs.append(sim.advance(s0, 0.0, 5e-4, 8, 1000, rt, rv).states)
    assert np.array_equal(runs[0], runs[1])


def test_a_contact_switching_every_step_stops_with_an_error_not_a_hang():
    """The integrator without the adapter's guard: a lag of 5e-7 s at a 3 ms step flips the belt every step
    (500 000 switches in one 0.7 s window before the cap); now it stops within a bounded number of switches."""
    cfg = load_rig("belt-ndof")
    sim = make_sim(cfg, environment_vector(cfg))
    e = sim.e.copy()
    e[E.VB_TAU] = 5e-7
    s0 = sim.initial_state(0.2)
    rt, rv = np.array([0.0, 1.0, 1.2, 100.0]), np.array([0.2, 0.2, 0.1, 0.1])
    hs = beltndof.new_hybrid(1, sim.p[beltndof.P.F_S0], 1.0)
    with pytest.raises(RuntimeError, match="chatters"):
        beltndof.simulate(s0, 0.0, 3e-3, 1, 1000, sim.p, e, rt, rv, hs)
