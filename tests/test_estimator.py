"""Online friction estimator: inverse dynamics with causal differentiation, regimes, running fit, bus.

How the estimates are compared with the simulator's truth
---------------------------------------------------------
The differentiator is a causal local polynomial (Savitzky-Golay) fit over the last N
samples evaluated ``lag`` = (N-1)/2 samples back, so each estimate refers to the input
sample ``index`` = newest - lag (a pure delay of lag samples: brake 11 ms, drum 2 ms,
belt 28 ms); it is compared with the truth *at that sample*.

"Away from transitions" excludes, from the truth, every sample within lag + 2 samples of
a stick/slip switch (|v_rel| crossing v_stick) or of a jump or kink of the true friction
force (|second difference| > 2 % of max |F| per sample^2: the law's accel-sign branch
switch and its break-away drop on belt-ndof), and the first 0.5 s (start-up). There the
fit window straddles a discontinuity of x'' and the estimate is biased by design; this is
the SPEC's warning, not a defect to tune away.

Tolerances (force, N): rms <= bias_rms + 1.3 sigma_F and p99 <= bias_max + 3.5 sigma_F,
with sigma_F = m_eff * noise_std * g the white-noise floor of the estimate (g = noise gain
of the filter that carries the noise; for the x'' filter g ~ sqrt(720)/(dt^2 N^2.5), i.e.
noise / (dt^2 N^2.5) amplification), and bias_* the noise-free error with ~2.5x margin:

  rig            filter              sigma_F   noise-free rms / max     bias tolerance
  brake-2dof     x'' deg 4, N = 23   0.020 N   0.0012 / 0.0044 N        0.003 / 0.011 N
  drum-pendulum  accel deg 2, N = 5  0.017 N   0.0006 / 0.0020 N        0.002 / 0.005 N
  belt-ndof      x'' deg 2, N = 15   0.019 N   0.034  / 0.137  N        0.06  / 0.20  N

The belt's bias is larger because its 250 Hz tracker sees the paper 000 law's kinks
(end of the break-away drop, w_min) every ~10 samples of a slip; the smooth-law rigs at
1 kHz are accurate to < 0.5 % of their force scale between transitions.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from daq.config import load_rig, rig_path
from daq.estimation.core import EstimatorCfg, FrictionEstimator, estimate_arrays
from daq.estimation.differentiate import noise_gain, sg_coefficients
from daq.estimation.online import OnlineCfg, OnlineEstimator
from daq.estimation.rigmodels import rig_model
from daq.io.stream_format import Block, BusEvent, StreamMeta
from daq.signals import FloatRing
from daq.sim.run import simulate
from daq.streaming.bus import Publisher, Subscriber

# rig -> (bias rms tolerance, bias max tolerance) [N], the channel whose noise dominates, m_eff
BIAS_TOL = {"brake-2dof": (0.003, 0.011), "drum-pendulum": (0.002, 0.005), "belt-ndof": (0.06, 0.20)}
NOISE_PATH = {"brake-2dof": ("x1", "x1''"), "drum-pendulum": ("accel", "accel"), "belt-ndof": ("x1", "x1''")}


def _m_eff(model) -> float:
    from daq.physics import beltndof, brake2dof, drum

    p = model.p
    return {"brake-2dof": lambda: p[brake2dof.P.m], "belt-ndof": lambda: p[beltndof.P.M],
            "drum-pendulum": lambda: p[drum.P.I0] / p[drum.P.R] ** 2}[model.rig_id]()


@pytest.fixture(scope="module")
def cfgs(brake_cfg, drum_cfg, belt_cfg):
    return {"brake-2dof": brake_cfg, "drum-pendulum": drum_cfg, "belt-ndof": belt_cfg}


@pytest.fixture(scope="module")
def runs(cfgs):
    """10 s of each rig at its own rate (belt 250 Hz), with the config's sensor noise and without."""
    return {(rig, noise): simulate(cfg, duration=10.0, noise=noise, seed=5)
            for rig, cfg in cfgs.items() for noise in (False, True)}


