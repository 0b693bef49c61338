from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import objective


def test_score_is_equation_one_in_expectation():
    u = objective.SCORE.utility(np.array([0.5, 0.5, 1.0, 0.0]))
    assert u.tolist() == [0.0, 0.5, 3.0, -1.0]


def test_target_is_minus_squared_distance_and_coefficients_agree():
    o = objective.parse("target:0.75")
    assert str(o) == "target-p:0.75" and o == objective.parse("target-p:0.75")  # the old name is an alias
    p = np.array([[0.75, 0.5, 1.0, 0.0]])
    assert o.utility(p)[0].tolist() == pytest.approx([0.0, -0.0625, -0.0625, -0.5625])
    for obj in (o, objective.SCORE):
        cf = obj.coefficients(4)
        assert np.allclose(cf[:, 0] + cf[:, 1] * p + cf[:, 2] * p ** 2, obj.utility(p))


@pytest.mark.parametrize("bad", ["target:1.5", "target:x", "loss", "target:0"])
def test_bad_objectives_name_the_text(bad):
    with pytest.raises(ValueError, match="target|objective"):
        objective.parse(bad)


def test_defaults():
    assert objective.parse(None) is objective.SCORE
    assert objective.parse("target").rate == 0.75


def test_target_rate_scores_the_session_rate_with_its_binomial_variance():
    o = objective.parse("target-rate:0.75")
    assert str(o) == "target-rate:0.75" and o.per_session and o.is_target
    assert o.terminal(4).tolist() == pytest.approx([-4 * (s / 4 - 0.75) ** 2 for s in range(5)])
    assert not o.coefficients(4).any()
    p = np.array([0.9, 0.75, 0.5, 0.1])
    # always level l: E[-H (S/H - R)^2] = -H (p - R)^2 - p (1 - p), against the binomial sum
    from scipy.stats import binom
    want = [sum(binom.pmf(s, 25, q) * -25 * (s / 25 - 0.75) ** 2 for s in range(26)) for q in p]
    assert o.fixed_value(p, 25) == pytest.approx(want)
    assert objective.parse("target-p:0.75").fixed_value(p, 25) == pytest.approx(-25 * (p - 0.75) ** 2)


def test_an_n_down_one_up_staircase_reaches_levitts_rate_on_a_fine_ladder():
    from scipy.stats import norm
    from nao_trainer.experiments import adaptive

    p = norm.sf(np.linspace(-3, 3, 120))  # 120 small steps of difficulty
    for need, levitt in ((2, 0.5 ** 0.5), (3, 0.5 ** (1 / 3))):  # 70.7 %, 79.4 % (Levitt 1971)
        start = int(np.argmin(abs(p ** need - 0.5))) + 1
        r = adaptive.staircase_exact(need, start, p, 300, objective.parse(f"target-rate:{levitt:.3f}"))
        assert r["success"] == pytest.approx(levitt, abs=0.003)


def test_the_planner_under_target_rate_is_exact_on_a_known_user():
    """A point-mass prior: the Bayes plan must equal the (turn, successes) dynamic programme of the
    known-rate oracle, and its forward evaluation must give the same value."""
    from nao_trainer.core import bayes
    from nao_trainer.experiments.ceiling import rate_oracle

    o = objective.parse("target-rate:0.7")
    p = np.array([[0.95, 0.8, 0.6, 0.3]])
    turns = 8
    plan = bayes.solve(p, np.ones(1), o.coefficients(4), turns, terminal=o.terminal(turns))
    value, visits, rate, var = rate_oracle(p[0], o, turns)
    assert plan.value == pytest.approx(value)
    ev = bayes.evaluate_plan(plan, p)
    assert ev.session[0] == pytest.approx(value)
    assert o.from_moments(ev.visits[0], p[0], ev.successes[0] / turns, ev.successes_var[0] / turns ** 2, turns) \
        == pytest.approx(value)
    # better than any fixed level (it steers the count), and two models: V(0) = mean of the users' values
    assert value > o.fixed_value(p[0], turns).max() + 1e-6
    two = np.array([[0.95, 0.8, 0.6, 0.3], [0.9, 0.5, 0.3, 0.1]])
    plan2 = bayes.solve(two, np.ones(2), o.coefficients(4), turns, terminal=o.terminal(turns))
    assert plan2.value == pytest.approx(bayes.evaluate_plan(plan2, two).session.mean())


def test_a_cached_target_rate_plan_is_checked_and_reloaded(tmp_path):
    """The cache re-checks a stored table against its inputs (``core.bayes.plan_problem``): a
    target-rate table must pass that check with its terminal value, and load as the same plan."""
    from nao_trainer.core import bayes
    from nao_trainer.learn.bayes_cache import solve_cached

    o = objective.parse("target-rate:0.75")
    p = np.array([[0.95, 0.8, 0.6, 0.3], [0.9, 0.5, 0.3, 0.1]])
    first = solve_cached(p, np.ones(2), o.coefficients(4), 6, 0, tmp_path, terminal=o.terminal(6))
    assert bayes.plan_problem(first) is None
    again = solve_cached(p, np.ones(2), o.coefficients(4), 6, 0, tmp_path, terminal=o.terminal(6))
    assert np.array_equal(first.action, again.action) and again.value == first.value
    other = solve_cached(p, np.ones(2), objective.parse("target-p:0.75").coefficients(4), 6, 0, tmp_path)
    assert other.fingerprint != first.fingerprint
