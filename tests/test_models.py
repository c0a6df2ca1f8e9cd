"""Model files, multiple-shooting fits, the noise floor and user effects (issue 5)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import expect_error, write
from scipy.optimize import lsq_linear

from daq.config import load_rig
from daq.errors import InputError
from daq.models.fit.lm import bounded_step
from daq.models.fit.session import Session
from daq.models.spec import add_effect, dumps, load_model, remove_effect, save_model, seed_model
from daq.sim.effectset import parse_effect
from daq.sim.run import simulate

# ----------------------------------------------------------------------------- model files


def test_seed_model_of_brake_is_paper_001_with_its_three_effects(tmp_path):
    m = seed_model("brake-2dof")
    assert set(m.effects) == {"normal-load", "geometric", "viscous-damping"}
    assert m.friction["mu0"].value == 0.5 and m.friction["mu0"].free
    assert m.effects["normal-load"].params["weight"].value == 1.0
    assert not m.effects["normal-load"].params["weight"].free  # structural, not a fit knob
    save_model(m, tmp_path / "m.toml")
    back = load_model(tmp_path / "m.toml")
    assert back.params() == m.params() and back.effects.keys() == m.effects.keys()
    assert "mu0 = { value = 0.5, free = true" in (tmp_path / "m.toml").read_text()


def test_add_and_remove_effects_round_trip(tmp_path):
    m = seed_model("drum-pendulum")
    m2 = add_effect(m, "bearing-friction")
    assert m2.effects["bearing-friction"].params["mu1"].free
    assert "bearing-friction" not in m.effects  # the original is not changed
    m3 = remove_effect(m2, "bearing-friction")
    assert dumps(m3) == dumps(m)
    with pytest.raises(InputError) as e:
        add_effect(m2, "bearing-friction")
    assert "already" in e.value.message
    with pytest.raises(InputError) as e:
        add_effect(m, "geometric")  # brake-only
    assert "does not apply to drum-pendulum" in e.value.message
    with pytest.raises(InputError) as e:
        remove_effect(m, "stick-time")
    assert e.value.field == "stick-time"


@pytest.mark.parametrize("text, field, fragment", [
    ('law = "brake-eq7"\n', "rig", "required"),
    ('rig = "brake-2dof"\nlaw = "drum-eq3"\n', "law", "has law 'brake-eq7'"),
    ('rig = "brake-2dof"\nlaw = "brake-eq7"\ncolour = 1\n', "colour", "unknown key"),
    ('rig = "brake-2dof"\nlaw = "brake-eq7"\n[friction]\nmu0 = { value = 0.5, lo = 1.0, hi = 0.1 }\n',
     "friction.mu0", "must be below"),
    ('rig = "brake-2dof"\nlaw = "brake-eq7"\n[friction]\nmu0 = { value = 3.0, lo = 0.0, hi = 1.0 }\n',
     "friction.mu0", "outside"),
    ('rig = "brake-2dof"\nlaw = "brake-eq7"\n[friction]\nmu0 = "half"\n', "friction.mu0", "expected a number"),
    ('rig = "brake-2dof"\nlaw = "brake-eq7"\n[friction]\nkappa = 1.0\n', "friction.kappa", "not a numeric"),
    ('rig = "brake-2dof"\nlaw = "brake-eq7"\n[effects.wear]\nk = 1.0\n', "effects.wear", "unknown effect"),
    ('rig = "brake-2dof"\nlaw = "brake-eq7"\n[effects.stick-time]\nspeed = 1.0\n', "effects.stick-time.speed",
     "unknown parameter"),
    ('rig = "brake-2dof"\nlaw = "brake-eq7"\n[friction\n', "(syntax)", ""),
])
def test_bad_model_files_name_the_file_and_field(tmp_path, text, field, fragment):
    path = write(tmp_path, "bad.toml", text)
    with pytest.raises(InputError) as e:
        load_model(path)
    expect_error(e.value, str(path), field, fragment)


# ----------------------------------------------------------------------------- fitting


@pytest.fixture(scope="module")
def brake_clean():
    cfg = load_rig("brake-2dof")
    return cfg, simulate(cfg, rate=1000.0, seed=2, duration=12.0, noise=False)


def test_true_model_reproduces_noise_free_data_to_the_sensor_resolution(brake_clean):
    """Windows simulated from states estimated from the data follow it to ~ the 1 um quantisation."""
    cfg, rec = brake_clean
    s = Session(rec, "sim", cfg, max_windows=30)
    model = seed_model("brake-2dof")
    pr = s.problem(model)
    w = s.win.select(None)
    vel = pr.fit_starts(pr.builder.base_values, w, max_iter=6)
    err = np.sqrt(np.mean(pr.window_errors(pr.builder.base_values, w, vel.start_values)["x1"]))
    assert err < 1.5e-6  # lsb 1 um; the x1 amplitude is ~5 mm


def test_at_100_hz_free_start_positions_bring_a_perfect_model_to_the_sensor_noise(brake_cfg, monkeypatch):
    """The true model on noisy 100 Hz data: with the start positions estimated from each window
    (start sample included) its error is about sigma (0.92-1.01 sigma over seeds 3-6); started from
    the raw sample 1.11-1.18 sigma, an offset that buried stick-time's trace at 100 Hz."""
    import daq.models.fit.data as data
    from daq.sim.run import simulate

    rec = simulate(brake_cfg, rate=100.0, seed=3, duration=20.0)
    errs = {}
    for label, limit in (("free", data.FREE_POSITIONS_BELOW_HZ), ("raw sample", 0.0)):
        monkeypatch.setattr(data, "FREE_POSITIONS_BELOW_HZ", limit)
        s = Session(rec, "sim", brake_cfg, max_windows=40)
        pr = s.problem(seed_model("brake-2dof"))
        w = s.win.select(None)
        fit = pr.fit_starts(pr.builder.base_values, w, max_iter=25)
        errs[label] = np.sqrt(np.mean(pr.window_errors(pr.builder.base_values, w, fit.start_values)["x1"]))
        assert len(pr.slots) == (4 if label == "free" else 2)
    sigma = s.m.sigma["x1"]
    assert errs["free"] < 1.05 * sigma, (errs, sigma)
    assert errs["raw sample"] > 1.1 * errs["free"], (errs, sigma)