def away_mask(truth: dict, idx: np.ndarray, v_stick: float, guard: int) -> tuple[np.ndarray, np.ndarray]:
    """Samples (at the estimates' reference indices) farther than ``guard`` from any transition."""
    f = truth["friction_force"]
    stuck = np.abs(truth["v_rel"]) < v_stick
    ev = np.zeros(f.size, dtype=bool)
    ev[1:] = np.diff(stuck.astype(np.int8)) != 0
    ev[1:-1] |= np.abs(np.diff(f, 2)) > 0.02 * np.abs(f).max()
    pos = np.flatnonzero(ev)
    j = np.searchsorted(pos, idx)
    d = np.minimum(np.abs(idx - pos[np.maximum(j - 1, 0)]), np.abs(pos[np.minimum(j, pos.size - 1)] - idx))
    return d > guard, stuck


# ---------------------------------------------------------------------------- differentiator


@pytest.mark.parametrize("degree,lag", [(2, 7), (4, 7), (2, 0), (4, 3)])
def test_local_polynomial_filter_is_exact_for_polynomials_of_its_degree(degree, lag):
    n, dt = 15, 1e-3
    t = np.arange(n) * dt
    t0 = t[n - 1 - lag]
    c = np.array([0.3, -2.0, 50.0, -800.0, 9000.0])[:degree + 1]
    x = sum(ck * (t - 0.01) ** k for k, ck in enumerate(c))
    for d in range(3):
        want = sum(ck * np.prod(np.arange(k, k - d, -1)) * (t0 - 0.01) ** (k - d)
                   for k, ck in enumerate(c) if k >= d)
        got = sg_coefficients(n, degree, d, lag, dt) @ x
        assert got == pytest.approx(want, rel=1e-6, abs=1e-6)


