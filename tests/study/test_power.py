"""The power simulation's parts: the schedule as the live policy plays it, the closed-form test against
statsmodels' MixedLM, power that grows with N and detects a planted difference, the interval warning."""
from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from _study_data import PROTOCOL, write_protocol
from nao_trainer.core import mdp
from nao_trainer.policies.fixed import FixedSchedule
from nao_trainer.study.analysis import fit_mixed
from nao_trainer.policies.fixed import schedule_table
from nao_trainer.study.power import arm_tests, power_study
from nao_trainer.study.protocol import load_protocol
from nao_trainer.study.registry import enrol, init_study, open_study, record_session
from nao_trainer.study.runner import plan_next


def test_the_schedule_table_plays_what_the_live_schedule_plays():
    actions = ("L2", "RF1", "L3", "L1")
    table = schedule_table(actions, 12)
    live = FixedSchedule(actions)
    rng = np.random.default_rng(0)
    state = mdp.START
    for t in range(12):
        chosen = live.act(state, rng)
        assert table[t, state, chosen] == 1.0
        state = mdp.next_state(state, chosen, bool(rng.random() < 0.6))


def test_the_closed_form_test_is_the_analysis_test_on_balanced_data():
    rng = np.random.default_rng(3)
    n, sessions = 18, 2
    arms = np.repeat([0, 1, 2], 6)
    u = rng.normal(0, 3, n)  # participants differ a lot (the variance component is well away from 0)
    data = [{"participant": f"P{i}", "arm": ("a", "b", "c")[arms[i]], "session": s + 1,
             "score": 10 + 2.5 * (arms[i] == 1) + u[i] + 0.5 * s + rng.normal(0, 1.0)}
            for i in range(n) for s in range(sessions)]
    rows, notes = fit_mixed(data, "score", ("arm", "session"), "a")
    assert not notes, notes
    fitted = {r["term"]: r for r in rows}
    means = np.array([[np.mean([d["score"] for d in data if d["participant"] == f"P{i}"]) for i in range(n)]])
    tests = arm_tests(means, arms[None, :], 3, 0)
    for a, name in ((1, "b"), (2, "c")):
        diff, se, p = (float(x[0]) for x in tests[a])
        assert diff == pytest.approx(fitted[f"arm[{name}]"]["estimate"], abs=1e-6)
        assert se == pytest.approx(fitted[f"arm[{name}]"]["se"], rel=1e-6)
        assert p == pytest.approx(fitted[f"arm[{name}]"]["p"], rel=1e-6, abs=1e-9)
    assert fitted["session"]["estimate"] == pytest.approx(0.5, abs=1.0)  # the session term of MixedLM


def test_power_finds_a_large_difference_and_grows_with_n(tmp_path):
    from nao_trainer.learn.users import cluster_user_set

    protocol = load_protocol(write_protocol(tmp_path, PROTOCOL.replace("policy: random}", "policy: schedule, "
                                                                       "overrides: {policy.schedule: [L4]}}")))
    users = cluster_user_set()
    report = power_study(protocol, [6, 24], 60, 1, users, "clusters", drift=0.3)
    key = "success_rate: random vs level2"  # the arm named random plays level 4 here: far worse than level 2
    assert report.power[key][1] >= 0.95 and report.effect[key][1] < -0.3
    score = "score: random vs level2"
    assert report.effect[score][1] < -3 and report.power[score][1] > report.power[score][0]
    again = power_study(protocol, [6, 24], 60, 1, users, "clusters", drift=0.3)
    assert again.power == report.power  # seeded
    assert "N for 80 %" in report.text()


def test_two_arms_playing_the_same_policy_are_found_different_about_alpha_of_the_time(tmp_path):
    from nao_trainer.learn.users import cluster_user_set

    same = PROTOCOL.replace("policy: random}", "policy: schedule, overrides: {policy.schedule: [L2]}}")
    protocol = load_protocol(write_protocol(tmp_path, same))
    report = power_study(protocol, [30], 200, 2, cluster_user_set(), "clusters", drift=0.3)
    for outcome in ("score", "success_rate"):
        assert report.power[f"{outcome}: random vs level2"][0] <= 0.12  # alpha 0.05, 200 studies


def test_study_next_warns_outside_the_interval(tmp_path):
    init_study(write_protocol(tmp_path, PROTOCOL.replace("min: 0", "min: 2")), tmp_path / "study")
    enrol(tmp_path / "study", "2026-11-02", "v1")
    ended = dt.datetime(2026, 11, 10, 12, 0, tzinfo=dt.timezone.utc)
    record_session(tmp_path / "study", "P001", {"number": 1, "folder": "P001_x", "status": "completed",
                                                "ended": ended.isoformat()})
    study = open_study(tmp_path / "study")
    soon = plan_next(study, "P001", {}, now=ended + dt.timedelta(days=1))
    assert soon.number == 2 and "1.0 days after session 1" in soon.warning and "2-7 days" in soon.warning
    assert plan_next(study, "P001", {}, now=ended + dt.timedelta(days=3)).warning == ""
    assert "8.0 days" in plan_next(study, "P001", {}, now=ended + dt.timedelta(days=8)).warning


