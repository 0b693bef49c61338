"""Learning from the supervisor: overrides are learned off-policy, guidance makes them preferred, invalid turns are not learned."""
from __future__ import annotations

import numpy as np

from fakes import ScriptedAnswers
from nao_trainer.core import mdp
from nao_trainer.policies.learned import load_policy
from nao_trainer.ports import Transition
from nao_trainer.session.record import read_turns
from test_commands import make, run

L1, L4 = mdp.ACTION_NAMES.index("L1"), mdp.ACTION_NAMES.index("L4")


def guided(policy, state, action, n):
    """``n`` supervised turns toward ``action`` in ``state``, each a failure (the worst case for preference)."""
    for _ in range(n):
        policy.guide(state, action)
        policy.observe(Transition(state, action, -1, None, mdp.next_state(state, action, False)
                                  if state != mdp.START else int(mdp.NEXT_STATE[state, action, 0]), False))


def margin(values, action, state):
    others = [values[b] for b in np.flatnonzero(mdp.ACTION_MASK[state]) if b != action]
    return values[action] - max(others)


def test_a_learner_guided_n_times_toward_an_action_prefers_it_by_the_stated_margin(tmp_path):
    # The stated rule (docs/reference/console.md): with guidance g >= 1, an action the supervisor always chose in a
    # state is preferred there by at least g value points, whatever the learned values say.
    for state in (mdp.START, mdp.encode(5, 0, -2)):
        plain = load_policy("usp:2", True, tmp_path / "plain.json", guidance=0.0)
        guide = load_policy("usp:2", True, tmp_path / "guided.json", guidance=1.0)
        probs = plain.probabilities(state)
        target = int(min(np.flatnonzero(mdp.ACTION_MASK[state]), key=lambda a: probs[a]))  # the least preferred
        assert margin(plain.choice_values(state), target, state) < -1.0  # far from preferred before
        guided(plain, state, target, 5)
        guided(guide, state, target, 5)
        assert margin(plain.choice_values(state), target, state) < 0  # outcomes alone do not make it preferred
        assert margin(guide.choice_values(state), target, state) >= 1.0
        assert guide.probabilities(state)[target] == max(guide.probabilities(state))
        np.testing.assert_array_equal(guide.learner.q, plain.learner.q)  # guidance never touches Q


def test_an_override_is_executed_and_learned_off_policy_and_guidance_is_saved(tmp_path):
    policy = load_policy("usp:2", True, tmp_path / "state.json", guidance=1.0)
    q_before = policy.learner.q[mdp.START, L4]
    s, rec, path, q, _ = make(tmp_path, policy=policy, turns=2)
    q.submit("override", {"action": "L4"}, source="console")
    assert run(s, rec) == 0
    assert read_turns(path)[0]["action"] == "L4"
    assert policy.learner.q[mdp.START, L4] != q_before  # the update used the overridden action
    policy.close()
    again = load_policy("usp:2", True, tmp_path / "state.json", guidance=1.0)
    assert again.guidance.counts[mdp.START, L4] == 1 and margin(again.choice_values(mdp.START), L4, mdp.START) >= 1.0


def test_a_turn_marked_invalid_leaves_the_learner_unchanged(tmp_path):
    policy = load_policy("usp:2", True, tmp_path / "state.json")
    answers = ScriptedAnswers()
    s, rec, path, q, _ = make(tmp_path, answers=answers, policy=policy, turns=3)
    seen = {}

    def during_answer(ctx):
        seen[ctx.turn] = policy.snapshot()
        if ctx.turn == 2:
            q.submit("invalid", {"turn": 2, "note": "participant distracted"}, source="console")

    answers.on_collect = during_answer
    assert run(s, rec) == 0
    assert read_turns(path)[1]["invalid"] == "True"
    assert seen[2] == seen[3]  # nothing learned from turn 2 (turn 1 before it, turn 3 after)
    assert seen[1] != seen[2]  # while turn 1 was learned
    assert policy.payload["live"]["turns_learned"] == 2