def test_noise_gain_of_second_derivative_follows_dt2_n2p5():
    """Centred quadratic fit: x'' noise gain = sqrt(720 / (N (N^2-1) (N^2-4))) / dt^2 ~ 27/(dt^2 N^2.5)."""
    for n in (9, 15, 31):
        g = noise_gain(sg_coefficients(n, 2, 2, (n - 1) // 2, 1e-3))
        assert g == pytest.approx(np.sqrt(720.0 / (n * (n * n - 1) * (n * n - 4))) / 1e-6, rel=1e-9)
    # why the default evaluates at the centre: at lag 0 (no delay) the brake's degree-4 x'' filter is 5x noisier
    assert noise_gain(sg_coefficients(23, 4, 2, 0, 1e-3)) > 5.0 * noise_gain(sg_coefficients(23, 4, 2, 11, 1e-3))


# ---------------------------------------------------------------------------- against the truth


@pytest.mark.parametrize("noise", [False, True], ids=["noise-free", "noisy"])
@pytest.mark.parametrize("rig", ["brake-2dof", "drum-pendulum", "belt-ndof"])
def test_friction_matches_truth_away_from_transitions(cfgs, runs, rig, noise):
    """See the module docstring for the exclusion and the tolerances (bias + noise floor)."""
    cfg, rec = cfgs[rig], runs[(rig, noise)]
    r = estimate_arrays(cfg, rec.t, rec.channels)
    est, idx = r.est, r.est.index
    assert r.delay_s == pytest.approx(r.lag / cfg.sensors.rate_Hz)
    assert np.array_equal(est.t, rec.t[idx])  # each estimate is stamped with the sample it refers to
    away, stuck = away_mask(rec.truth, idx, cfg.contact.v_stick_m_per_s, r.lag + 2)
    away &= est.t > 0.5
    assert away.mean() > 0.3 and (away & ~stuck[idx]).sum() > 50  # slips are tested, not only sticks

    fe = FrictionEstimator(rig_model(cfg), cfg.sensors.rate_Hz)
    ch, key = NOISE_PATH[rig]
    sigma = _m_eff(fe.model) * cfg.channels[ch].noise_std * fe.gains[key] if noise else 0.0
    bias_rms, bias_max = BIAS_TOL[rig]
    err = (est.F - rec.truth["friction_force"][idx])[away]
    rms, p99 = float(np.sqrt(np.mean(err**2))), float(np.percentile(np.abs(err), 99))
    assert rms <= bias_rms + 1.3 * sigma, (rms, sigma)
    assert p99 <= bias_max + 3.5 * sigma, (p99, sigma)
    if not noise:
        assert np.abs(err).max() <= bias_max
    # mu = F / N with N from the same physics (eq. 6 / thrust gauge / F0)
    n_err = (est.N - rec.truth["normal_load"][idx])[away]
    assert np.sqrt(np.mean(n_err**2)) <= 0.01 * np.abs(rec.truth["normal_load"]).mean()

    # regime: slip iff |v_rel| > v_stick (with hysteresis) agrees with the truth away from switches
    agree = (est.slip == ~stuck[idx])[away].mean()
    assert agree > 0.95, agree


def test_blocks_of_any_size_give_the_same_estimates(brake_cfg, runs):
    rec = runs[("brake-2dof", True)]
    whole = estimate_arrays(brake_cfg, rec.t, rec.channels).est
    pieces = estimate_arrays(brake_cfg, rec.t, rec.channels, block=37).est
    assert np.array_equal(whole.index, pieces.index)
    for k in ("F", "N", "mu", "v_rel", "slip", "growing"):
        np.testing.assert_array_equal(getattr(whole, k), getattr(pieces, k))


def test_a_time_gap_restarts_the_window(brake_cfg, runs):
    """Lost blocks leave a hole in t: no estimate may use samples from both sides of it."""
    rec = runs[("brake-2dof", False)]
    keep = np.r_[0:3000, 3050:rec.t.size]
    fe = FrictionEstimator(rig_model(brake_cfg), 1000.0)
    x = np.stack([rec.channels[c] for c in fe.inputs])
    est = fe.process(rec.t[keep], x[:, keep])
    assert fe.resets == 1
    fresh = FrictionEstimator(rig_model(brake_cfg), 1000.0).process(rec.t[3050:], x[:, 3050:])
    after = est.t > rec.t[3049]
    np.testing.assert_allclose(est.F[after], fresh.F, rtol=0, atol=1e-12)
    assert est.size == keep.size - 2 * (fe.n_taps - 1)


# ---------------------------------------------------------------------------- running fit


def test_running_fit_recovers_mu0_from_noise_free_data(brake_cfg, runs):
    """mu0 within 1 % (0.005) and gamma within 3 % from a 10 s noise-free window.

    The residual bias (~0.2 %) comes from the differentiator's bias in slip; alpha and beta
    are held (they shape |v_rel| < 2/alpha = v_stick, where the fit takes no samples).
    With the rig's sensor noise mu0 stays within 3 % and its standard error is reported.
    """
    rec = runs[("brake-2dof", False)]
    r = estimate_arrays(brake_cfg, rec.t, rec.channels, block=100, fit=True)
    assert len(r.fits) >= 9  # one per second of data, plus the final window
    fit = r.fits[-1]
    assert fit.success and fit.free == ["mu0", "gamma"] and fit.n_points > 1000
    assert abs(fit.params["mu0"] - brake_cfg.friction.mu0) <= 0.005
    assert abs(fit.params["gamma"] / brake_cfg.friction.gamma_s_per_m - 1.0) <= 0.03
    assert 0.0 < fit.stderr["mu0"] < 0.005

    noisy = runs[("brake-2dof", True)]
    fit_n = estimate_arrays(brake_cfg, noisy.t, noisy.channels, fit=True).fits[-1]
    assert abs(fit_n.params["mu0"] - brake_cfg.friction.mu0) <= 0.015
    assert fit_n.stderr["mu0"] < 0.01


def test_fit_frees_only_known_parameters(brake_cfg):
    with pytest.raises(ValueError, match="not parameters"):
        FrictionEstimator(rig_model(brake_cfg), 1000.0, EstimatorCfg(fit_free=("mu0", "nope")))


# ---------------------------------------------------------------------------- on the bus


def _wait_for(cond, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return False


def test_end_to_end_over_zeromq(brake_cfg, runs):
    """Publisher (laser 1 kHz + motor 200 Hz streams) -> OnlineEstimator -> Subscriber.

    The estimates arrive with their latency bookkeeping, equal the offline algorithm's
    (the 200 Hz belt speed is aligned by sample-and-hold), and a law fit arrives from the
    worker process.
    """
    rec = runs[("brake-2dof", True)]
    n = 3001  # 3 s: fits are due at 1 s and 2 s of data
    pub = Publisher("tcp://127.0.0.1:0")
    est = OnlineEstimator(brake_cfg, OnlineCfg(sub_endpoint=pub.endpoint, fit="process"))
    sink = Subscriber(est.endpoint, streams=["estimator", "friction_fit"], name="test-sink")
    try:
        est.warm_up()
        est.start()
        probe = StreamMeta(stream="probe", channels=("z",), units=("-",))
        assert _wait_for(lambda: pub.publish(probe, np.zeros(1), np.zeros(1)) and
                         "probe" in est.sub.stats.streams, 10.0), "estimator never subscribed"
        time.sleep(0.2)  # the sink's subscription to the estimator
        laser = StreamMeta(stream="laser", channels=("x1", "phi"), units=("m", "rad"), rig=brake_cfg.rig,
                           rate_hz=1000.0)
        motor = StreamMeta(stream="motor", channels=("vb", "vb_set"), units=("m/s", "m/s"), rate_hz=200.0)
        base = time.monotonic()
        for i in range(0, n, 50):
            sl = slice(i, min(i + 50, n))
            pub.publish(laser, base + rec.t[sl], np.column_stack([rec.channels["x1"][sl], rec.channels["phi"][sl]]))
            j = np.arange(sl.start, sl.stop)[::5]  # the regulator's 200 Hz updates
            pub.publish(motor, base + rec.t[j], np.column_stack([rec.channels["vb"][j], rec.channels["vb_set"][j]]))
            time.sleep(0.001)
        blocks, events, fits = [], [], []
        end = time.monotonic() + 30.0
        while time.monotonic() < end and not (sum(b.header.n for b in blocks) >= n - 22 and fits):
            m = sink.recv(0.1)
            if isinstance(m, Block):
                (blocks if m.meta.stream == "estimator" else fits).append(m)
            elif isinstance(m, BusEvent):
                events.append(m)
    finally:
        est.close()
        sink.close()
        pub.close()

    assert est.stats.lost_blocks == 0 and sink.stats.lost_blocks == 0
    assert blocks, "no estimates arrived"
    t = np.concatenate([b.t for b in blocks]) - base
    f = np.concatenate([b.column("F_est") for b in blocks])
    lat = np.concatenate([b.column("latency") for b in blocks])
    assert np.all(np.isfinite(lat)) and lat.min() >= 0.0 and np.percentile(lat, 50) < 0.5
    assert blocks[0].meta.channels[:7] == ("F_est", "N_est", "mu_est", "v_rel", "slip", "growing", "latency")
    offline = estimate_arrays(brake_cfg, rec.t[:n], {k: v[:n] for k, v in rec.channels.items()}).est
    assert f.size == offline.size
    np.testing.assert_allclose(t, offline.t, atol=1e-9)
    np.testing.assert_allclose(f, offline.F, rtol=0, atol=1e-9)

    started = [e for e in events if e.kind == "estimator_started"]
    assert started and json.loads(started[0].detail)["delay_s"] == pytest.approx(0.011)
    assert fits, "no law fit arrived"
    row = dict(zip(fits[-1].meta.channels, fits[-1].data[0]))
    assert abs(row["mu0"] - brake_cfg.friction.mu0) < 0.05 and row["mu0_se"] > 0
    assert any(e.kind == "friction_fit" for e in events)


@pytest.mark.slow
def test_bench_estimator_reports_its_figures_beside_the_baseline():
    """A 1 s run of `daq bench estimator` (the figures themselves are the benchmark's job, not asserted)."""
    from daq.bench.estimator import bench_estimator, format_estimator

    r = bench_estimator(1.0)
    for key in ("latency_p99_ms", "keeps_up", "baseline_latency_p99_ms", "samples_per_s", "latency_p50_ms"):
        assert key in r
    assert isinstance(r["keeps_up"], bool)
    assert r["blocks_processed"] == r["blocks_sent"] == 100 and r["lost_blocks"] == 0
    assert r["estimates_received"] == r["estimates"] > 9000
    assert np.isfinite(r["latency_p99_ms"]) and np.isfinite(r["baseline_latency_p99_ms"])
    json.dumps(r)
    assert "baseline" in format_estimator(r)


def test_a_spring_slider_driven_at_a_changing_speed_is_estimated_in_the_drivers_frame(tmp_path):
    """driven = "spring": the chain's far end moves at v_b and the track is fixed, so every mass feels + M v_b' in
    the driver's frame (decision 24). A drive speed swinging 0.1-0.3 m/s at 0.5 Hz gives M v_b' up to 0.16 N; the
    estimate leaves it out only at the belt bias tolerance (before: the whole of it was read as friction)."""
    text = rig_path("belt-ndof").read_text()
    assert 'driven = "belt"' in text
    path = tmp_path / "spring-driven.toml"
    path.write_text(text.replace('driven = "belt"', 'driven = "spring"', 1))
    cfg = load_rig(path)
    t = np.linspace(0.0, 11.0, 2201)
    ramp = (t, 0.2 + 0.1 * np.sin(2 * np.pi * 0.5 * t))
    rec = simulate(cfg, ramp=ramp, duration=10.0, noise=False, seed=5)
    r = estimate_arrays(cfg, rec.t, rec.channels)
    est, idx = r.est, r.est.index
    away, stuck = away_mask(rec.truth, idx, cfg.contact.v_stick_m_per_s, r.lag + 2)
    away &= est.t > 0.5
    frame = cfg.mechanics.mass_kg * np.gradient(rec.channels["vb"], rec.t)[idx]
    assert np.abs(frame[away]).max() > 0.1  # the frame's push is there to be missed
    err = (est.F - rec.truth["friction_force"][idx])[away]
    assert np.sqrt(np.mean(err**2)) <= BIAS_TOL["belt-ndof"][0], float(np.sqrt(np.mean(err**2)))


def test_the_estimators_logs_keep_their_bound_oldest_first_and_are_resident_from_the_start():
    """FloatRing (the estimator's latency and work logs): the last `keep` values, oldest first, in memory taken
    at once (a deque of a million floats grew 0.51 MB/min through a 30-minute soak, issue 29)."""
    ring = FloatRing(5)
    assert len(ring) == 0 and list(ring) == []
    for x in range(3):
        ring.append(float(x))
    assert list(ring) == [0.0, 1.0, 2.0]
    for x in range(3, 12):
        ring.append(float(x))
    assert len(ring) == 5 and list(ring) == [7.0, 8.0, 9.0, 10.0, 11.0]
    assert ring.values().tolist() == [7.0, 8.0, 9.0, 10.0, 11.0]
    big = FloatRing(1_000_000)
    assert big._ring.nbytes == 8_000_000 and np.isnan(big._ring).all()  # written through: resident now
