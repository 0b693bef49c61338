"""Gymnasium environment of a simulated participant (optional extra: ``pip install nao-trainer[gym]``).

Importing this module registers ``"NaoTrainer/SequenceLearning-v0"``::

    import gymnasium, nao_trainer.learn.gym_env
    env = gymnasium.make("NaoTrainer/SequenceLearning-v0", simulator="1")  # cluster 1 of sim/models

The rest of nao-trainer never imports gymnasium.
"""
from __future__ import annotations

from typing import Any

import numpy as np

try:
    import gymnasium as gym
    from gymnasium import spaces
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "nao_trainer.learn.gym_env needs gymnasium: pip install 'nao-trainer[gym]' (or pip install gymnasium)"
    ) from exc

from nao_trainer.core import mdp, processes
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.learn.artifacts import load_simulator

ENV_ID = "NaoTrainer/SequenceLearning-v0"


class SequenceLearningEnv(gym.Env):
    """The sequence-learning session as seen by the robot's decision maker.

    ## Description
    A participant hears a sequence of 3/5/7/9 letters (levels 1-4) and repeats it; before a
    sequence the robot may give encouraging or challenging feedback on the last outcome. The
    participant is a fitted ``UserSimulator``: P(success | state) and engagement Phi(state, outcome)
    (Tsiakas et al. 2018, section 5.1). Each step plays one turn.

    ## Action Space
    ``Discrete(6)``: 0-3 = L1..L4 (new sequence of that level, no feedback), 4 = RF1
    (encouraging feedback, then a sequence of the same length), 5 = RF2 (challenging feedback,
    same length). In the start state only 0-3 are allowed (``info["action_mask"]``); a feedback
    action taken there anyway is played as L1 and flagged with ``info["invalid_action"] = True``.

    ## Observation Space
    ``Discrete(109)``: the index of the turn state (L, RF, PR) just played,
    ``(level-1)*27 + RF*9 + PR+4`` (``nao_trainer.core.mdp.decode``), or 108 = START before the
    first turn. The played turn's outcome is hidden: it shows only as the next state's PR.
    With ``mdp="informed"``: ``Discrete(217)``, the turn state and its outcome, ``index * 2 + outcome``
    (``nao_trainer.core.processes``), START = 216.

    ## Starting State
    Always START (108; 216 in the informed MDP).

    ## Rewards
    The paper's equation (1) for the turn just played: +level on success, -1 on failure.
    ``info["engagement"]`` holds Phi(state, outcome) of that turn (for reward shaping).

    ## Episode End
    Terminated after ``turns`` turns (25 in the paper and the published data); never truncated.

    ## Information
    ``action_mask`` (bool[6]) for the new observation, ``engagement``, ``success``, ``turn``,
    ``score`` (signed +level/-level), ``level``, ``invalid_action``.

    ## Arguments
    ``simulator``: a ``UserSimulator`` or a spec for ``nao_trainer.learn.artifacts.load_simulator``
    (cluster id or JSON path); ``turns``: episode length; ``render_mode``: None or ``"ansi"``;
    ``mdp``: ``"paper"`` (default) or ``"informed"`` (``nao_trainer.core.processes``).
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(self, simulator: UserSimulator | str = "1", turns: int = 25, render_mode: str | None = None,
                 mdp: str = "paper"):
        self.process = processes.get(mdp)
        if isinstance(simulator, str):
            simulator = load_simulator(simulator)
        if not isinstance(simulator, UserSimulator):
            raise TypeError(f"simulator must be a UserSimulator or a model spec, got {type(simulator).__name__}")
        if not isinstance(turns, (int, np.integer)) or turns < 1:
            raise ValueError(f"turns must be a positive integer, got {turns!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'ansi', got {render_mode!r}")
        self.simulator = simulator
        self.turns = int(turns)
        self.render_mode = render_mode
        self.observation_space = spaces.Discrete(self.process.n_states)
        self.action_space = spaces.Discrete(self.process.action_mask.shape[1])  # the parameter `mdp` hides the module here
        self.state = self.process.start
        self._full = processes.START_FULL
        self.turn = 0
        self._success = False
        self._last: dict[str, Any] = {}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[int, dict[str, Any]]:
        super().reset(seed=seed)
        self.state = self.process.start
        self._full = processes.START_FULL
        self.turn = 0
        self._success = False
        self._last = {}
        return self.state, {"action_mask": self.process.action_mask[self.state].copy(), "turn": 0}

    def step(self, action: int) -> tuple[int, float, bool, bool, dict[str, Any]]:
        if self.turn >= self.turns:
            raise RuntimeError("episode is over: call reset()")
        a = int(action)
        if not 0 <= a < mdp.N_ACTIONS:
            raise ValueError(f"action must be in 0..{mdp.N_ACTIONS - 1}, got {action!r}")
        invalid = not self.process.action_mask[self.state, a]
        if invalid:
            a = 0
        nxt = int(processes.NEXT_TURN[self._full, a])
        success = self.simulator.sample_success(nxt, self.np_random)
        self._full = 2 * nxt + int(success)
        self.state, self._success = int(self.process.obs[self._full]), success
        self.turn += 1
        reward = float(mdp.SCORE[nxt, int(success)])
        info = {
            "action_mask": self.process.action_mask[self.state].copy(),
            "engagement": self.simulator.engagement_of(nxt, success),
            "success": success,
            "turn": self.turn,
            "score": int(mdp.SIGNED_SCORE[nxt, int(success)]),
            "level": int(mdp.LEVEL[nxt]),
            "invalid_action": invalid,
        }
        self._last = {"action": mdp.ACTION_NAMES[a], **info}
        return self.state, reward, self.turn >= self.turns, False, info

    def render(self) -> str | None:
        if self.render_mode != "ansi":
            return None
        if not self._last:
            return f"turn 0/{self.turns}: START"
        d = self._last
        return (f"turn {d['turn']}/{self.turns}: {d['action']} -> state {self.process.label(self.state)} "
                f"{'success' if d['success'] else 'failure'} score {d['score']:+d} engagement {d['engagement']:.2f}")


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point=f"{__name__}:SequenceLearningEnv")
