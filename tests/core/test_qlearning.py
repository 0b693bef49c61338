"""Q-learning maths: update rule, temperature, masking, shaping, augmentation, batch == single agent."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import mdp
from nao_trainer.core.batch import BatchLearner
from nao_trainer.core.qlearning import (
    METHODS, QConfig, QLearner, choose_columns, expected_scores, inverse_temperature,
    policy_probabilities,
    temperature,
)
from nao_trainer.core.simulation import UserSimulator

S0 = mdp.encode(*mdp.S0)
S1 = mdp.encode(7, 0, 2)


def test_update_rule_hand_computed_with_bootstrap_and_terminal():
    ql = QLearner("performance")
    ql.q[S1] = [1.0, 3.0, 2.0, 0.0, 0.0, 0.0]
    target = ql.update(S0, 2, 2, 0.5, S1, done=False)
    assert target == pytest.approx(2 + 0.95 * 3.0)
    assert ql.q[S0, 2] == pytest.approx(0.08 * 4.85)  # 0.388
    ql.update(S0, 2, -1, 0.5, S1, done=True)  # terminal: no bootstrap
    assert ql.q[S0, 2] == pytest.approx(0.388 + 0.08 * (-1 - 0.388))  # 0.27696
    assert ql.visits[S0] == 2
    assert np.count_nonzero(ql.q[S0]) == 1  # only the taken pair changes


def test_update_from_start_and_self_loop_reads_q_before_writing():
    ql = QLearner("performance", QConfig(alpha=0.5, gamma=0.5))
    ql.q[S0] = [4.0, 0, 0, 0, 0, 0]
    # S0 --RF1, failure--> S0 itself: the target uses Q(S0, L1) = 4 before the update of Q(S0, RF1).
    assert mdp.NEXT_STATE[S0, mdp.ENCOURAGE, 0] == S0
    ql.update(S0, mdp.ENCOURAGE, -1, None, S0, done=False)
    assert ql.q[S0, mdp.ENCOURAGE] == pytest.approx(0.5 * (-1 + 0.5 * 4.0))
    ql.update(mdp.START, 1, 2, None, mdp.encode(5, 0, 0), done=False)
    assert ql.q[mdp.START, 1] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="not allowed"):
        ql.update(mdp.START, mdp.CHALLENGE, 1, None, S0, done=False)


def test_shaping_adds_beta1_times_engagement_to_the_reward():
    shaped, plain = QLearner("shaping"), QLearner("performance")
    for ql in (shaped, plain):
        ql.update(S0, 1, 1, 0.4, S1, done=True)
    assert shaped.q[S0, 1] == pytest.approx(0.08 * (1 + 7.5 * 0.4))
    assert plain.q[S0, 1] == pytest.approx(0.08 * 1)
    no_eeg = QLearner("shaping")
    no_eeg.update(S0, 1, 1, None, S1, done=True)  # engagement unavailable: plain reward
    assert no_eeg.q[S0, 1] == pytest.approx(0.08)


def test_qaug_learns_q_from_score_and_chooses_on_q_plus_beta2_h():
    ql = QLearner("qaug")
    for e in (0.2, 0.6, 0.7):
        ql.update(S0, 3, 2, e, S1, done=True)
    q = 0.0
    for _ in range(3):
        q += 0.08 * (2 - q)
    assert ql.q[S0, 3] == pytest.approx(q)  # the Q update uses r, not engagement
    assert ql.h[S0, 3] == pytest.approx(0.5)  # incremental sample mean of 0.2, 0.6, 0.7
    assert ql.h_counts[S0, 3] == 3
    ql.update(S0, 3, 2, None, S1, done=True)  # no engagement: H unchanged
    assert ql.h[S0, 3] == pytest.approx(0.5) and ql.h_counts[S0, 3] == 3
    expected = ql.q[S0] + 0.8 * ql.h[S0]
    np.testing.assert_allclose(ql.values(S0), expected)
    perf = QLearner("performance", q=ql.q.copy(), h=ql.h.copy())
    np.testing.assert_allclose(perf.values(S0), ql.q[S0])  # other methods ignore H
    assert ql.probabilities(S0)[3] > perf.probabilities(S0)[3]


def test_h_prior_is_the_starting_estimate():
    ql = QLearner("qaug", QConfig(h_prior=0.5))
    assert ql.h[S0, 0] == 0.5
    ql.update(S0, 0, 1, 0.9, S1, done=True)
    assert ql.h[S0, 0] == pytest.approx(0.9)  # first observation replaces the prior (n = 1)


def test_temperature_schedule_values():
    cfg = QConfig()
    np.testing.assert_allclose(temperature([0, 200, 600, 1800, 100_000], cfg), [5.0, 2.5, 1.25, 0.5, 0.1])
    cfg2 = QConfig(tau0=2.0, tau_min=0.5, n_half=10)
    np.testing.assert_allclose(temperature([0, 10, 30, 1000], cfg2), [2.0, 1.0, 0.5, 0.5])
    np.testing.assert_allclose(inverse_temperature(200, cfg), 0.4)
    ql = QLearner("performance")
    ql.update(S0, 0, 1, 0.5, S1, done=True)
    assert ql.inverse_temperature(S0) == pytest.approx(1 / (5.0 / (1 + 1 / 200)))


def test_first_choices_are_near_uniform():
    ql = QLearner("shaping")
    np.testing.assert_allclose(ql.probabilities(S0), np.full(6, 1 / 6))
    # After one full-reward update per action the policy is still close to uniform.
    for a in range(6):
        ql.update(S0, a, 4 if a == 3 else -1, 1.0, S1, done=True)
    p = ql.probabilities(S0)
    assert p.max() / p.min() < 1.35
    rng = np.random.default_rng(3)
    counts = np.bincount([QLearner("performance").act(S0, rng) for _ in range(3000)], minlength=6)
    assert counts.min() > 400  # ~500 each


def test_start_state_masks_feedback_actions():
    ql = QLearner("performance")
    ql.q[mdp.START] = [0, 0, 0, 0, 100.0, 100.0]  # even if RF looked attractive
    rng = np.random.default_rng(0)
    actions = {ql.act(mdp.START, rng) for _ in range(500)}
    assert actions == {0, 1, 2, 3}
    p = ql.probabilities(mdp.START)
    assert p[4] == p[5] == 0 and p[:4].sum() == pytest.approx(1)


def test_choose_columns_samples_the_softmax():
    rng = np.random.default_rng(7)
    values = np.array([1.0, 2.0, 0.0, 3.0])
    inv_tau = 1.3
    n = 40_000
    a = choose_columns(np.repeat(values[:, None], n, axis=1), np.full(n, inv_tau), rng.random(n))
    freq = np.bincount(a, minlength=4) / n
    expected = policy_probabilities(values, np.ones(4, bool), inv_tau)
    np.testing.assert_allclose(freq, expected, atol=0.01)
    # Huge values at a tiny temperature do not overflow: the best action is chosen.
    big = np.array([[500.0], [900.0], [899.0]])
    assert choose_columns(big, np.array([10.0]), np.array([0.999]))[0] == 1


def test_config_validation_names_the_bad_value():
    with pytest.raises(ValueError, match="alpha.*1.5"):
        QConfig(alpha=1.5)
    with pytest.raises(ValueError, match="tau_min"):
        QConfig(tau_min=10.0)
    with pytest.raises(ValueError, match="method must be one of"):
        QLearner("sarsa")
    assert QConfig.from_dict(QConfig(beta1=3.0).to_dict()) == QConfig(beta1=3.0)


def _users():
    a = UserSimulator.from_level_rates("a", [0.95, 0.8, 0.4, 0.1], [0.3, 0.5, 0.6, 0.4])
    b = UserSimulator.from_level_rates("b", [0.99, 0.9, 0.7, 0.5], [0.6, 0.5, 0.4, 0.3])
    rng = np.random.default_rng(11)
    # Per-state, per-outcome variation so engagement matters for shaping and qaug.
    eng = [np.clip(s.engagement * rng.uniform(0.5, 1.5, s.engagement.shape), 0, 1) for s in (a, b)]
    return np.stack([a.p_success, b.p_success]), np.stack(eng)


def test_batch_learner_equals_single_agents_step_by_step():
    p, e = _users()
    P, E = np.repeat(p, 3, axis=0), np.repeat(e, 3, axis=0)
    methods = list(METHODS) * 2
    episodes, turns = 120, 25
    res = BatchLearner(P, E, methods).run(episodes, turns, [np.random.default_rng(i) for i in range(6)], block=17)
    for i, method in enumerate(methods):
        ql = QLearner(method)
        u = np.random.default_rng(i).random((episodes, turns, 2))
        scores, engs = [], []
        for k in range(episodes):
            s, o, total, eng = mdp.START, 0, 0, 0.0
            for t in range(turns):
                a = ql.choose(s, u[k, t, 0])
                s2 = int(mdp.NEXT_STATE[s, a, o])
                o2 = int(u[k, t, 1] < P[i, s2])
                r = int(mdp.SCORE[s2, o2])
                ql.update(s, a, r, E[i, s2, o2], s2, t == turns - 1)
                s, o, total, eng = s2, o2, total + r, eng + E[i, s2, o2]
            scores.append(total)
            engs.append(eng / turns)
        assert np.array_equal(ql.q, res.q[i]), method
        assert np.array_equal(ql.h, res.h[i]) and np.array_equal(ql.h_counts, res.h_counts[i])
        assert np.array_equal(ql.visits, res.visits[i])
        assert np.array_equal(scores, res.episode_score[i])
        np.testing.assert_allclose(engs, res.episode_engagement[i], rtol=1e-12)
        assert res.h_counts[i, mdp.START, 4:].sum() == 0  # never RF in START
        assert res.visits[i, mdp.START] == episodes


def test_batch_agent_does_not_depend_on_its_neighbours():
    p, e = _users()
    alone = BatchLearner(p[:1], e[:1], ["qaug"]).run(50, 25, [np.random.default_rng(5)])
    mixed = BatchLearner(np.concatenate([p[1:], p[:1]]), np.concatenate([e[1:], e[:1]]), ["shaping", "qaug"]).run(
        50, 25, [np.random.default_rng(9), np.random.default_rng(5)], block=8)
    assert np.array_equal(alone.q[0], mixed.q[1])
    assert np.array_equal(alone.episode_score[0], mixed.episode_score[1])


def test_batch_learns_to_prefer_the_best_level():
    # A user who always succeeds: L4 (+4 per turn) is best, the learner should find it.
    p = np.ones((1, mdp.N_TURN_STATES))
    e = np.full((1, mdp.N_TURN_STATES, 2), 0.5)
    res = BatchLearner(p, e, ["performance"]).run(600, 25, [np.random.default_rng(0)])
    first, last = res.episode_score[0, :10].mean(), res.episode_score[0, -60:].mean()
    best, uniform = expected_scores(p[0], 25)
    assert (best, uniform) == (100.0, 62.5)  # L4 only; uniform levels average 2.5 per turn
    assert first < 75 and last > 90
    assert np.argmax(res.q[0, mdp.START]) == 3


def test_batch_rejects_bad_inputs():
    p, e = _users()
    with pytest.raises(ValueError, match="shape|need"):
        BatchLearner(p, e[:1], ["performance", "qaug"])
    with pytest.raises(ValueError, match="one generator per agent"):
        BatchLearner(p, e, ["performance", "qaug"]).run(1, 25, [np.random.default_rng(0)])


def test_extreme_hyper_parameters_never_give_invalid_actions():
    # Huge shaping weight, full learning rate, near-greedy temperature: the reused softmax shift can
    # be far from the maximum, yet no NaN/inf may appear and both learners still agree.
    p, e = _users()
    cfg = QConfig(alpha=1.0, beta1=1e4, beta2=50.0, tau0=0.1, tau_min=0.01)
    with np.errstate(over="raise", invalid="raise"):
        _extreme_run(p, e, cfg)


def _extreme_run(p, e, cfg):
    res = BatchLearner(p, e, ["shaping", "qaug"], cfg).run(30, 25, [np.random.default_rng(1), np.random.default_rng(2)])
    assert np.isfinite(res.q).all() and np.isfinite(res.episode_score).all()
    for i, method in enumerate(["shaping", "qaug"]):
        ql = QLearner(method, cfg)
        u = np.random.default_rng(i + 1).random((30, 25, 2))
        for k in range(30):
            s, o = mdp.START, 0
            for t in range(25):
                a = ql.choose(s, u[k, t, 0])
                assert mdp.ACTION_MASK[s, a]
                s2 = int(mdp.NEXT_STATE[s, a, o])
                o2 = int(u[k, t, 1] < p[i, s2])
                ql.update(s, a, int(mdp.SCORE[s2, o2]), e[i, s2, o2], s2, t == 24)
                s, o = s2, o2
        assert np.array_equal(ql.q, res.q[i])
        assert np.isfinite(ql.probabilities(S0)).all()


@pytest.mark.parametrize("name, value", [("alpha", "0.5"), ("tau0", None), ("beta1", "x"), ("h_prior", [0.1])])
def test_config_with_a_non_number_is_a_value_error_naming_it(name, value):
    # core.settings: one validator and one message style for every settings class (a SettingError is a ValueError)
    with pytest.raises(ValueError, match=rf"key '{name}' (must be a number|needs a value \(a number\)), got"):
        QConfig(**{name: value})


def test_the_learner_owns_its_state():
    rng = np.random.default_rng(3)
    lr = QLearner("qaug")
    s = mdp.encode(5, 0, 2)
    a = int(np.flatnonzero(mdp.ACTION_MASK[s])[0])
    lr.update(s, a, 3, 0.7, mdp.next_state(s, a, True), False)
    saved = lr.state_dict(transient=True)
    assert set(saved) == {"q", "h", "h_counts", "visits", "shift"} and "shift" not in lr.state_dict()
    other = QLearner("qaug")
    other.load_state_dict(saved)
    nxt = mdp.next_state(s, a, True)
    u = rng.random()
    assert other.choose(nxt, u) == lr.choose(nxt, u) and np.array_equal(other.q, lr.q)
    with pytest.raises(ValueError, match="q must have shape"):
        other.load_state_dict({**saved, "q": [[0.0] * 6]})
    with pytest.raises(KeyError):
        other.load_state_dict({k: v for k, v in saved.items() if k != "visits"})