def test_fit_recovers_law_parameters_started_off_target(brake_clean):
    cfg, rec = brake_clean
    s = Session(rec, "sim", cfg, max_windows=30)
    m = seed_model("brake-2dof")
    m.friction["mu0"].value = 0.42
    m.friction["beta"].value = 0.55
    f = s.fit(m)
    assert f.values["friction.mu0"] == pytest.approx(0.5, abs=2e-3)
    assert f.values["friction.beta"] == pytest.approx(0.7, abs=1e-2)
    assert f.fit.std["friction.mu0"] > 0
    assert f.rms("x1") < 2e-6


def test_a_held_out_window_keeps_the_better_of_its_two_start_fits(brake_cfg):
    """Session.held_out with ``also`` (start values a nearby model's fit ended at): each window's start fitted from
    the data's estimate and from there, the lower loss kept; no window worse than either start alone. Off target
    (mu0 0.40, beta 0.5) the data's start leaves a window of ten in a poorer basin than a start from elsewhere."""
    rec = simulate(brake_cfg, rate=100.0, seed=3, duration=20.0)
    s = Session(rec, "sim", brake_cfg, max_windows=30, loss="squares")
    pr = s.problem(seed_model("brake-2dof"))
    v = {**pr.builder.base_values, "friction.mu0": 0.40, "friction.beta": 0.5}
    hw = s.win.select(True)
    data, ms_data = s.held_out(pr, v)
    other, ms_other = s.held_out(pr, v, near=-data.start_values)  # from elsewhere: another basin in places
    both, ms_both = s.held_out(pr, v, also=other.start_values)
    costs = [pr.window_costs(v, hw, f.start_values) for f in (data, other, both)]
    assert np.all(costs[2] <= np.minimum(costs[0], costs[1]) * (1 + 1e-6)), costs
    assert np.any(ms_other["x1"] < 0.8 * ms_data["x1"])  # the case exists (else this test shows nothing)
    assert np.any(ms_both["x1"] < 0.8 * ms_data["x1"])  # ...and the better start is kept there


def test_noise_floor_matches_the_sensor_noise(brake_cfg):
    """On noisy data from the true model, the error is at the floor and the floor is ~ the noise sigma."""
    rec = simulate(brake_cfg, rate=1000.0, seed=4, duration=12.0)
    s = Session(rec, "sim", brake_cfg, max_windows=30)
    f = s.fit(seed_model("brake-2dof"))
    floor = s.noise_floor(f)["x1"]
    sigma = (5e-6**2 + 1e-6**2 / 12) ** 0.5
    assert 0.9 * sigma < floor < 1.3 * sigma
    # 30 windows of 0.2 s: the error of one realisation scatters by ~10 % around the floor
    assert abs(f.rms("x1", "all") - floor) < 0.2 * floor


