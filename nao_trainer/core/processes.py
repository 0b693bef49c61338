"""The two decision processes over the task's turns: ``paper`` and ``informed``.

Pure: no I/O. Both share ``core.mdp``'s 108 turn states, actions, rewards and user tables; they
differ only in what the decision maker sees when it chooses the next action.

``paper``     the state is the turn state ``s`` of the turn just played (``core.mdp``): the outcome
              of that turn is still hidden, it shows only as the next state's previous result.
              109 states (``START`` = 108).
``informed``  the state is ``(s, o)``: the turn state *and* the outcome of the turn just played
              (the robot knows it: its feedback sentence depends on it). Index ``s * 2 + o``,
              ``START`` = 216; 217 states.

Both are views of one *full* state ``x = s * 2 + o`` (``START_FULL`` = 216): ``OBS[x]`` is what the
policy sees; ``NEXT_TURN[x, a]`` is the turn state played next after action ``a`` (-1 where the
action is not allowed); that turn's outcome ``o'`` is drawn from the user's P(success | s') and the
next full state is ``s' * 2 + o'``. The reward is ``core.mdp.SCORE[s', o']``, as in the paper.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nao_trainer.core import mdp

N_FULL = 2 * mdp.N_TURN_STATES + 1  # 217
START_FULL = N_FULL - 1  # 216
NAMES: tuple[str, ...] = ("paper", "informed")

INFORMED_DEFINITION = mdp.DEFINITION + (
    "; informed: state=(turn state, outcome of that turn); index=turn*2+outcome; START=216"
)


@dataclass(frozen=True, eq=False)
class DecisionProcess:
    """One of ``NAMES``: what the policy sees (``obs``) of the full state, and its tables."""

    name: str
    definition: str
    n_states: int
    start: int
    obs: np.ndarray  # (217,) full state -> observed state
    action_mask: np.ndarray  # (n_states, 6)

    def label(self, state: int) -> str:
        """Human-readable state label: ``(5, 1, -2)``, ``(5, 1, -2) success`` or ``START``."""
        if state == self.start:
            return "START"
        if self.name == "paper":
            return mdp.state_label(state)
        s, o = divmod(int(state), 2)
        return f"{mdp.state_label(s)} {'success' if o else 'failure'}"

    def labels(self) -> list[str]:
        return [self.label(s) for s in range(self.n_states)]

    def turn_of(self, state: np.ndarray | int) -> np.ndarray:
        """The turn state (0..107) of observed states (START maps to 108)."""
        st = np.asarray(state)
        if self.name == "paper":
            return st
        return np.where(st == self.start, mdp.START, st // 2)

    def beliefs(self, p_success: np.ndarray) -> np.ndarray:
        """(n_states, 217): P(full state | observed state) for a user with ``p_success``.

        Exact for any policy: the hidden outcome of the turn in ``s`` is drawn from p(s) alone.
        """
        b = np.zeros((self.n_states, N_FULL))
        if self.name == "paper":
            turns = np.arange(mdp.N_TURN_STATES)
            b[turns, 2 * turns] = 1.0 - p_success
            b[turns, 2 * turns + 1] = p_success
            b[mdp.START, START_FULL] = 1.0
        else:
            b[np.arange(N_FULL), np.arange(N_FULL)] = 1.0
        return b


def _build() -> tuple[np.ndarray, dict[str, DecisionProcess]]:
    nxt = np.full((N_FULL, mdp.N_ACTIONS), -1, dtype=np.int64)
    for x in range(N_FULL - 1):
        s, o = divmod(x, 2)
        nxt[x] = mdp.NEXT_STATE[s, :, o]
    nxt[START_FULL] = mdp.NEXT_STATE[mdp.START, :, 0]
    paper_obs = np.append(np.arange(N_FULL - 1) // 2, mdp.START)
    informed_mask = np.ones((N_FULL, mdp.N_ACTIONS), dtype=bool)
    informed_mask[:-1] = mdp.ACTION_MASK[np.arange(N_FULL - 1) // 2]
    informed_mask[START_FULL] = mdp.ACTION_MASK[mdp.START]
    procs = {
        "paper": DecisionProcess("paper", mdp.DEFINITION, mdp.N_STATES, mdp.START, paper_obs,
                                 mdp.ACTION_MASK),
        "informed": DecisionProcess("informed", INFORMED_DEFINITION, N_FULL, START_FULL, np.arange(N_FULL),
                                    informed_mask),
    }
    for arr in (nxt, paper_obs, informed_mask):
        arr.setflags(write=False)
    return nxt, procs


#: NEXT_TURN[x, a]: the turn state played after action a in full state x (-1 where not allowed).
NEXT_TURN, _PROCESSES = _build()


def get(name: "str | DecisionProcess") -> DecisionProcess:
    """The decision process called ``name`` (``paper`` or ``informed``); ValueError otherwise."""
    if isinstance(name, DecisionProcess):
        return name
    if name not in _PROCESSES:
        raise ValueError(f"mdp must be one of {', '.join(NAMES)}, got {name!r}")
    return _PROCESSES[name]


def by_definition(definition: str) -> DecisionProcess | None:
    """The process whose definition text is ``definition`` (None for an unknown text)."""
    return next((p for p in _PROCESSES.values() if p.definition == definition), None)
