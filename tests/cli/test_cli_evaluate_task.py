"""`nao-trainer evaluate --task nback` (issue 26): baselines, learners, the oracle and the Bayes ceiling under both
target objectives, on n-back's own simulated users (its signal-detection observers), levels taken from the task;
the fitted user sets, which are people playing the sequence task, are refused for it in one line."""
from __future__ import annotations

import csv
import gzip
import json

import numpy as np
import pytest

from nao_trainer.cli import main
from nao_trainer.core.objective import parse
from nao_trainer.tasks.nback import ABILITIES, NBackTask, rules

TURNS = 3
FAST = ["--seeds", "1", "--episodes", "100", "--mc-episodes", "10", "--workers", "1", "--turns", str(TURNS),
        "--limit", "2", "--no-plots", "--json"]
POLICIES = "fixed:1,fixed:2,fixed:3,fixed:4,best-fixed,random,staircase:2d1u@2,usp:performance,oracle"


def _observer_rates(ability: float) -> np.ndarray:
    """What the task's observer of that ability succeeds at, per level n = 1..4, computed from the rules here."""
    s = NBackTask().settings
    return np.array([rules.success_probability(ability * d, c, n) for n, d, c in zip((1, 2, 3, 4), s.d_prime,
                                                                                      s.criterion)])


@pytest.mark.parametrize("objective", ["target-p:0.75", "target-rate:0.75"])
def test_evaluate_nback_compares_baselines_learners_oracle_and_ceiling(objective, tmp_path, capsys):
    out = tmp_path / "ev"
    assert main(["evaluate", "--task", "nback", "--policies", POLICIES, "--objective", objective, "--out", str(out),
                 *FAST]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["users"] == "task nback" and report["n_users"] == 2
    names = {r["policy"] for r in report["summary"]}
    assert {"fixed:1", "best-fixed", "staircase:2d1u@2", "usp:performance", "oracle"} <= names
    with gzip.open(out / "evaluation_rows.csv.gz", "rt") as f:
        rows = list(csv.DictReader(f))
    users = [f"nback-d{a:g}x" for a in ABILITIES[:2]]
    assert sorted({r["user"] for r in rows}) == users  # the task's own observers, not the fitted clusters
    rates = {u: _observer_rates(a) for u, a in zip(users, ABILITIES)}
    for r in rows:  # always level L scores T ((L + 1) p_L - 1), p_L the observer's block success at n = L
        if r["policy"].startswith("fixed:"):
            level = int(r["policy"][-1])
            assert float(r["score"]) == pytest.approx(TURNS * (rates[r["user"]][level - 1] * (level + 1) - 1), abs=1e-6)
    ceiling = report["ceiling"]
    assert ceiling["objective"] == objective and ceiling["turns"] == TURNS
    value = {s["policy"]: s["value"] for s in ceiling["summary"]}
    obj = parse(objective)
    for level in (1, 2, 3, 4):  # each fixed level's value under the objective, exactly
        expected = np.mean([obj.fixed_value(rates[u], TURNS)[level - 1] for u in users])
        assert value[f"fixed:{level}"] == pytest.approx(expected, abs=1e-6)
    # The Bayes ceiling (uniform prior over these users) bounds every policy that does not know the user, and the
    # oracle knowing the user bounds it.
    for name in ("fixed:1", "fixed:2", "fixed:3", "fixed:4", "random", "staircase:2d1u@2", "usp:performance"):
        assert value["ceiling"] >= value[name] - 1e-9, name
    assert value["oracle-objective"] >= value["ceiling"] - 1e-9


@pytest.mark.parametrize("flags, words", [
    (["--task", "nback", "--users", "clusters"], "people playing the sequence task"),
    (["--task", "nback", "--personalise"], "published data, which are the sequence task's"),
    (["--task", "sequence", "--users", "task"], "declares no simulated users"),
])
def test_user_sets_of_another_task_are_refused_in_one_line(flags, words, tmp_path, capsys):
    assert main(["evaluate", *flags, "--no-plots", "--out", str(tmp_path / "ev")]) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
