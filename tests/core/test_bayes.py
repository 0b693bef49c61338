"""The exact Bayes-adaptive planner: against a brute force over histories, a hand-computed case,
and its forward evaluation on the users of its own prior."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import bayes, objective

pytestmark = pytest.mark.skipif(not bayes.available(), reason="the planner needs numba")


def brute_force(p, prior, util, horizon, commit=0):
    """Bayes value by expectimax over full outcome histories (no count compression)."""
    p, prior, util = np.asarray(p, float), np.asarray(prior, float), np.asarray(util, float)

    def value(weights, left):
        w = weights / weights.sum()
        u = w @ util
        if left == 0:
            return commit * u.max()
        best = -np.inf
        for lv in range(p.shape[1]):
            q = u[lv]
            for outcome in (1, 0):
                lik = p[:, lv] if outcome else 1.0 - p[:, lv]
                new = weights * lik
                if new.sum() > 0:
                    q += (new.sum() / weights.sum()) * value(new, left - 1)
            best = max(best, q)
        return best

    return value(prior.copy(), horizon)


@pytest.mark.parametrize("obj", ["score", "target:0.75"])
@pytest.mark.parametrize("commit", [0, 6])
def test_planner_equals_brute_force_on_a_small_horizon(obj, commit):
    rng = np.random.default_rng(3)
    p = rng.uniform(0.05, 0.95, (4, 3))
    prior = rng.uniform(0.2, 1.0, 4)
    o = objective.parse(obj)
    coef = o.coefficients(3)
    plan = bayes.solve(p, prior, coef, 4, commit=commit)
    want = brute_force(p, prior / prior.sum(), o.utility(p), 4, commit)
    assert plan.value == pytest.approx(want, abs=1e-10)
    # the plan run forward on each model, weighted by the prior, earns its value
    ev = bayes.evaluate_plan(plan, p)
    assert float(prior / prior.sum() @ ev.total) == pytest.approx(want, abs=1e-10)
    assert np.allclose(ev.visits.sum(axis=1), 4)


def test_ceiling_of_two_users_by_hand():
    """User A succeeds always at level 1 and never at level 2, user B always at both; prior 1/2 each;
    three turns, the paper's score. Level 1 first learns nothing: 1 + 2 (best of the rest) = 3.
    Level 2 first: 0.5 expected, and it reveals the user: then A plays level 1 twice (+2), B level 2
    twice (+4): 0.5 + 3 = 3.5. The ceiling is 3.5; the oracle 4.5 (A 3, B 6); the best fixed level 3."""
    p = np.array([[1.0, 0.0], [1.0, 1.0]])
    plan = bayes.solve(p, [0.5, 0.5], objective.SCORE.coefficients(2), 3)
    assert plan.value == pytest.approx(3.5, abs=1e-12)
    assert plan.decide([0, 0, 0, 0]) == 2
    assert plan.decide([0, 0, 0, 1]) == 1  # failed level 2: user A
    assert plan.decide([0, 0, 1, 0]) == 2  # succeeded: user B
    ev = bayes.evaluate_plan(plan, p)
    assert ev.session.tolist() == pytest.approx([1.0, 6.0])


def test_counts_are_sufficient_and_posterior_weights():
    p = np.array([[0.9, 0.2], [0.5, 0.5]])
    w = bayes.posterior_weights(p, [0.5, 0.5], [2, 1, 0, 3])
    raw = np.array([0.9 ** 2 * 0.1 * 0.8 ** 3, 0.5 ** 6])
    assert w == pytest.approx(raw / raw.sum())
    with pytest.raises(ValueError, match="no user model"):
        bayes.posterior_weights(np.array([[1.0, 0.5]]), [1.0], [0, 1, 0, 0])


def test_prior_certain_of_one_user_plays_its_best_level():
    p = np.array([[0.99, 0.9, 0.3, 0.1]])
    plan = bayes.solve(p, [1.0], objective.SCORE.coefficients(), 6)
    assert plan.value == pytest.approx(6 * (0.9 * 3 - 1))
    target = bayes.solve(p, [1.0], objective.parse("target:0.3").coefficients(), 6)
    assert target.decide([0] * 8) == 3 and target.value == pytest.approx(0.0)


def test_bad_inputs_are_one_line_errors():
    coef = objective.SCORE.coefficients(2)
    with pytest.raises(ValueError, match="lie in"):
        bayes.solve(np.array([[1.2, 0.5]]), [1.0], coef, 3)
    with pytest.raises(ValueError, match="prior weights"):
        bayes.solve(np.array([[0.2, 0.5]]), [0.0], coef, 3)
    plan = bayes.solve(np.array([[0.2, 0.5]]), [1.0], coef, 3)
    with pytest.raises(ValueError, match="covers 3 turns"):
        plan.decide([3, 0, 0, 0])


def test_state_count():
    assert bayes.n_states(25, 4) == 13_884_156
    assert int(bayes.layer_sizes(25, 4).sum()) == 13_884_156


def test_solve_refuses_a_horizon_over_its_memory_bound_before_allocating():
    """Issue 30: the bound covers what solve allocates (the table and its float layers)."""
    p = np.array([[0.9, 0.7, 0.5, 0.2]])
    coef = np.tile([0.0, 1.0, 0.0], (4, 1))
    with pytest.raises(bayes.PlanTooLarge) as err:
        bayes.solve(p, np.ones(1), coef, 500, max_bytes=2**30)  # 150 PiB: would raise MemoryError unchecked
    assert err.value.max_horizon == bayes.max_horizon(4, 2**30) and "needs 150.8 PiB" in str(err.value)
    plan = bayes.solve(p, np.ones(1), coef, 6, max_bytes=bayes.solve_bytes(6, 4))
    assert plan.action.nbytes + 5 * 8 * bayes.layer_sizes(8, 4)[-1] <= bayes.solve_bytes(6, 4)
    assert bayes.solve_bytes(25, 4) < 256 * 2**20 and bayes.max_horizon(4, bayes.solve_bytes(25, 4)) == 25