BAYES_VS_LEVEL2 = PROTOCOL.replace("  - {name: personalised, policy: personalised}\n", "").replace(
    "{name: random, policy: random}", "{name: bayes, policy: bayes}").replace("block_size: 6", "block_size: 4")


class _Recorded:
    """An episode policy that records what the wrapped one chose and what it was told."""

    def __init__(self, inner):
        self.inner, self.actions, self.scores = inner, [], []

    def act(self, obs, turn, rng):
        a = self.inner.act(obs, turn, rng)
        self.actions.append(np.array(a))
        return a

    def observe(self, obs, a, r, en, obs2, done):
        self.scores.append(np.array(r))
        self.inner.observe(obs, a, r, en, obs2, done)


def test_a_bayes_arm_is_simulated_by_the_bayes_planner(tmp_path, monkeypatch):
    """The bug of issue 26: every arm that was not schedule, random or usp: was simulated as the personalised
    pipeline. A bayes arm now plays the live policy's own plan: every level of session 1 is the plan's decision
    for the counts so far, and from session 2 on the posterior-best level after the carried counts."""
    from nao_trainer.core import bayes
    from nao_trainer.learn.users import cluster_user_set
    from nao_trainer.policies.bayes import BayesSessions, load_bayes
    from nao_trainer.study.power import SessionPolicies, play_sessions, user_tables

    if not bayes.available():
        pytest.skip("numba is not installed")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    protocol = load_protocol(write_protocol(tmp_path, BAYES_VS_LEVEL2))
    arm = next(a for a in protocol.arms if a.name == "bayes")
    sessions = SessionPolicies(protocol, arm)
    assert isinstance(sessions.offline, BayesSessions)
    live = load_bayes(None, "P1", sessions.turns, "score", False, None)
    assert sessions.offline.plan.fingerprint == live.plan.fingerprint  # the live policy's prior, objective, plan
    p, e = user_tables(cluster_user_set())
    rng = np.random.default_rng(4)
    for session in (1, 2):
        episode = _Recorded(sessions.start(len(p), session))
        carried = sessions.offline.carried.copy()
        play_sessions(episode, p, e, sessions.turns, rng)
        counts = np.zeros((len(p), 8), dtype=np.int64)
        for a, r in zip(episode.actions, episode.scores):
            if session == 1:
                expected = [live.plan.decide(c) - 1 for c in counts]
            else:
                expected = [int(np.argmax(np.round(bayes.posterior_weights(live.p, live.weights, c0 + c)
                                                   @ live.objective.utility(live.p), 12))) for c0, c in
                            zip(carried, counts)]
            assert a.tolist() == expected
            counts[np.arange(len(p)), 2 * a + np.where(r > 0, 0, 1)] += 1


