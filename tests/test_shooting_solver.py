"""The multiple-shooting solver (daq/models/fit/lm.py) on a toy objective, no rig: the joint fit and the per-window fit
reach the least-squares solution of a linear problem with the block structure of multiple shooting; a fork pool
gets its work passed in (daq/models/fit/forked.py). Decision record: docs/decisions/0041-models-core-as-a-solver.md."""

from __future__ import annotations

from functools import partial

import numpy as np

from daq.models.fit import forked, lm

NW, L = 6, 20  # windows, samples per window


def _toy(seed: int = 0):
    """Residuals y(t) = a t + b + v_w - data: two shared parameters, one start value per window."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, L)
    true_v = rng.normal(0.0, 1.0, NW)
    data = 2.0 * t[None, :] - 0.5 + true_v[:, None] + rng.normal(0.0, 0.01, (NW, L))

    def scaled(values, windows, vel, length):
        v = np.zeros(windows.size) if vel is None else vel[:, 0]
        pred = values["a"] * t[None, :] + values["b"] + v[:, None]
        return ((pred - data[windows]) / 0.01)[:, None, :]  # in units of the noise: (n_win, n_out, L)

    return t, data, scaled


def test_the_joint_fit_reaches_the_least_squares_solution_of_a_linear_problem():
    t, data, scaled = _toy()
    windows = np.arange(NW)
    ob = lm.Joint(scaled, {"a": 0.0, "b": 0.0}, ["a", "b"], windows, None, 1, np.ones(NW), "squares",
                  np.array([-10.0, -10.0]), np.array([10.0, 10.0]), np.ones(1), True, False)
    theta, V = np.zeros(2), np.zeros((NW, 1))
    R = ob.resid(theta, V)
    cost, W = ob.loss(R)
    Jg, Jv = ob.jacobian(theta, V, R)
    st = lm.solve(ob, lm.JointState(theta, V, R, cost, W, Jg, Jv), max_iter=50)
    # the same problem stacked: columns a, b (b and the start values are collinear: fix b by the minimum norm)
    X = np.zeros((NW * L, 2 + NW))
    for w in range(NW):
        X[w * L:(w + 1) * L, 0] = t
        X[w * L:(w + 1) * L, 1] = 1.0
        X[w * L:(w + 1) * L, 2 + w] = 1.0
    sol = np.linalg.lstsq(X, data.ravel(), rcond=None)[0]
    assert st.success, st.message
    assert abs(st.theta[0] - sol[0]) < 1e-6  # the slope is identified
    np.testing.assert_allclose(st.theta[1] + st.V[:, 0], sol[1] + sol[2:], atol=1e-6)  # offsets per window
    assert ob.nfev > 0


def test_the_per_window_fit_reaches_each_windows_least_squares_start_value():
    t, data, scaled = _toy(1)
    windows = np.arange(NW)
    ob = lm.Starts(scaled, {"a": 2.0, "b": -0.5}, windows, 1, np.ones(NW), "squares", np.ones(1))
    V = np.zeros((NW, 1))
    R = ob.resid(V, windows)
    cost, W = ob.loss(R, windows)
    st = lm.solve_starts(ob, lm.StartsState(V, R, cost, W, ob.jac(V, windows, R), np.full(NW, lm.START_DAMPING),
                                            1e-4, np.ones(NW, bool), np.zeros(NW, int)), max_iter=25)
    best = np.mean(data - (2.0 * t[None, :] - 0.5), axis=1)
    assert st.success
    np.testing.assert_allclose(st.V[:, 0], best, atol=1e-3)


def _decaying_swing(seed: int = 2):
    """A nonlinear per-window problem: y(t) = exp(-d t) sin(w t + phase_w) amplitude_w, two start values a window."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 4 * L)
    true = np.column_stack([rng.uniform(-0.6, 0.6, NW), rng.uniform(0.8, 1.2, NW)])

    def curve(V):
        return V[:, 1:2] * np.exp(-0.7 * t)[None, :] * np.sin(9.0 * t[None, :] + V[:, 0:1])

    data = curve(true) + rng.normal(0.0, 0.01, (NW, t.size))

    def scaled(values, windows, vel, length):
        return ((curve(vel) - data[windows]) / 0.01)[:, None, :]

    return scaled, true


def test_the_per_window_fit_with_broyden_updates_ends_where_finite_differences_end_for_fewer_simulations():
    """Carried Jacobians (rank-one updates after each accepted step) change the path, not the end: every window is
    judged converged on a fresh finite-difference Jacobian, and that is the one it ends with."""
    scaled, true = _decaying_swing()
    windows = np.arange(NW)
    ends = {}
    for broyden in (False, True):
        ob = lm.Starts(scaled, {}, windows, 1, np.ones(NW), "squares", np.ones(2), broyden)
        V = true + np.array([0.3, -0.15])  # a start that needs several steps
        R = ob.resid(V, windows)
        cost, W = ob.loss(R, windows)
        st = lm.solve_starts(ob, lm.StartsState(V, R, cost, W, ob.jac(V, windows, R), np.full(NW, lm.START_DAMPING),
                                                1e-6, np.ones(NW, bool), np.zeros(NW, int)), max_iter=25)
        assert st.success and st.fresh.all()
        np.testing.assert_allclose(st.J, ob.jac(st.V, windows, st.R), rtol=1e-9, atol=1e-9)
        ends[broyden] = (st.V.copy(), ob.nfev)
    np.testing.assert_allclose(ends[True][0], ends[False][0], atol=1e-4)
    np.testing.assert_allclose(ends[True][0], true, atol=0.02)
    assert ends[True][1] < ends[False][1], ends


def _scaled_sum(offset: float, task: int) -> float:
    return offset + task


def test_a_fork_pool_runs_the_work_it_is_given_and_the_parent_keeps_no_global():
    if not forked.can_fork():
        return
    with forked.pool(2, partial(_scaled_sum, 10.0)) as pool:
        got = sorted(pool.imap_unordered(forked.run, range(4)))
    assert got == [10.0, 11.0, 12.0, 13.0]
    assert forked._WORK is None  # written in the workers only
