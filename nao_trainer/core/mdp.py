"""The training task as a Markov decision process (paper section 3.2, Table 2).

Pure: no I/O. Everything the learners and simulators need is precomputed here as numpy tables.

States
    A *turn state* ``s = (L, RF, PR)`` describes a turn about to be played: its sequence length
    ``L`` in {3, 5, 7, 9}, the robot feedback ``RF`` spoken just before it (0 none, 1 encouraging,
    2 challenging) and the previous result ``PR`` in -4..4, the signed score (+level / -level) of
    the turn before (0 on the first turn). These are the ``state_EEG`` rows of the published data
    and the states on which a user's P(success | state) and engagement are defined.
    There are 4 x 3 x 9 = 108 turn states plus ``START`` (no turn played yet), 109 in all::

        index(L, RF, PR) = (level(L) - 1) * 27 + RF * 9 + (PR + 4)        START = 108

    The paper's S0 = (5, 1, -2) ("level 2, encouraging feedback given after the user failed
    level 2 on the previous turn") is index 1*27 + 1*9 + 2 = 38.

Actions
    ``0..3`` = L1..L4 (play a new sequence of that level, no feedback), ``4`` = RF1 (encouraging
    feedback on the last outcome, then a new sequence of the *same* length), ``5`` = RF2
    (challenging feedback, same length). In ``START`` only the level actions are allowed
    (``action_mask``). The numbering matches the ``action`` column of the published tables.

Transitions
    The agent chooses ``a`` in the state ``s`` of the turn just played; that turn's outcome ``o``
    (0 failure, 1 success) is drawn from the user's P(success | s). The next turn state is the
    deterministic ``NEXT_STATE[s, a, o] = (L', RF', signed score of the turn in s)`` where
    ``L' = length(a)`` for a level action and ``L' = L`` for a feedback action, ``RF' = 0`` for a
    level action and 1 or 2 for a feedback action. From ``START`` the first turn is ``(L', 0, 0)``.

Reward
    The paper's equation (1) for the turn played in the next state: ``SCORE[s', o']`` = +level on
    success, -1 on failure. Engagement, when used, is that turn's engagement.

Episode end
    A session has a fixed number of turns (25 in the paper and the published data).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nao_trainer.core.task import LENGTHS, length_of, level_of, score, signed_score

FEEDBACKS: tuple[int, ...] = (0, 1, 2)
PREVIOUS_RESULTS: tuple[int, ...] = tuple(range(-4, 5))

N_TURN_STATES = len(LENGTHS) * len(FEEDBACKS) * len(PREVIOUS_RESULTS)  # 108
START = N_TURN_STATES  # 108
N_STATES = N_TURN_STATES + 1  # 109

ACTION_NAMES: tuple[str, ...] = ("L1", "L2", "L3", "L4", "RF1", "RF2")
N_ACTIONS = len(ACTION_NAMES)
LEVEL_ACTIONS: tuple[int, ...] = (0, 1, 2, 3)
ENCOURAGE, CHALLENGE = 4, 5

#: A text that identifies this state/action definition; stored with policies and simulators so a
#: file made for another definition is refused.
DEFINITION = (
    "turn-state=(L in 3,5,7,9; RF in 0,1,2; PR in -4..4); "
    "index=(level-1)*27+RF*9+PR+4; START=108; actions=L1,L2,L3,L4,RF1,RF2; reward=eq1(+level/-1)"
)


@dataclass(frozen=True)
class State:
    """A turn state (L, RF, PR); see the module docstring."""

    length: int
    feedback: int
    previous: int

    def __post_init__(self) -> None:
        level_of(self.length)
        if self.feedback not in FEEDBACKS:
            raise ValueError(f"robot feedback must be 0, 1 or 2, got {self.feedback!r}")
        if self.previous not in PREVIOUS_RESULTS:
            raise ValueError(f"previous result must be in -4..4, got {self.previous!r}")

    @property
    def level(self) -> int:
        return level_of(self.length)

    @property
    def index(self) -> int:
        return encode(self.length, self.feedback, self.previous)


def encode(length: int, feedback: int, previous: int) -> int:
    """Index of the turn state (L, RF, PR); raises ValueError naming a bad component."""
    State(length, feedback, previous)
    return (level_of(length) - 1) * 27 + feedback * 9 + (previous + 4)


def decode(index: int) -> State:
    """The turn state of an index in 0..107 (``START`` has no turn state)."""
    if not 0 <= int(index) < N_TURN_STATES:
        raise ValueError(f"turn-state index must be in 0..{N_TURN_STATES - 1}, got {index!r}")
    level, rest = divmod(int(index), 27)
    feedback, prev = divmod(rest, 9)
    return State(LENGTHS[level], feedback, prev - 4)


#: The state the paper's Figure 8 shows policies for, and its index (38).
S0 = (5, 1, -2)
S0_INDEX = encode(*S0)


def action_mask(state: int) -> np.ndarray:
    """Boolean mask of the allowed actions (only level actions in ``START``)."""
    return ACTION_MASK[state].copy()


def next_state(state: int, action: int, success: bool) -> int:
    """Index of the next turn state after ``action`` in ``state`` whose turn had ``success``."""
    nxt = int(NEXT_STATE[state, action, int(bool(success))])
    if nxt < 0:
        raise ValueError(f"action {ACTION_NAMES[action]} is not allowed in the start state")
    return nxt


def _build_tables() -> tuple[np.ndarray, ...]:
    mask = np.ones((N_STATES, N_ACTIONS), dtype=bool)
    mask[START, [ENCOURAGE, CHALLENGE]] = False
    nxt = np.full((N_STATES, N_ACTIONS, 2), -1, dtype=np.int64)
    scores = np.zeros((N_TURN_STATES, 2), dtype=np.int64)
    signed = np.zeros((N_TURN_STATES, 2), dtype=np.int64)
    levels = np.zeros(N_TURN_STATES, dtype=np.int64)
    feedback = np.zeros(N_TURN_STATES, dtype=np.int64)
    previous = np.zeros(N_TURN_STATES, dtype=np.int64)
    reachable = np.zeros(N_TURN_STATES, dtype=bool)
    for s in range(N_TURN_STATES):
        st = decode(s)
        levels[s], feedback[s], previous[s] = st.level, st.feedback, st.previous
        for o in (0, 1):
            scores[s, o] = score(st.level, bool(o))
            signed[s, o] = signed_score(st.level, bool(o))
            for a in LEVEL_ACTIONS:
                nxt[s, a, o] = encode(length_of(a + 1), 0, signed[s, o])
            nxt[s, ENCOURAGE, o] = encode(st.length, 1, signed[s, o])
            nxt[s, CHALLENGE, o] = encode(st.length, 2, signed[s, o])
        first_turn = st.feedback == 0 and st.previous == 0
        after_level = st.feedback == 0 and st.previous != 0
        after_feedback = st.feedback > 0 and abs(st.previous) == st.level
        reachable[s] = first_turn or after_level or after_feedback
    for a in LEVEL_ACTIONS:
        nxt[START, a, :] = encode(length_of(a + 1), 0, 0)
    for table in (mask, nxt, scores, signed, levels, feedback, previous, reachable):
        table.setflags(write=False)
    return mask, nxt, scores, signed, levels, feedback, previous, reachable


#: ACTION_MASK[s, a]: action a allowed in state s.
#: NEXT_STATE[s, a, o]: next turn state (-1 where not allowed).
#: SCORE[s, o]: equation (1) for the turn played in turn state s with outcome o.
#: SIGNED_SCORE[s, o]: +level / -level (the next state's previous result).
#: LEVEL[s], FEEDBACK[s], PREVIOUS[s]: level (1..4), robot feedback RF and previous result PR of turn state s.
#: REACHABLE[s]: the state can occur in a session.
ACTION_MASK, NEXT_STATE, SCORE, SIGNED_SCORE, LEVEL, FEEDBACK, PREVIOUS, REACHABLE = _build_tables()


def state_label(index: int) -> str:
    """Human-readable label, e.g. ``(5, 1, -2)`` or ``START``."""
    if index == START:
        return "START"
    st = decode(index)
    return f"({st.length}, {st.feedback}, {st.previous})"
