"""User-model posterior (core.posterior) on cases computed by hand."""
from __future__ import annotations

import math

import numpy as np
import pytest

from nao_trainer.core import mdp, posterior


def level_only(rates, engagement=(0.5, 0.5, 0.5, 0.5)):
    p = np.asarray(rates, dtype=float)[mdp.LEVEL - 1]
    e = np.repeat(np.asarray(engagement, dtype=float)[mdp.LEVEL - 1][:, None], 2, axis=1)
    return p, e


def two_models(sigma=None):
    pa, ea = level_only([0.9, 0.8, 0.5, 0.2], [0.4, 0.4, 0.4, 0.4])
    pb, eb = level_only([0.9, 0.6, 0.3, 0.1], [0.6, 0.6, 0.6, 0.6])
    return posterior.ModelSet(("a", "b"), np.stack([pa, pb]), np.stack([ea, eb]), np.array([1.0, 3.0]), sigma)


L2 = mdp.encode(5, 0, 0)  # a level-2 turn state
L3 = mdp.encode(7, 0, 2)  # a level-3 turn state


def test_posterior_by_hand_prior_times_outcome_likelihoods():
    models = two_models()
    # Prior 1/4, 3/4. Outcomes: L2 success, L2 failure, L3 success.
    # a: 0.25 * 0.8 * 0.2 * 0.5 = 0.02 ; b: 0.75 * 0.6 * 0.4 * 0.3 = 0.054 ; P(a) = 0.02 / 0.074
    w = posterior.posterior(models, [L2, L2, L3], [True, False, True])
    assert w == pytest.approx([0.02 / 0.074, 0.054 / 0.074], abs=1e-12)
    assert posterior.posterior(models, [], []) == pytest.approx([0.25, 0.75])


def test_finite_kappa_is_the_beta_binomial_mixture():
    """Level-only models: the sequential predictive equals prior x Beta-binomial marginal per level."""
    models = two_models()
    kappa = 4.0
    states = [L2, L2, L2, L3, L3]
    wins = [True, True, False, True, False]
    w = posterior.posterior(models, states, wins, kappa=kappa)

    def log_beta(a, b):
        return math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)

    def marginal(rate, k, n):  # probability of this exact sequence with k successes in n under Beta(kappa*m, ...)
        a, b = kappa * rate, kappa * (1 - rate)
        return math.exp(log_beta(a + k, b + n - k) - log_beta(a, b))

    la = 0.25 * marginal(0.8, 2, 3) * marginal(0.5, 1, 2)
    lb = 0.75 * marginal(0.6, 2, 3) * marginal(0.3, 1, 2)
    assert w == pytest.approx([la / (la + lb), lb / (la + lb)], rel=1e-9)
    # ... and differs from the plain posterior (the participant's own rates count).
    assert not np.allclose(w, posterior.posterior(models, states, wins))


def test_engagement_likelihood_is_gaussian_around_each_model():
    models = two_models(sigma=np.array([0.1, 0.2]))
    e = 0.55
    w = posterior.posterior(models, [L2], [True], engagements=[e])
    la = 0.25 * 0.8 * math.exp(-0.5 * ((e - 0.4) / 0.1) ** 2) / 0.1
    lb = 0.75 * 0.6 * math.exp(-0.5 * ((e - 0.6) / 0.2) ** 2) / 0.2
    assert w == pytest.approx([la / (la + lb), lb / (la + lb)], rel=1e-9)
    # An unknown engagement (NaN) counts the outcome only.
    assert posterior.posterior(models, [L2], [True], engagements=[float("nan")]) == pytest.approx(
        posterior.posterior(models, [L2], [True]))


def test_one_surprising_turn_does_not_rule_a_model_out():
    pa, ea = level_only([1.0, 1.0, 1.0, 1.0])
    pb, eb = level_only([0.5, 0.5, 0.5, 0.5])
    models = posterior.ModelSet(("sure", "coin"), np.stack([pa, pb]), np.stack([ea, eb]), np.array([1.0, 1.0]))
    w = posterior.posterior(models, [L2], [False])
    assert 0 < w[0] < 0.01 and w[0] == pytest.approx(posterior.FLOOR / (posterior.FLOOR + 0.5))


def test_model_set_refuses_bad_shapes_and_priors():
    p, e = level_only([0.9, 0.8, 0.5, 0.2])
    with pytest.raises(ValueError, match="priors"):
        posterior.ModelSet(("a",), p[None], e[None], np.array([0.0]))
    with pytest.raises(ValueError, match="needs p_success"):
        posterior.ModelSet(("a", "b"), p[None], e[None], np.array([1.0, 1.0]))
