"""The margins' bootstrap (daq/models/diagnosis/margins.py): what it must do whatever the data, derived by hand."""

from __future__ import annotations

import numpy as np
import pytest

from daq.models.candidates import Candidate
from daq.models.diagnosis.margins import LEVEL, Margin, margin, resamples
from daq.models.diagnosis.verdict import Verdict


def test_a_model_against_itself_has_no_margin_and_is_not_decided():
    ms = np.random.default_rng(1).gamma(2.0, 1.0, 30)
    m = margin("A", "A again", ms, ms.copy(), excess=1.0, cap=np.inf)
    assert m.share == 0.0 and m.lower == 0.0 and m.upper == 0.0 and not m.decided
    assert m.rival_wins == 1.0  # ties count for the rival: a named effect must do better, not as well


def test_margins_are_antisymmetric_and_in_shares_of_the_excess():
    rng = np.random.default_rng(2)
    a, b = rng.gamma(2.0, 1.0, 40), rng.gamma(2.0, 1.5, 40)
    ab, ba = margin("a", "b", a, b, excess=2.0, cap=np.inf), margin("b", "a", b, a, excess=2.0, cap=np.inf)
    assert ab.share == pytest.approx(-ba.share, abs=1e-15)
    assert ab.lower == pytest.approx(-ba.upper, abs=1e-12) and ab.upper == pytest.approx(-ba.lower, abs=1e-12)
    assert ab.share == pytest.approx((np.sqrt(b.mean()) - np.sqrt(a.mean())) / 2.0)
    assert margin("a", "b", a, b, excess=4.0, cap=np.inf).share == pytest.approx(ab.share / 2.0)


def test_a_consistent_improvement_is_decided_a_noisy_one_is_not():
    rng = np.random.default_rng(3)
    base = rng.gamma(4.0, 1.0, 27)
    better = base * 0.5  # every window halves its error
    assert margin("x", "nothing", better, base, excess=1.0, cap=np.inf).decided
    noisy = base * rng.choice([0.4, 1.7], 27)  # as many windows worse as better, no net gain
    m = margin("x", "nothing", noisy, base, excess=1.0, cap=np.inf)
    assert not m.decided and m.lower < 0.0 < m.upper


def test_one_window_cannot_decide_when_capped():
    base = np.ones(30)
    one = base.copy()
    one[0] = 1e6  # the rival fails one window catastrophically, equals the named model elsewhere
    assert margin("x", "rival", base, one, excess=1.0, cap=np.inf).share > 100
    capped = margin("x", "rival", base, one, excess=1.0, cap=25.0)
    assert capped.share < 1.0 and not capped.decided  # one window in 30, capped at 25: within the bootstrap spread


def test_the_bootstrap_is_fixed_by_the_data_alone():
    idx = resamples(12)
    assert np.array_equal(idx[0], np.arange(12)) and np.array_equal(idx, resamples(12))
    rng = np.random.default_rng(4)
    a, b = rng.gamma(2.0, 1.0, 20), rng.gamma(2.0, 1.2, 20)
    assert margin("a", "b", a, b, 1.0, np.inf) == margin("a", "b", a.copy(), b.copy(), 1.0, np.inf)
    assert 0.0 < LEVEL < 0.5


def test_a_named_effect_whose_form_is_open_says_which_run_tells_the_forms_apart():
    """A verdict on rate-and-state whose aging/slip margin straddles zero reports the form as open and names the
    run that separates the forms (velocity steps up and down, holds over decades); a decided form, or an effect
    with one form, names none."""
    over_nothing = Margin("rate-and-state (aging)", "nothing more", 0.9, 0.7, 1.0, 0.0)
    open_form = Margin("rate-and-state (aging)", "rate-and-state (slip)", 0.02, -0.05, 0.08, 0.3)
    v = Verdict(Candidate("effect", "rate-and-state", "aging"), [over_nothing], [open_form]).as_json()
    assert v["decided"] and not v["form_decided"]
    assert "velocity steps up and down" in v["forms_told_apart_by"] and "holds" in v["forms_told_apart_by"]
    decided = Margin("rate-and-state (aging)", "rate-and-state (slip)", 0.2, 0.1, 0.3, 0.0)
    v = Verdict(Candidate("effect", "rate-and-state", "aging"), [over_nothing], [decided]).as_json()
    assert v["form_decided"]
    # a consistent but tiny preference over a rival form that itself reaches the noise floor decides nothing
    at_floor = Margin("rate-and-state (aging)", "rate-and-state (slip)", 0.003, 0.001, 0.005, 0.0, rival_at_floor=True)
    v = Verdict(Candidate("effect", "rate-and-state", "aging"), [over_nothing], [at_floor]).as_json()
    assert not v["form_decided"] and v["forms"][0]["rival_at_floor"] and v["forms_told_apart_by"]
    one_form = Verdict(Candidate("effect", "normal-load"), [over_nothing]).as_json()
    assert one_form["form_decided"] and one_form["forms_told_apart_by"] == ""
