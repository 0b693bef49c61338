"""The ceiling beside an evaluation: hand-computed values, shares of the achievable gap, several
sessions, and the `evaluate` section from the command line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nao_trainer.cli import main
from nao_trainer.core import bayes, objective
from nao_trainer.experiments import ceiling

pytestmark = pytest.mark.skipif(not bayes.available(), reason="the planner needs numba")

# user A: always succeeds at level 1, never above; user B: always succeeds at levels 1 and 2
A, B = [1.0, 0.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0]


def test_ceiling_of_two_users_by_hand(tmp_path):
    """Three turns, the score: level 2 first (0.5 expected) reveals the user, then A plays level 1
    twice (+2) and B level 2 twice (+4): ceiling 3.5 = mean of A's 1 and B's 6; oracle 4.5; level 1
    always 3."""
    rows = ceiling.bayes_rows(["A", "B"], ["1", "2"], np.array([A, B]), None, objective.SCORE, turns=3,
                              loo=True, cache=tmp_path)
    ceil = {r["user"]: r["utility"] for r in rows if r["policy"] == "ceiling"}
    assert ceil == pytest.approx({"A": 1.0, "B": 6.0})
    assert {r["user"]: r["score"] for r in rows if r["policy"] == "ceiling"} == pytest.approx(ceil)
    # leave one out: each user's prior is the other user alone, a point mass that is wrong
    loo = {r["user"]: r["utility"] for r in rows if r["policy"] == "bayes-loo"}
    # A is sent to level 2 (B's best), fails, which no model in its prior can do: from counts the prior
    # cannot produce, the plan plays level 1 (documented in core.bayes) -> -1 + 1 + 1; B plays level 1
    assert loo == pytest.approx({"A": 1.0, "B": 3.0})
    fixed = ceiling.objective_rows({"A": np.array(A), "B": np.array(B)}, {"A": np.array(A), "B": np.array(A)},
                                   {}, objective.SCORE, 3)
    by = {(r["user"], r["policy"]): r["utility"] for r in fixed}
    assert by[("A", "oracle-objective")] == 3.0 and by[("B", "oracle-objective")] == 6.0
    assert by[("A", "pooled-fixed")] == 3.0 and by[("B", "pooled-fixed")] == 3.0  # level 1: 3 vs level 2: 1.5
    # two people: the ceiling's gain over the pooled level is -2 (A) and +3 (B), an interval around 0,
    # so no share is given; the paired difference is
    summary = {s["policy"]: s for s in ceiling.achievable(rows + fixed, reference="pooled-fixed")}
    assert summary["ceiling"]["achievable_share"]["share"] is None
    assert summary["ceiling"]["achievable_share"]["gap"] == pytest.approx(0.5)
    assert summary["ceiling"]["d_reference"] == pytest.approx(0.5) and summary["ceiling"]["people"] == 2


def test_utility_of_a_policy_comes_from_its_turns_per_level():
    rows = [{"user": "A", "policy": "x", "visits": [10.0, 15.0, 0.0, 0.0]}]
    ceiling.add_utility(rows, {"A": np.array([0.9, 0.75, 0.5, 0.1])}, objective.parse("target:0.75"))
    assert rows[0]["utility"] == pytest.approx(-10 * 0.15 ** 2)


def test_several_sessions_are_ordered_best_fixed_commit_bound_oracle(tmp_path):
    rng = np.random.default_rng(4)
    p = np.sort(rng.uniform(0.1, 0.99, (6, 4)), axis=1)[:, ::-1]
    out = ceiling.multi_session(p, objective.SCORE, turns=6, sessions=(1, 3), cache=tmp_path)
    v = {(m["sessions"], m["policy"]): m["value_per_session"] for m in out}
    for s in (1, 3):
        assert v[(s, "pooled-fixed")] <= v[(s, "explore-commit")] + 1e-9
        assert v[(s, "explore-commit")] <= v[(s, "bound")] + 1e-9 <= v[(s, "oracle")] + 2e-9
    assert v[(1, "explore-commit")] == pytest.approx(v[(1, "bound")])
    assert v[(3, "bound")] > v[(1, "bound")]  # the truth revealed is worth more over more sessions


@pytest.mark.slow  # QUEST+ by expected entropy run exactly on every user (about 25 s on a loaded machine)
def test_evaluate_prints_the_ceiling_under_the_target_objective(tmp_path, capsys):
    out = tmp_path / "e"
    rc = main(["evaluate", "--users", "level-only", "--policies", "fixed:2,best-fixed,staircase:2d1u",
               "--mc-episodes", "50", "--objective", "target-rate:0.75", "--no-plots", "--out", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "against the Bayes ceiling, objective target-rate:0.75" in text
    report = json.loads((out / "evaluation.json").read_text())
    summary = {s["policy"]: s for s in report["ceiling"]["summary"]}
    assert summary["ceiling"]["value"] >= summary["pooled-fixed"]["value"] - 1e-9
    assert summary["oracle-objective"]["value"] >= summary["ceiling"]["value"] - 1e-9
    # every baseline is there and judged under the session-rate objective (the Monte Carlo staircase
    # through the variance of its success rate)
    assert summary["staircase:2d1u"]["value"] < 0  # the Monte Carlo staircase, judged through its rate variance
    for policy in ("staircase-tuned", "questplus", "questplus-mean", "fixed:2"):  # exact rows
        assert summary[policy]["value"] <= summary["oracle-objective"]["value"] + 1e-9, policy
    assert {c["prior"] for c in report["ceiling"]["prior_checks"]} >= {"questplus (uniform grid)"}


def test_bad_objective_is_one_line(tmp_path, capsys):
    assert main(["evaluate", "--users", "level-only", "--objective", "target:2", "--out", str(tmp_path / "e")]) == 2
    assert "--objective" in capsys.readouterr().err
    assert main(["evaluate", "--users", "clusters", "--policies", "fixed:2", "--objective", "target:0.7",
                 "--no-plots", "--out", str(tmp_path / "f")]) == 2


def test_calibration_bins_and_error():
    from nao_trainer.experiments import user_models

    pairs = [(0.9, 1)] * 9 + [(0.9, 0)] + [(0.2, 0)] * 4 + [(0.2, 1)] * 6
    cal = user_models.calibration(pairs)
    # the 0.9 bin is exact; the 0.2 bin observes 0.6: ECE = 10/20 * 0.4
    assert cal["ece"] == pytest.approx(0.2)
    assert [b["n"] for b in cal["bins"]] == [10, 10]


def test_noise_corrected_oracle_sees_no_gap_when_everyone_is_the_same():
    """50 people with the same true rates, 6 turns per level: their own rates spread by binomial noise
    alone and give an oracle gap; the beta-binomial population (between-person variance ~ 0) gives
    nearly none. With a real spread at level 4 the population gap stays."""
    rng = np.random.default_rng(5)
    p = np.array([0.95, 0.85, 0.7, 0.45])

    def counts(rates):
        s = rng.binomial(6, rates)
        return np.stack([s, 6 - s], axis=-1).reshape(-1)

    same = {f"session:user_{i}/session_1": counts(p) for i in range(50)}
    obj = objective.parse("target-rate:0.75")
    out = ceiling.noise_corrected_oracle(same, obj, rng=np.random.default_rng(0))
    assert out["people"] == 50 and out["own_rates"]["oracle_gap"] > 0.1
    assert out["population"]["oracle_gap"] < 0.25 * out["own_rates"]["oracle_gap"]
    spread = {f"session:user_{i}/session_1": counts(np.r_[p[:3], rng.uniform(0.2, 0.95)]) for i in range(50)}
    assert ceiling.noise_corrected_oracle(spread, obj)["population"]["oracle_gap"] > out["population"]["oracle_gap"]


def test_the_ceiling_section_prints_the_noise_corrected_oracle_beside_the_own_rates_one():
    """evaluate --personalise puts both oracle gaps in its ceiling section; a level every person passed
    (no spread to draw from) still gives a finite population gap."""
    from nao_trainer.cli.ceiling_report import format_section

    rng = np.random.default_rng(2)
    counts = {f"session:user_{i}/session_1": np.array([6, 0, *np.ravel([(s, 6 - s) for s in
                                                      rng.binomial(6, [0.85, 0.6, 0.3])])]) for i in range(12)}
    nc = ceiling.noise_corrected_oracle(counts, objective.parse("target-p:0.75"))
    assert np.isfinite(nc["population"]["oracle_gap"]) and nc["level_mean"][0] == 1.0
    text = format_section({"objective": "target-p:0.75", "turns": 25, "summary": [], "noise_corrected_oracle": nc})
    line = next(ln for ln in text.splitlines() if "noise-corrected" in ln)
    assert f"own rates {nc['own_rates']['oracle_gap']:.3f}" in line and f"{nc['population']['oracle_gap']:.3f}" in line


def test_a_prior_predictive_check_compares_what_a_prior_predicts_with_the_users():
    """The ceiling's prior (uniform over the users) predicts exactly the users' per-level mean; a prior
    that puts all its weight on one model predicts no spread, and its mean is that model's rates."""
    p = np.array([[0.99, 0.9, 0.6, 0.3], [0.98, 0.8, 0.4, 0.1], [1.0, 0.95, 0.7, 0.5]])
    own = ceiling.prior_check(p, np.ones(3), p)
    assert own["prior_mean"] == pytest.approx(p.mean(axis=0).round(4).tolist())
    assert own["users_sd"] == pytest.approx(p.std(axis=0, ddof=1).round(4).tolist())
    one = ceiling.prior_check(p, np.array([0.0, 1.0, 0.0]), p)
    assert one["prior_mean"] == pytest.approx(p[1].tolist()) and not any(one["prior_sd"])
