"""Assessment schedule, exact value tables and the policy choice by posterior expected value."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import assessment, evaluation, mdp, processes, posterior


def level_only(rates):
    p = np.asarray(rates, dtype=float)[mdp.LEVEL - 1]
    return p, np.full((mdp.N_TURN_STATES, 2), 0.5)


def test_default_schedule_is_short_blocks_at_levels_2_3_4():
    assert assessment.assessment_schedule() == (2, 2, 3, 3, 4, 4)
    assert assessment.assessment_schedule(4) == (2, 2, 3, 4)
    assert assessment.assessment_schedule(0) == ()
    assert assessment.assessment_schedule(3, (1, 4)) == (1, 1, 4)
    with pytest.raises(ValueError):
        assessment.assessment_schedule(-1)
    with pytest.raises(ValueError):
        assessment.assessment_schedule(3, (0, 5))


def test_value_tables_equal_exact_evaluation_from_the_start():
    rng = np.random.default_rng(3)
    p = rng.uniform(0.05, 0.95, mdp.N_TURN_STATES)
    e = rng.uniform(0, 1, (mdp.N_TURN_STATES, 2))
    table = rng.uniform(0, 1, (mdp.N_STATES, mdp.N_ACTIONS)) * mdp.ACTION_MASK
    table /= table.sum(axis=1, keepdims=True)
    v, n = assessment.value_tables(table, p, 25)
    out = evaluation.evaluate(table, p, e, 25)
    assert v[25, processes.START_FULL] == pytest.approx(out.score, abs=1e-9)
    assert n[25, processes.START_FULL] == pytest.approx(out.visits, abs=1e-9)
    assert np.allclose(n[7].sum(axis=1), 7.0)
    # From a later state: a fixed level on a level-only user is r turns of (level + 1) p - 1.
    pl, _ = level_only([0.9, 0.8, 0.5, 0.3])
    v3, _ = assessment.value_tables(evaluation.fixed_level_policy(3), pl, 10)
    x = 2 * mdp.encode(5, 0, 2) + 1
    assert v3[4, x] == pytest.approx(4 * (4 * 0.5 - 1))


def hand_built():
    """Model A (likely, 0.6): level 4 is best by a little. Model B (0.4): level 4 is a disaster.

    A: p = (1, .9, .8, .6) -> fixed:4 scores 5 * .6 - 1 = 2.0 per turn, fixed:2 3 * .9 - 1 = 1.7.
    B: p = (1, .9, .5, .1) -> fixed:4 scores -0.5 per turn, fixed:2 1.7.
    Posterior EV per turn: fixed:4 .6 * 2 + .4 * -.5 = 1.0; fixed:2 1.7. The most likely model's
    policy (fixed:4) is the wrong choice.
    """
    pa, ea = level_only([1.0, 0.9, 0.8, 0.6])
    pb, eb = level_only([1.0, 0.9, 0.5, 0.1])
    models = posterior.ModelSet(("A", "B"), np.stack([pa, pb]), np.stack([ea, eb]), np.array([0.6, 0.4]))
    cands = [assessment.Candidate("usp:A", evaluation.fixed_level_policy(4)),
             assessment.Candidate("usp:B", evaluation.fixed_level_policy(2))]
    return models, cands


def test_posterior_expected_value_beats_the_most_likely_clusters_policy():
    models, cands = hand_built()
    ev = assessment.Personaliser(models, cands, schedule=(), kappa=float("inf"), margin=0.0, turns=25)
    paper = assessment.Personaliser(models, cands, schedule=(), kappa=float("inf"), margin=0.0, turns=25,
                                     mode="map", own_policy=(0, 1))
    values = ev.expected_values(0)[0]
    assert values == pytest.approx([25 * 1.0, 25 * 1.7])
    assert ev.decide(0)[0] == 1  # usp:B, not the most likely model's policy
    assert paper.decide(0)[0] == 0
    # And it is right: over participants drawn from the prior, EV's choice scores more.
    rng = np.random.default_rng(0)
    totals = {}
    for name, pol in (("ev", ev), ("map", paper)):
        scores = [evaluation.monte_carlo(pol, models.p_success[k], np.full((108, 2), 0.5), 400, rng).score
                  for k in range(2)]
        totals[name] = 0.6 * scores[0] + 0.4 * scores[1]
    assert totals["ev"] > totals["map"] + 10


def test_anti_flip_flop_margin():
    models, cands = hand_built()
    pol = assessment.Personaliser(models, cands, schedule=(), kappa=float("inf"), margin=0.5, turns=25)
    pol.current[:] = 0  # following usp:A
    assert pol.decide(0)[0] == 1  # gains 17.5 points > margin: switches
    sticky = assessment.Personaliser(models, cands, schedule=(), kappa=float("inf"), margin=100.0, turns=25)
    sticky.current[:] = 0
    assert sticky.decide(0)[0] == 0 and sticky.switches[0] == 0


def test_assessment_turns_follow_the_schedule_then_the_choice():
    models, cands = hand_built()
    pol = assessment.Personaliser(models, cands, schedule=(2, 3, 4), kappa=10.0, turns=25)
    pol.reset(5, processes.get("paper"))
    rng = np.random.default_rng(1)
    obs = np.full(5, mdp.START)
    assert list(pol.act(obs, 0, rng)) == [1] * 5 and list(pol.act(obs, 2, rng)) == [3] * 5
    assert pol.in_assessment(2) and not pol.in_assessment(3)


def test_per_level_learning_finds_a_strong_participant():
    """No model says level 4 pays (best p4 = 0.45: 1.25 points a turn against level 2's 1.7); a
    participant who succeeds at level 4 gets it when the per-level Beta posteriors learn (kappa
    finite), never with the models as fitted (kappa inf)."""
    pa, ea = level_only([1.0, 0.9, 0.4, 0.1])
    pb, eb = level_only([1.0, 0.9, 0.6, 0.45])
    models = posterior.ModelSet(("A", "B"), np.stack([pa, pb]), np.stack([ea, eb]), np.array([1.0, 1.0]))
    cands = [assessment.Candidate(f"fixed:{lv}", evaluation.fixed_level_policy(lv)) for lv in (1, 2, 3, 4)]
    strong, e = level_only([1.0, 0.95, 0.9, 0.95])
    rng = np.random.default_rng(2)
    out = {}
    for kappa in (4.0, float("inf")):
        pol = assessment.Personaliser(models, cands, schedule=(2, 2, 3, 3, 4, 4), kappa=kappa, turns=25)
        out[kappa] = evaluation.monte_carlo(pol, strong, e, 300, rng)
    assert out[4.0].visits[3] > 15 and out[float("inf")].visits[3] == pytest.approx(2.0)
    assert out[4.0].score > out[float("inf")].score + 15


def test_a_bonus_is_an_argument_of_one_decision_and_the_choice_has_names():
    models, cands = hand_built()
    pol = assessment.Personaliser(models, cands, schedule=(), kappa=float("inf"), margin=0.0, turns=25,
                                  mode=assessment.Choice.EXPECTED_VALUE)
    assert pol.decide(0)[0] == 1
    pol.current[:] = -1
    assert pol.decide(0, bonus=np.array([[100.0, 0.0]]))[0] == 0  # the supervisor's guidance, this decision only
    assert assessment.Personaliser(models, cands, schedule=(), mode="map", own_policy=(0, 1)).mode \
        is assessment.Choice.MOST_LIKELY  # the strings still name the choices
    with pytest.raises(ValueError, match="mode must be one of ev, map"):
        assessment.Personaliser(models, cands, mode="best")


def test_snapshot_and_restore_of_one_participant():
    models, cands = hand_built()
    pol = assessment.Personaliser(models, cands, schedule=(2, 3), kappa=10.0, turns=25)
    for state, ok in [(mdp.encode(3, 0, 0), True), (mdp.encode(5, 0, 2), False)]:
        pol.update(np.array([state]), np.array([ok]))
    pol.decide(2)
    snap = pol.snapshot()
    again = assessment.Personaliser(models, cands, schedule=(), kappa=10.0, turns=25)
    again.restore(snap)
    assert again.snapshot() == snap and again.schedule == (2, 3) and again.turn == 2
    assert np.allclose(again.posterior(), pol.posterior())


def test_the_beta_ratio_is_the_log_gamma_form_and_loads_no_scipy():
    """The probes' Beta-binomial terms: log B(a+k, b+j) - log B(a, b), without scipy.special (0.3 s per session)."""
    import subprocess
    import sys

    from scipy.special import gammaln as g

    rng = np.random.default_rng(0)
    a, b = rng.uniform(0.05, 40, (200, 3)), rng.uniform(0.05, 40, (200, 3))
    for k, j in [(0, 0), (1, 0), (0, 1), (2, 1), (0, 3), (3, 0)]:
        ref = g(a + k) + g(b + j) - g(a + b + k + j) - (g(a) + g(b) - g(a + b))
        np.testing.assert_allclose(assessment._log_beta_ratio(a, b, k, j), ref, rtol=0, atol=1e-12)
    code = """if True:
        import sys, numpy as np
        import nao_trainer.session.wiring, nao_trainer.policies.personalised  # what a session loads
        from nao_trainer.core import assessment, evaluation, mdp, posterior, processes
        p = np.stack([np.asarray(r)[mdp.LEVEL - 1] for r in ([1, .9, .8, .6], [1, .9, .5, .1])])
        models = posterior.ModelSet(("A", "B"), p, np.full((2, mdp.N_TURN_STATES, 2), 0.5), np.array([.6, .4]))
        cands = [assessment.Candidate("usp:A", evaluation.fixed_level_policy(4))]
        pol = assessment.Personaliser(models, cands, schedule=(), kappa=10.0, turns=25)
        pol.reset(1, processes.get("paper"))
        assert np.isfinite(pol.probe_values(0)).all()
        print(sorted(m for m in sys.modules if m.startswith("scipy")))"""
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "[]\n"
