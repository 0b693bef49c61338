"""Users to evaluate on (learn.users), the tested-effects fit (learn.effects), and `nao-trainer evaluate`."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nao_trainer.cli import main
from nao_trainer.core import mdp
from nao_trainer.experiments import comparison
from nao_trainer.learn import effects, policy_files, users
from nao_trainer.learn.fitting import Turns


def test_level_only_variants_depend_on_the_level_only():
    clusters = users.cluster_user_set(None, "clusters")
    flat = users.cluster_user_set(None, "level-only")
    for c, f in zip(clusters, flat):
        assert f.train is not None and f.train.fingerprint() == c.truth.fingerprint()  # trained as shipped
        for lv in (1, 2, 3, 4):
            assert np.ptp(f.truth.p_success[mdp.LEVEL == lv]) == 0
            assert np.ptp(f.truth.engagement[mdp.LEVEL == lv]) == 0
        assert not np.array_equal(f.truth.p_success, c.truth.p_success)


def test_beta_prior_shrinks_a_session_toward_its_cluster_by_hand():
    # Cluster: 4 other sessions with level-1 rates 0.5, 0.5, 1.0, 1.0 over 4 turns each.
    assert users.beta_concentration(np.array([0.5, 0.5, 1.0, 1.0]), np.array([4, 4, 4, 4])) == pytest.approx(
        np.clip(0.75 * 0.25 / (np.var([0.5, 0.5, 1, 1], ddof=1) - 0.75 * 0.25 / 4) - 1, 1, 100))
    # No spread beyond binomial noise: the prior dominates.
    assert users.beta_concentration(np.array([0.5, 0.5]), np.array([4, 4])) == 100.0


def _turns(rng, n_sessions=30, feedback_effect=0.0):
    """Synthetic turns: level-dependent success, optionally + feedback_effect after encouraging feedback."""
    rows = []
    for s in range(n_sessions):
        for _ in range(25):
            level = rng.integers(1, 5)
            fb = rng.integers(0, 3)
            prev = int(rng.choice([-level, level]))
            state = mdp.encode(mdp.LENGTHS[level - 1], int(fb), prev)
            p = [0.95, 0.8, 0.5, 0.2][level - 1] + (feedback_effect if fb == 1 else 0.0)
            rows.append((f"s{s}", state, rng.random() < min(p, 1.0), 0.3 + 0.05 * level + rng.normal(0, 0.05)))
    sess, state, succ, eng = zip(*rows)
    n = len(rows)
    return Turns(np.array(sess), np.array(state), np.array(succ), np.array(eng), np.ones(n), np.ones(n))


def test_effects_are_kept_only_where_the_data_supports_them():
    rng = np.random.default_rng(0)
    plain = _turns(rng)
    pm = effects.TestedPerformanceModel().fit(plain.state, plain.success)
    assert pm.effects_ == () and not pm.tests["feedback"]["kept"]
    for lv in (1, 2, 3, 4):
        assert np.ptp(pm.table_[mdp.LEVEL == lv]) < 1e-9  # level only
    strong = _turns(rng, feedback_effect=0.45)
    pm2 = effects.TestedPerformanceModel().fit(strong.state, strong.success)
    assert "feedback" in pm2.effects_ and pm2.tests["feedback"]["p"] < 0.001
    assert pm2.table_[mdp.encode(7, 1, 3)] > pm2.table_[mdp.encode(7, 0, 3)] + 0.2
    em = effects.TestedEngagementModel().fit(plain.state, plain.success, plain.engagement)
    assert em.effects_ == () and em.table_[mdp.encode(9, 2, -4), 1] == pytest.approx(0.5, abs=0.02)


def test_policy_specs_are_checked():
    assert comparison.parse_policy("staircase:2d1u@3") == ("staircase", ("2d1u", 3))
    assert comparison.parse_policy("usp-learning:qaug") == ("usp-learning", "qaug")
    for bad in ("fixed:5", "staircase:3u", "usp:sarsa", "best"):
        with pytest.raises(Exception, match="unknown policy"):
            comparison.parse_policy(bad)


def test_evaluate_on_clusters_writes_table_and_figure(tmp_path, capsys):
    out = tmp_path / "ev"
    rc = main(["evaluate", "--users", "clusters", "--seeds", "2", "--episodes", "300", "--mc-episodes", "50",
               "--policies", "fixed:2,best-fixed,staircase:1u1d,usp:performance,usp:shaping,usp-learning:qaug,oracle",
               "--out", str(out), "--json"])
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    by = {s["policy"]: s for s in report["summary"]}
    assert by["oracle"]["regret"] == pytest.approx(0, abs=1e-9)
    assert all(s["regret"] >= -1e-9 for s in report["summary"] if not s["policy"].startswith("staircase"))
    assert by["usp:performance"]["n"] == 3 * 2 and by["fixed:2"]["n"] == 3
    assert by["best-fixed"]["score"] >= by["fixed:2"]["score"] - 1e-9
    assert report["claims"][0]["a"] == "usp:shaping" and report["claims"][0]["n"] == 6
    assert (out / "evaluation.png").stat().st_size > 0 and (out / "evaluation.csv").read_text().startswith("policy,")
    from nao_trainer.experiments.reports import read_rows

    rows = read_rows(out / "evaluation_rows.csv.gz")
    assert len(rows) == 3 * (2 + 1 + 2 * 2 + 2 + 1)  # baselines 1 row per user, usp kinds 2 seeds
    oracle = {r["user"]: r["score"] for r in rows if r["policy"] == "oracle"}
    for r in rows:
        assert r["regret"] == pytest.approx(oracle[r["user"]] - r["score"], abs=1e-8)


def test_policy_files_for_the_other_mdp_are_refused_with_one_line(tmp_path, capsys):
    rc = main(["evaluate", "--users", "clusters", "--mdp", "informed", "--policy-files", str(policy_files.default_policies_dir()),
               "--policies", "usp:qaug", "--out", str(tmp_path / "ev")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "made for the paper MDP, not the informed MDP" in err[0]


def test_shipped_policy_files_evaluate_on_the_shipped_models(tmp_path, capsys):
    rc = main(["evaluate", "--users", "level-only", "--policy-files", str(policy_files.default_policies_dir()), "--policies",
               "usp:qaug,best-fixed", "--out", str(tmp_path / "ev"), "--no-plots", "--json"])
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    assert {s["policy"] for s in report["summary"]} == {"usp:qaug", "best-fixed"}


def test_bad_user_sets_are_one_line_errors(tmp_path, capsys):
    assert main(["evaluate", "--users", str(tmp_path / "nowhere"), "--out", str(tmp_path / "e")]) == 2
    assert main(["evaluate", "--users", "sessions", "--out", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "nowhere" in err[0] and "--data" in err[1]


def test_leave_one_session_out_never_trains_on_the_user(dataset_root):
    """Changing a session's own outcomes changes its truth but not the simulator its policies train on."""
    turns = Turns.from_columns(users.read_turns(dataset_root, "authors2018").columns)
    who = "user_1/session_4"
    user = users._loso_one(turns, who, 3, 10, 0)
    assert user.name == f"session:{who}" and user.train.metadata["left_out"] == who
    # Move the session's successes to other states at the same level: its user model (and cluster)
    # stay the same; a simulator fitted on these turns would change.
    idx = np.flatnonzero(turns.session == who)
    success = turns.success.copy()
    for lv in (1, 2, 3, 4):
        at = idx[turns.level[idx] == lv]
        success[at] = np.sort(turns.success[at])  # same count of successes, other turns
    assert not np.array_equal(success, turns.success)
    moved = Turns(turns.session, turns.state, success, turns.engagement, turns.reaction_time, turns.completion_time)
    other = users._loso_one(moved, who, 3, 10, 0)
    assert other.cluster == user.cluster
    assert other.train.fingerprint() == user.train.fingerprint()
    np.testing.assert_array_equal(other.truth.p_success, user.truth.p_success)
    for lv in (1, 2, 3, 4):
        assert np.ptp(user.truth.p_success[mdp.LEVEL == lv]) == 0


