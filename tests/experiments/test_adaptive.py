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
    """For a user whose level 3 succeeds at 0.75, QUEST+ placing by its posterior mean under target:0.75
    ends up at level 3 most."""
    p = np.array([[0.99, 0.95, 0.75, 0.35]])
    v = adaptive.questplus_values(p, objective.parse("target:0.75"), 25, "mean")
    assert int(np.argmax(v.visits[0])) == 2


def test_our_questplus_places_the_next_level_as_the_package_does():
    """QUEST+'s own placement (minimum expected entropy): after a fixed history our next level is the
    package's ``next_stim`` at every step."""
    questplus = pytest.importorskip("questplus")
    grid = adaptive.QuestPlusGrid.build()
    qp = adaptive.package_questplus(questplus.QuestPlus)
    counts = np.zeros(8)
    for length, ok in ((5, True), (7, False), (7, True), (9, False), (3, True), (5, True), (7, True)):
        theirs = int(round(-qp.next_stim["intensity"]))
        mine = LENGTHS_OF[int(grid.choose_entropy(counts)[0])]
        assert mine == theirs, (counts, mine, theirs)
        qp.update(stim={"intensity": -float(length)}, outcome={"response": "Correct" if ok else "Incorrect"})
        counts[2 * ((length - 3) // 2) + (0 if ok else 1)] += 1
    assert LENGTHS_OF[int(grid.choose_entropy(counts)[0])] == int(round(-qp.next_stim["intensity"]))


LENGTHS_OF = (3, 5, 7, 9)


def test_tuned_staircase_and_fitted_questplus_run_exactly():
    p = np.array([[0.99, 0.95, 0.75, 0.35], [0.98, 0.8, 0.5, 0.2]])
    obj = objective.parse("target-rate:0.75")
    need, start = adaptive.tuned_staircase(p, obj, 25)
    assert 1 <= need <= 4 and 1 <= start <= 4
    grid = adaptive.QuestPlusGrid.build()
    fitted = grid.fitted(p)
    assert np.isclose(np.exp(fitted.log_prior).sum(), 1.0)
    v = adaptive.questplus_values(p, obj, 25, "entropy", fitted)
    assert np.allclose(v.visits.sum(axis=1), 25) and v.successes_var is not None
