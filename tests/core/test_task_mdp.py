import numpy as np
import pytest

from nao_trainer.tasks.sequence import rules
from nao_trainer.core import mdp, task


def test_levels_and_lengths():
    assert [task.length_of(lv) for lv in task.LEVELS] == [3, 5, 7, 9]
    assert [task.level_of(n) for n in task.LENGTHS] == [1, 2, 3, 4]
    with pytest.raises(ValueError, match="sequence length must be one of"):
        task.level_of(4)


def test_sequences_are_seeded_and_use_abc():
    a = rules.generate_sequence(np.random.default_rng(7), 9)
    b = rules.generate_sequence(np.random.default_rng(7), 9)
    assert a == b and len(a) == 9 and set(a) <= {"A", "B", "C"}
    seqs = {rules.generate_sequence(np.random.default_rng(s), 5) for s in range(50)}
    assert len(seqs) > 40


def test_scores():
    assert [task.score(lv, True) for lv in task.LEVELS] == [1, 2, 3, 4]
    assert {task.score(lv, False) for lv in task.LEVELS} == {-1}
    assert [task.signed_score(lv, False) for lv in task.LEVELS] == [-1, -2, -3, -4]
    assert rules.is_correct(("A", "b"), ("a", "B")) and not rules.is_correct(("A", "B"), ("A",))


def test_paper_s0_index_and_roundtrip():
    assert mdp.encode(*mdp.S0) == 38
    st = mdp.decode(38)
    assert (st.length, st.feedback, st.previous) == (5, 1, -2) and st.level == 2
    assert all(mdp.decode(i).index == i for i in range(mdp.N_TURN_STATES))
    assert mdp.N_STATES == 109 and mdp.START == 108


def test_start_mask_allows_only_levels():
    assert mdp.action_mask(mdp.START).tolist() == [True] * 4 + [False] * 2
    assert mdp.action_mask(0).all()
    with pytest.raises(ValueError, match="not allowed in the start state"):
        mdp.next_state(mdp.START, mdp.ENCOURAGE, True)


def test_transitions_follow_the_paper():
    s = mdp.encode(7, 0, 2)  # a level-3 turn
    # a feedback action keeps the length, records the feedback and this turn's signed score
    assert mdp.next_state(s, mdp.ENCOURAGE, False) == mdp.encode(7, 1, -3)
    assert mdp.next_state(s, mdp.CHALLENGE, True) == mdp.encode(7, 2, 3)
    # a level action sets the length and no feedback
    assert mdp.next_state(s, 0, True) == mdp.encode(3, 0, 3)
    assert mdp.next_state(mdp.START, 3, False) == mdp.encode(9, 0, 0)
    # S0 is reached by RF1 after failing level 2
    assert mdp.next_state(mdp.encode(5, 0, 1), mdp.ENCOURAGE, False) == 38
    assert mdp.SCORE[38].tolist() == [-1, 2]


def test_reachable_states_count():
    # rf=0: 4 lengths x 9 previous results; rf>0: 4 lengths x 2 feedbacks x (+level, -level)
    assert int(mdp.REACHABLE.sum()) == 36 + 16
    assert mdp.REACHABLE[38]


def test_component_tables_and_s0_index_agree_with_decode():
    for s in range(mdp.N_TURN_STATES):
        st = mdp.decode(s)
        assert (mdp.LEVEL[s], mdp.FEEDBACK[s], mdp.PREVIOUS[s]) == (st.level, st.feedback, st.previous)
    assert mdp.S0_INDEX == mdp.encode(*mdp.S0) == 38
