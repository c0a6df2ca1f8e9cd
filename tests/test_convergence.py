"""Convergence as the step (or the smoothing) shrinks: the numbers we publish are not artefacts."""

from __future__ import annotations

import numpy as np

from daq.physics.drum import P as DP
from daq.sim.effectset import effect_vector
from daq.sim.rigs import make_sim


def _run(cfg, dt, duration, rate=1000.0, ramp=None):
    """Integrate the rig's seed configuration with step dt; ramp (t, v) defaults to the seed ramp."""
    e, _ = effect_vector(cfg)
    sim = make_sim(cfg, e)
    rt, rv = ramp if ramp is not None else (np.array([0.0, 45.0]), np.array([cfg.drive.V0_m_per_s, 0.0]))
    n_sub = max(1, int(round(1.0 / rate / dt)))
    s0 = sim.initial_state(float(rv[0]))
    return sim.advance(s0, 0.0, 1.0 / rate / n_sub, n_sub, int(duration * rate) + 1, rt, rv)


def _orders(errors):
    return [errors[i] / errors[i + 1] for i in range(len(errors) - 1)]


def test_brake_rk4_fourth_order_through_stick_slip(brake_cfg):
    """Seed case, first 1.5 s (several creep-slip cycles): velocity error falls ~16x per halving."""
    dts = [5e-4, 2.5e-4, 1.25e-4]
    ref = _run(brake_cfg, 1.5625e-5, 1.5).states[:, 1]
    errs = [np.max(np.abs(_run(brake_cfg, dt, 1.5).states[:, 1] - ref)) for dt in dts]
    assert errs[0] < 1e-3  # the default step is accurate to < 1 mm/s on spikes of ~0.4 m/s
    assert all(r > 10 for r in _orders(errs)), errs


def test_belt_hybrid_fourth_order_with_events(belt_cfg):
    """Paper 000's discontinuous law with located events keeps RK4's order (~16x per halving)."""
    dts = [2e-3, 1e-3, 5e-4]

    def run(dt):
        return _run(belt_cfg, dt, 3.0, rate=250.0, ramp=(np.array([0.0, 10.0]), np.array([0.2, 0.2])))

    ref = run(6.25e-5)
    errs = [np.max(np.abs(run(dt).states[:, 0] - ref.states[:, 0])) for dt in dts]
    assert all(r > 10 for r in _orders(errs)), errs
    # the stick/slip pattern itself is identical at every step size
    modes = [run(dt).extra["modes"][:, 0] for dt in dts]
    assert all(np.array_equal(m, ref.extra["modes"][:, 0]) for m in modes)
    assert ref.extra["modes"][:, 0].mean() > 0.2  # there is real sticking


def test_drum_smoothing_converges_first_order(drum_cfg):
    """sgn regularised as tanh(v/eps): trajectories through v_rel = 0 converge as eps -> 0 (order 1)."""
    e, _ = effect_vector(drum_cfg)
    epss = [4e-4, 2e-4, 1e-4, 5e-5]

    def run(eps):
        sim = make_sim(drum_cfg, e.copy())
        sim.p[DP.EPS] = eps
        dt = min(1e-4, eps / 4)
        n_sub = int(round(1e-3 / dt))
        rt, rv = np.array([0.0, 100.0]), np.array([0.012, 0.012])
        s0 = sim.initial_state(0.012)
        s0[0] = -0.03  # released against the spring: R phi' overtakes the drum, v_rel changes sign
        c = sim.advance(s0, 0.0, 1e-3 / n_sub, n_sub, 3001, rt, rv)
        return c

    ref = run(6.25e-6)
    assert np.sum(np.diff(np.sign(ref.aux[:, 5])) != 0) >= 2  # the run does cross v_rel = 0
    errs = [np.max(np.abs(run(eps).states[:, 0] - ref.states[:, 0])) for eps in epss]
    assert all(1.6 < r < 3.0 for r in _orders(errs)), errs
    assert errs[1] < 2e-4  # the default eps = 0.2 mm/s: < 0.2 mrad against phi swings of 30 mrad
