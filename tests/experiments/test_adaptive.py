"""Staircases and QUEST+ evaluated exactly: against Monte Carlo and against the questplus package."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import baselines, evaluation, objective
from nao_trainer.experiments import adaptive

P = np.array([0.98, 0.85, 0.6, 0.3])


def test_exact_staircase_matches_monte_carlo_of_the_session_staircase():
    """The informed MDP's staircase also sees the outcome of the turn just played."""
    exact = adaptive.staircase_exact(2, 2, P, 25, objective.SCORE)
    p_table = P[np.repeat(np.arange(4), 27)]
    out = evaluation.monte_carlo(baselines.Staircase("2d1u", 2), p_table, np.zeros((108, 2)), 4000,
                                 np.random.default_rng(0), 25, "informed")
    assert out.score_ci[0] <= exact["score"] <= out.score_ci[1]
    assert np.allclose(out.visits, exact["visits"], atol=0.35)


def test_questplus_posterior_is_the_packages():
    questplus = pytest.importorskip("questplus")
    grid = adaptive.QuestPlusGrid.build()
    qp = questplus.QuestPlus(stim_domain={"intensity": -np.array([3.0, 5.0, 7.0, 9.0])},
                             param_domain={"mean": -adaptive.THRESHOLDS, "sd": adaptive.SPREADS,
                                           "lower_asymptote": np.array([0.0]), "lapse_rate": adaptive.LAPSES},
                             outcome_domain={"response": ["Correct", "Incorrect"]}, func="norm_cdf",
                             stim_scale="linear")
    counts = np.zeros(8)
    for length, ok in ((5, True), (7, False), (7, True), (9, False), (3, True)):
        qp.update(stim={"intensity": -float(length)}, outcome={"response": "Correct" if ok else "Incorrect"})
        counts[2 * ((length - 3) // 2) + (0 if ok else 1)] += 1
    theirs = qp.posterior.transpose("mean", "sd", "lower_asymptote", "lapse_rate").values.reshape(-1)
    w, mean = adaptive.QuestPlusGrid.predictive(grid, counts)
    assert np.allclose(w[0], theirs, atol=1e-9)
    assert np.all(np.diff(mean[0]) < 0)  # longer sequences are harder


def test_questplus_targets_the_rate():
    """For a user whose level 3 succeeds at 0.75, QUEST+ under target:0.75 ends up at level 3 most."""
    p = np.array([[0.99, 0.95, 0.75, 0.35]])
    v = adaptive.questplus_values(p, objective.parse("target:0.75"), 25)
    assert int(np.argmax(v.visits[0])) == 2