@pytest.mark.slow
def test_user_effect_from_a_file_explains_a_hidden_temperature_effect(tmp_path, brake_cfg):
    """A user's own effect file (not in the package) is fitted like a catalog effect."""
    path = write(tmp_path, "my_temp.py", (
        "from daq.models.user_effects import UserParam\n"
        "PARAMS = {'c': UserParam(start=0.0, lo=-0.1, hi=0.1, unit='1/K')}\n"
        "def mu_factor(v_rel, t, temp, travel, stick_clock, p0, p1, p2, p3):\n"
        "    return 1.0 + p0 * (temp - 22.0)\n"))
    rec = simulate(brake_cfg, effects=[parse_effect("temperature:coef=-0.02")], rate=1000.0, seed=3, duration=10.0)
    s = Session(rec, "sim", brake_cfg, max_windows=24)
    m = seed_model("brake-2dof")
    base = s.fit(m)
    m2 = add_effect(m, "my_temp", path=str(path))
    save_model(m2, tmp_path / "m2.toml")
    m2 = load_model(tmp_path / "m2.toml")
    f = s.fit(m2)
    assert f.values["effects.my_temp.c"] == pytest.approx(-0.02, abs=1e-3)
    assert f.rms("x1") < 0.2 * base.rms("x1")


def test_bad_user_effect_files_are_one_line_errors(tmp_path):
    m = seed_model("brake-2dof")
    p = write(tmp_path, "bad1.py", "PARAMS = {}\n")
    with pytest.raises(InputError) as e:
        add_effect(m, "bad1", path=str(p))
    expect_error(e.value, str(p), "mu_factor", "missing")
    p = write(tmp_path, "bad2.py", (
        "from daq.models.user_effects import UserParam\nPARAMS = {'a': UserParam()}\n"
        "def mu_factor(v_rel, t, temp, travel, stick_clock, p0, p1, p2, p3):\n    return {'x': 1}[v_rel]\n"))
    with pytest.raises(InputError) as e:
        add_effect(m, "bad2", path=str(p))
    expect_error(e.value, str(p), "mu_factor", "numba")
    p = write(tmp_path, "bad3.py", "import nonexistent_module_xyz\n")
    with pytest.raises(InputError) as e:
        add_effect(m, "bad3", path=str(p))
    expect_error(e.value, str(p), "(import)", "nonexistent_module_xyz")


def test_bounded_step_leaves_a_held_parameter_out_and_reaches_the_constrained_optimum():
    """A quadratic with two coupled parameters, the first held at its upper bound 0 by the data's pull: the
    active-set step solves for the other with it fixed (exact: scipy's bounded least squares agrees); the
    full step clipped afterwards leaves the other where the unbounded optimum wanted it (a higher cost)."""
    J = np.array([[1.0, 1.0], [1.0, 1.1], [0.0, 0.2], [0.3, 0.0]])
    b = np.array([2.0, 2.3, 0.1, 1.0])
    lo, hi = np.array([-np.inf, -np.inf]), np.array([0.0, np.inf])
    x = np.zeros(2)
    S, rhs = J.T @ J, -J.T @ (J @ x - b)
    unbounded = np.linalg.solve(S, rhs)
    assert unbounded[0] > 0  # the data pull the first parameter past its bound
    active = x + bounded_step(S, rhs, x, lo, hi)
    clipped = np.clip(x + unbounded, lo, hi)
    best = lsq_linear(J, b, bounds=(lo, hi)).x
    np.testing.assert_allclose(active, best, atol=1e-9)

    def cost(v):
        return 0.5 * float(np.sum((J @ v - b) ** 2))

    assert cost(active) < 0.9 * cost(clipped)
    # away from the bound nothing changes: the plain Gauss-Newton step
    x2 = np.array([-1.0, 0.0])
    rhs2 = -J.T @ (J @ x2 - b)
    np.testing.assert_allclose(bounded_step(S, rhs2, x2, lo, hi), np.linalg.solve(S, rhs2))


@pytest.mark.slow
def test_a_models_own_fit_goes_on_past_its_iteration_limit_while_it_converges(brake_cfg):
    """What compare reports and diagnose judges against is a converged fit: stopped at its limit while the cost
    still falls, the fit goes on (up to CONVERGE_ITER in all) and ends lower; a candidate's fit (warm) does not."""
    rec = simulate(brake_cfg, effects=[parse_effect("accel-sign")], rate=1000.0, seed=4, duration=12.0)
    s = Session(rec, "sim", brake_cfg, max_windows=30)
    m = add_effect(seed_model("brake-2dof"), "accel-sign")
    short = s.fit(m, max_iter=3, converge=False)
    assert not short.fit.success and short.fit.message.startswith("iteration limit")
    full = s.fit(m, max_iter=3)  # a model's own fit: converge by default
    assert "after 3 iterations" in full.fit.message
    # (seen: 4405 against 4649 before the chain's refit from the file's values, decision 22, which gives the short fit
    # a second 3-iteration run of its own: 4405 against 4406 now; the converged one is never higher, and converged;
    # since the Huber stage (decision 26) both end at the same point, 4403.2867, within 6e-8 of each other: a stage
    # stops when a step gains < 1e-4 of the cost, so 1e-6 is still far inside what "not higher" can resolve)
    assert full.fit.success and full.fit.cost <= short.fit.cost * (1 + 1e-6)
    assert full.values["effects.accel-sign.amp"] == pytest.approx(0.15, abs=0.02)