def test_study_power_runs_a_protocol_with_a_bayes_arm(tmp_path, monkeypatch, capsys):
    import json

    from nao_trainer.cli import main

    from nao_trainer.core import bayes

    if not bayes.available():
        pytest.skip("numba is not installed")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    out = tmp_path / "power"
    code = main(["study", "power", str(write_protocol(tmp_path, BAYES_VS_LEVEL2)), "--reps", "20", "--n", "8",
                 "--users", "clusters", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    power = json.loads((out / "power.json").read_text())
    assert set(power["power"]) >= {"score: bayes vs level2", "success_rate: bayes vs level2"}


def test_type_one_error_is_five_percent_on_a_three_arm_null_with_unequal_variances():
    """No arm differs, the arms' SDs of participant means are 12.3, 7.1 and 7.1 (the random and level-2
    arms of the published data), 8 participants per arm: each contrast must reject 5 % +- 3 Monte
    Carlo SEs. A variance pooled over the arms (the old test) rejects the 7.1-vs-7.1 contrast about
    1.5 % of the time, and a normal reference rejects too often at this N."""
    rng = np.random.default_rng(11)
    reps, per = 20000, 8
    arms = np.tile(np.repeat([0, 1, 2], per), (reps, 1))
    sd = np.array([12.3, 7.1, 7.1])[arms]
    y = rng.normal(0.0, 1.0, arms.shape) * sd
    mc = 3 * np.sqrt(0.05 * 0.95 / reps)
    for a, (diff, se, p) in arm_tests(y, arms, 3, 1).items():
        assert abs(np.mean(p < 0.05) - 0.05) < mc, (a, np.mean(p < 0.05))


def test_the_multiplicity_plan_adjusts_all_but_the_primary_test():
    from nao_trainer.study.analysis import holm

    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([0.5]) == [0.5]


def test_baseline_covariate_model_and_arm_specific_variances_on_data():
    """Session 1 as covariate: an ANCOVA of the later sessions (HC2); the arms' own variances make
    the contrast between the two quiet arms narrower than a pooled variance would."""
    from nao_trainer.study.analysis import fit_baseline

    rng = np.random.default_rng(4)
    arms = np.repeat(["a", "b", "c"], 10)
    sd = {"a": 1.0, "b": 1.0, "c": 6.0}
    data = []
    for i, arm in enumerate(arms):
        u = rng.normal(0, sd[arm])
        for s in (1, 2, 3):
            data.append({"participant": f"P{i}", "arm": arm, "session": s,
                         "score": u + (1.5 if arm == "b" and s > 1 else 0.0) + rng.normal(0, 0.5)})
    rows, notes = fit_baseline(data, "score", "a")
    b = {r["term"]: r for r in rows}["arm[b]"]
    assert not notes and b["ci_low"] < 1.5 < b["ci_high"] and b["n_participants"] == 30
    own, _ = fit_mixed(data, "score", ("arm", "session"), "a", variance="arm")
    pooled, _ = fit_mixed(data, "score", ("arm", "session"), "a", variance="pooled")
    w = {r["term"]: r for r in own}["arm[b]"]
    pw = {r["term"]: r for r in pooled}["arm[b]"]
    assert w["se"] < 0.6 * pw["se"] and w["df"] < 27


NBACK_PROTOCOL = """\
protocol: {name: nback-3arm, description: three arms on n-back}
study_config: nback-base.yaml
arms:
  - {name: personalised, policy: personalised}
  - {name: bayes, policy: bayes}
  - {name: level2, policy: schedule, overrides: {policy.schedule: [L2]}}
sessions: {per_participant: 2, interval_days: {min: 0, max: 7}}
target_n: 12
allocation: {method: blocked, block_size: 6, seed: 7}
blinding: false
outcomes: {primary: score, secondary: [success_rate]}
analysis: {model: "outcome ~ arm + session + (1|participant)", reference_arm: level2}
"""


def test_an_nback_protocols_model_based_arms_are_simulated_over_the_tasks_own_users(tmp_path, monkeypatch):
    """Issue 26: under n-back the personalised arm's user models and the bayes arm's prior are the task's simulated
    users (the live policies' own, ``tasks/nback``), not the models fitted on the sequence task's data."""
    from nao_trainer.core import bayes
    from nao_trainer.policies.bayes import BayesSessions, load_bayes
    from nao_trainer.policies.personalised import PersonalisedSessions
    from nao_trainer.study.power import SessionPolicies
    from nao_trainer.tasks.nback import NBackTask

    if not bayes.available():
        pytest.skip("numba is not installed")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    (tmp_path / "nback-base.yaml").write_text("task: {name: nback}\nsession: {turns: 4, practice: false}\n"
                                              "robot: {url: mock}\n")
    (tmp_path / "protocol.yaml").write_text(NBACK_PROTOCOL)
    protocol = load_protocol(tmp_path / "protocol.yaml")
    arms = {a.name: SessionPolicies(protocol, a) for a in protocol.arms}
    names = tuple(name for name, _ in NBackTask().simulated_users())
    assert isinstance(arms["personalised"].offline, PersonalisedSessions)
    assert arms["personalised"].offline.pers.models.names == names
    assert isinstance(arms["bayes"].offline, BayesSessions) and arms["bayes"].offline.names == names
    live = load_bayes(None, "P1", 4, "score", False, None, task=NBackTask())
    assert arms["bayes"].offline.plan.fingerprint == live.plan.fingerprint  # the live n-back policy's plan


def test_study_power_on_the_nback_protocol_simulates_the_tasks_own_users(tmp_path, capsys):
    import json

    from nao_trainer.cli import main
    from nao_trainer.files import PROJECT_ROOT

    shipped = PROJECT_ROOT / "config" / "protocols" / "nback-2arm.yaml"
    out = tmp_path / "power"
    assert main(["study", "power", str(shipped), "--reps", "4", "--n", "4", "--out", str(out)]) == 0
    power = json.loads((out / "power.json").read_text())
    assert power["users"] == "task nback" and any("task nback's own simulated users" in n for n in power["notes"])
    capsys.readouterr()
    code = main(["study", "power", str(shipped), "--users", "clusters", "--reps", "4", "--n", "4",
                 "--out", str(tmp_path / "again")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert "protocol 'nback-2arm' trains task 'nback'" in err and not (tmp_path / "again").exists()