@pytest.mark.slow
def test_evaluate_on_sessions_of_a_dataset_root(dataset_root, own_cache, tmp_path, capsys):
    out = tmp_path / "ev"
    rc = main(["evaluate", "--users", str(dataset_root), "--limit", "2", "--seeds", "1", "--episodes", "100",
               "--policies", "fixed:2,best-fixed,usp:qaug,oracle", "--out", str(out), "--no-plots", "--json"])
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    assert report["users"] == "sessions" and report["n_users"] == 2
    by = {s["policy"]: s for s in report["summary"]}
    assert by["oracle"]["score"] >= max(s["score"] for s in report["summary"]) - 1e-9


def test_shipped_tested_effect_models_load_and_record_their_tests():
    from nao_trainer.files import PROJECT_ROOT

    folder = PROJECT_ROOT / "sim" / "models-tested"
    for user in users.cluster_user_set(folder):
        effects_ = user.truth.metadata["effects"]
        assert set(effects_["success"]) == {"feedback", "previous"}
        for test in (*effects_["success"].values(), *effects_["engagement"].values()):
            assert test["kept"] == (test["p"] < 0.05 / (2 if test in effects_["success"].values() else 3))
        assert not effects_["success"]["feedback"]["kept"]  # the published data shows no feedback effect
