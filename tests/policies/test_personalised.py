"""The live personalised policy: the participant's state across sessions, and what it refuses."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import mdp, task
from nao_trainer.errors import DataError
from nao_trainer.policies import personalised
from nao_trainer.ports import Transition


def load(out, fresh=False, turns=8):
    return personalised.load_personalised(personalised.participant_file(out, "p01"), "p01", turns, (2, 3, 4), 10.0,
                                          0.5, True, fresh)


def play(policy, successes, seed=0):
    """A session without a robot: the policy acts, the outcomes are given, it observes."""
    rng = np.random.default_rng(seed)
    state, last, levels, phases = mdp.START, False, [], []
    for i, ok in enumerate(successes):
        a = policy.act(state, rng)
        phases.append(policy.status()["phase"])
        nxt = int(mdp.NEXT_STATE[mdp.START, a, 0]) if state == mdp.START else mdp.next_state(state, a, last)
        level = int(mdp.LEVEL[nxt])
        levels.append(level)
        policy.observe(Transition(state, a, task.score(level, ok), None, nxt, i == len(successes) - 1))
        state, last = nxt, ok
    policy.close()
    return levels, phases


def test_state_persists_across_two_sessions(tmp_path):
    first = load(tmp_path)
    shipped_q = [lr.q.copy() for _c, lr in first.learners]
    levels, phases = play(first, [True, True, False, True, True, True, False, True])
    assert levels[:3] == [2, 3, 4] and phases[:3] == ["assessment"] * 3 and phases[3] == "personalised"
    path = tmp_path / "participants" / "p01" / "personalised.json"
    saved = personalised.read_state(path, first.fingerprint)
    assert len(saved["sessions"]) == 1 and saved["sessions"][0]["turns"] == 8 and sum(saved["played"]) == 8
    assert any(not np.allclose(q, lr.q) for q, (_c, lr) in zip(shipped_q, first.learners))  # the learners learned

    second = load(tmp_path)  # starts where the first ended, without an assessment
    assert second.pers.schedule == ()
    assert np.allclose(second.pers.log_w, first.pers.log_w) and np.allclose(second.pers.wins, first.pers.wins)
    for (_c, a), (_d, b) in zip(first.learners, second.learners):
        assert np.array_equal(a.q, b.q) and np.array_equal(a.visits, b.visits)
    _levels, phases = play(second, [True] * 5, seed=1)
    assert "assessment" not in phases
    saved = personalised.read_state(path, second.fingerprint)
    assert len(saved["sessions"]) == 2 and sum(saved["played"]) == 13
    assert saved["sessions"][1]["matched"] in second.models.names


def one_line(exc):
    return "\n" not in str(exc.value) and "--fresh-policy" in str(exc.value)


def test_foreign_or_corrupt_state_is_refused_in_one_line_and_fresh_keeps_it(tmp_path):
    policy = load(tmp_path)
    play(policy, [True, False, True])
    path = tmp_path / "participants" / "p01" / "personalised.json"
    good = personalised.PARTICIPANT_FILE.read(path, DataError)

    personalised.PARTICIPANT_FILE.write(path, {**good, "mdp_definition": "another definition"})
    with pytest.raises(DataError, match="another MDP") as exc:
        load(tmp_path)
    assert one_line(exc)

    personalised.PARTICIPANT_FILE.write(path, {**good, "models_fingerprint": "0" * 64})
    with pytest.raises(DataError, match="other user models") as exc:
        load(tmp_path)
    assert one_line(exc)

    torn = path.read_text()[:200]
    path.write_text(torn)
    with pytest.raises(DataError, match="not valid JSON") as exc:
        load(tmp_path)
    assert one_line(exc)

    fresh = load(tmp_path, fresh=True)  # the torn file is kept beside, the new state starts from the prior
    kept = list(path.parent.glob("personalised.json.replaced-*"))
    assert len(kept) == 1 and kept[0].read_text() == torn and not path.exists()
    assert fresh.pers.schedule == (2, 3, 4) and np.allclose(fresh.pers.posterior()[0], fresh.models.prior)


def test_participants_of_different_ability_get_different_levels_on_average():
    """Over 300 simulated sessions with the shipped models and policies: the strong participant
    (best level 4) gets level 4 after the assessment, the weak one (best level 2) does not."""
    from nao_trainer.core import evaluation
    from nao_trainer.files import PROJECT_ROOT
    from nao_trainer.learn.artifacts import load_simulator_file

    visits = {}
    for who in ("level2", "level4"):
        policy = personalised.load_personalised(None, who, 25, (2, 2, 3, 3, 4, 4), 10.0, 0.5, False, False)
        truth = load_simulator_file(PROJECT_ROOT / "sim" / "participants" / f"{who}.json")
        visits[who] = evaluation.monte_carlo(policy.pers, truth.p_success, truth.engagement, 300,
                                             np.random.default_rng(0)).visits
    assert visits["level2"][3] < 2.5 and visits["level4"][3] > 6.0  # 2 level-4 turns are the assessment's
    assert visits["level2"][1] > 18


def test_guidance_feeds_in_and_a_snapshot_restores():
    guided = personalised.load_personalised(None, "g", 25, (), 10.0, 0.5, True, False, guidance=1.0)
    plain = personalised.load_personalised(None, "g", 25, (), 10.0, 0.5, True, False, guidance=0.0)
    rng = np.random.default_rng(0)
    for pol in (guided, plain):
        for _ in range(5):
            pol.guide(mdp.START, 3)  # the supervisor started with level 4, five times
    assert [guided.act(mdp.START, rng) for _ in range(5)] == [3] * 5  # guidance 1: preferred
    assert plain.act(mdp.START, rng) != 3  # guidance 0: the posterior choice (level 2 here)
    assert guided.status()["following"] == "fixed:4"
    # A checkpoint's snapshot restores the whole state in a new policy.
    play(plain, [True, False, True, True], seed=2)
    snap = plain.snapshot()
    other = personalised.load_personalised(None, "g", 25, (), 10.0, 0.5, True, False)
    other.restore(snap)
    assert np.allclose(other.pers.log_w, plain.pers.log_w) and other.turn == plain.turn == 4
    assert other.status()["following"] == plain.status()["following"]
    for (_c, a), (_d, b) in zip(plain.learners, other.learners):
        assert np.array_equal(a.q, b.q)


def test_a_state_belongs_to_its_pseudonym(tmp_path):
    first = load(tmp_path)
    play(first, [True] * 4)
    own = personalised.participant_file(tmp_path, "p01")
    assert personalised.read_state(own, first.fingerprint, "p01")["pseudonym"] == "p01"
    other = personalised.participant_file(tmp_path, "p02")
    other.parent.mkdir(parents=True)
    other.write_bytes(own.read_bytes())  # p01's file copied into p02's folder
    with pytest.raises(DataError) as exc:
        personalised.load_personalised(other, "p02", 8, (2, 3, 4), 10.0, 0.5, True, False)
    assert one_line(exc) and "'p01', not of 'p02'" in str(exc.value)
    fresh = personalised.load_personalised(other, "p02", 8, (2, 3, 4), 10.0, 0.5, True, True)  # --fresh-policy
    assert fresh.pers.schedule == (2, 3, 4) and list(other.parent.glob("personalised.json.replaced-*"))
