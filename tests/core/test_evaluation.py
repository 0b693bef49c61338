"""Exact evaluation, the finite-horizon optimum and Monte Carlo (core.evaluation), baselines (core.baselines)."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import baselines, evaluation, mdp, processes
from nao_trainer.core.qlearning import QLearner, expected_scores
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.learn import artifacts


def _tables(p_default=0.5):
    return np.full(mdp.N_TURN_STATES, p_default), np.full((mdp.N_TURN_STATES, 2), 0.5)


def test_one_turn_of_a_fixed_level_by_hand():
    p, e = _tables()
    p[mdp.LEVEL == 2] = 0.7
    e[mdp.LEVEL == 2] = [0.2, 0.6]
    out = evaluation.evaluate(evaluation.fixed_level_policy(2), p, e, turns=1)
    assert out.score == pytest.approx(0.7 * 2 + 0.3 * -1)
    assert out.engagement == pytest.approx(0.3 * 0.2 + 0.7 * 0.6)
    assert out.success == pytest.approx(0.7)
    np.testing.assert_allclose(out.visits, [0, 1, 0, 0])


def test_two_turns_where_the_previous_result_matters_by_hand():
    p, e = _tables()
    p[mdp.encode(3, 0, 0)] = 0.5
    p[mdp.encode(3, 0, 1)] = 1.0
    p[mdp.encode(3, 0, -1)] = 0.5
    out = evaluation.evaluate(evaluation.fixed_level_policy(1), p, e, turns=2)
    # turn 1: 0.5*1 + 0.5*(-1) = 0; turn 2: after success 1.0 * 1, after failure 0.5*1 + 0.5*(-1) = 0
    assert out.score == pytest.approx(0.5)
    assert out.success == pytest.approx((0.5 + 0.5 * 1.0 + 0.5 * 0.5) / 2)


def _informed_case():
    p, e = _tables(0.0)  # every other turn fails (-1)
    p[mdp.encode(3, 0, 0)] = 0.5
    p[mdp.encode(5, 0, 0)] = 0.0
    p[mdp.encode(3, 0, 1)] = p[mdp.encode(3, 0, -1)] = 0.5
    p[mdp.encode(5, 0, 1)] = 0.9
    p[mdp.encode(5, 0, -1)] = 0.1
    return p, e


def test_the_informed_optimum_uses_the_last_outcome_by_hand():
    p, _ = _informed_case()
    # turn 1: L1 (expected 0; L2 from START always fails). Turn 2 after a success: L2 gives
    # 0.9*2 - 0.1 = 1.7; after a failure L1 gives 0 (L2: 0.1*2 - 0.9 = -0.7).
    assert evaluation.optimal(p, 2, "informed").value == pytest.approx(0.5 * 1.7)
    # Without the outcome: L2 is worth 0.5*1.7 + 0.5*(-0.7) = 0.5 > L1's 0.
    assert evaluation.optimal(p, 2, "paper").value == pytest.approx(0.5)


def test_the_optimum_policy_evaluates_to_its_value_in_both_processes():
    p, e = _informed_case()
    for proc in processes.NAMES:
        opt = evaluation.optimal(p, 2, proc)
        assert evaluation.evaluate(opt.policy, p, e, 2, proc).score == pytest.approx(opt.value)


@pytest.fixture(scope="module")
def shipped():
    return [artifacts.load_simulator(c) for c in artifacts.available_models()]


def test_optimum_equals_the_existing_dynamic_programme_and_bounds_every_policy(shipped):
    for sim in shipped:
        best, uniform = expected_scores(sim.p_success, 25)
        opt = evaluation.optimal(sim.p_success, 25, "paper")
        assert opt.value == pytest.approx(best, abs=1e-9)
        assert evaluation.evaluate(evaluation.uniform_policy(), sim.p_success, sim.engagement).score == \
            pytest.approx(uniform, abs=1e-9)
        fixed = [evaluation.evaluate(evaluation.fixed_level_policy(lv), sim.p_success, sim.engagement).score
                 for lv in (1, 2, 3, 4)]
        assert max(fixed) <= opt.value + 1e-9
        assert evaluation.optimal(sim.p_success, 25, "informed").value >= opt.value - 1e-9
        level = baselines.best_fixed_level(sim.p_success, sim.engagement)
        assert fixed[level - 1] == max(fixed)


def _learner(process: str, seed: int = 0) -> QLearner:
    rng = np.random.default_rng(seed)
    n = processes.get(process).n_states
    return QLearner("qaug", q=rng.normal(0, 1, (n, 6)), h=rng.uniform(0, 1, (n, 6)),
                    h_counts=np.ones((n, 6), dtype=np.int64), visits=rng.integers(0, 400, n), process=process)


@pytest.mark.parametrize("process", processes.NAMES)
def test_monte_carlo_agrees_with_the_exact_values(shipped, process):
    sim = shipped[1]
    for table in (evaluation.uniform_policy(process), baselines.learner_table(_learner(process), process)):
        exact = evaluation.evaluate(table, sim.p_success, sim.engagement, 25, process)
        mc = evaluation.monte_carlo(evaluation.TablePolicy(table), sim.p_success, sim.engagement, 4000,
                                    np.random.default_rng(1), 25, process)
        assert mc.score_ci[0] <= exact.score <= mc.score_ci[1]
        assert mc.engagement_ci[0] <= exact.engagement <= mc.engagement_ci[1]
        np.testing.assert_allclose(mc.visits, exact.visits, atol=0.25)


def test_a_1u1d_staircase_in_the_informed_mdp_matches_its_exact_table(shipped):
    """With the outcome in the state, 1-up/1-down is stationary: Monte Carlo must agree with exact."""
    proc = processes.get("informed")
    table = np.zeros((proc.n_states, 6))
    table[proc.start, 2 - 1] = 1.0
    for x in range(proc.n_states - 1):
        s, o = divmod(x, 2)
        table[x, int(np.clip(mdp.LEVEL[s] + (1 if o else -1), 1, 4)) - 1] = 1.0
    sim = shipped[2]
    exact = evaluation.evaluate(table, sim.p_success, sim.engagement, 25, "informed")
    mc = evaluation.monte_carlo(baselines.Staircase("1u1d", 2), sim.p_success, sim.engagement, 4000,
                                np.random.default_rng(2), 25, "informed")
    assert mc.score_ci[0] <= exact.score <= mc.score_ci[1]


def test_staircases_follow_their_rule():
    p = np.ones(mdp.N_TURN_STATES)  # always succeeds
    e = np.full((mdp.N_TURN_STATES, 2), 0.3)
    up1 = evaluation.monte_carlo(baselines.Staircase("1u1d", 1), p, e, 2, np.random.default_rng(0), 6, "informed")
    np.testing.assert_allclose(up1.visits, [1, 1, 1, 3])
    up2 = evaluation.monte_carlo(baselines.Staircase("2d1u", 1), p, e, 2, np.random.default_rng(0), 6, "informed")
    np.testing.assert_allclose(up2.visits, [2, 2, 2, 0])
    # The paper MDP's state carries the last outcome one turn late; the staircase still reacts at once
    # (it sees each outcome when the planner does)
    paper = evaluation.monte_carlo(baselines.Staircase("1u1d", 1), p, e, 2, np.random.default_rng(0), 6, "paper")
    np.testing.assert_allclose(paper.visits, [1, 1, 1, 3])


def test_a_learner_that_keeps_learning_changes_its_tables_and_stays_valid(shipped):
    lr = _learner("paper")
    pol = baselines.KeepLearning(lr)
    out = evaluation.monte_carlo(pol, shipped[0].p_success, shipped[0].engagement, 50, np.random.default_rng(0))
    assert out.samples == 50 and np.all(pol.visits.sum(axis=1) == lr.visits.sum() + 25)
    assert np.isfinite(out.score)


def test_tables_that_do_not_fit_the_process_are_refused():
    p, e = _tables()
    with pytest.raises(ValueError, match="does not fit the informed MDP"):
        evaluation.evaluate(evaluation.uniform_policy("paper"), p, e, 25, "informed")
    bad = evaluation.uniform_policy("paper")
    bad[mdp.START] = 1 / 6
    with pytest.raises(ValueError, match="not allowed"):
        evaluation.evaluate(bad, p, e)
    with pytest.raises(ValueError, match="must be one of paper, informed"):
        processes.get("pomdp")
    with pytest.raises(ValueError, match="learner has 109 states"):
        baselines.learner_table(_learner("paper"), "informed")


def test_one_simulator_fits_both_processes():
    sim = UserSimulator.from_level_rates("x", [0.9, 0.8, 0.5, 0.2])
    for proc in processes.NAMES:
        out = evaluation.evaluate(evaluation.fixed_level_policy(2, proc), sim.p_success, sim.engagement, 25, proc)
        assert out.score == pytest.approx(25 * (0.8 * 2 - 0.2))
