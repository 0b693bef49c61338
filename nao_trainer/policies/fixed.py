"""Policies that do not learn: a fixed schedule (``policy.kind: schedule``) and a seeded uniform one (``random``).

Both implement ``ports.Policy``; the learning ones are ``policies.learned`` and ``policies.personalised``.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from nao_trainer.core import evaluation, mdp
from nao_trainer.errors import ConfigError
from nao_trainer.policies.base import StatelessPolicy, TableSessions
from nao_trainer.policies.plugin import LiveContext, OfflineContext


class FixedSchedule(StatelessPolicy):
    """Plays a list of actions in order, cycling when the session is longer.

    A feedback action is replaced by the first level action of the schedule in ``START`` (where
    there is no outcome to give feedback on); the schedule validator rejects such a first entry.
    """

    name = "schedule"

    def __init__(self, actions: Sequence[str]) -> None:
        if not actions:
            raise ConfigError("policy.schedule: the schedule needs at least one action")
        self.actions = tuple(self._action_index(a) for a in actions)
        self._i = 0

    @staticmethod
    def _action_index(a: str) -> int:
        if a not in mdp.ACTION_NAMES:
            raise ConfigError(f"policy.schedule: unknown action {a!r}; use {', '.join(mdp.ACTION_NAMES)}")
        return mdp.ACTION_NAMES.index(a)

    def act(self, state: int, rng: np.random.Generator) -> int:
        action = self.actions[self._i % len(self.actions)]
        self._i += 1
        if not mdp.ACTION_MASK[state, action]:
            return next(a for a in self.actions if mdp.ACTION_MASK[state, a])
        return action

    def probabilities(self, state: int) -> np.ndarray | None:
        return _one_hot(state, self.actions[self._i % len(self.actions)])

    def snapshot(self) -> dict | None:
        return {"next": self._i}

    def restore(self, data: dict | None) -> None:
        self._i = int((data or {}).get("next", 0))


def _one_hot(state: int, action: int) -> np.ndarray:
    probs = np.zeros(mdp.N_ACTIONS)
    probs[action if mdp.ACTION_MASK[state, action] else int(np.flatnonzero(mdp.ACTION_MASK[state])[0])] = 1.0
    return probs


class UniformRandom(StatelessPolicy):
    """Uniform over the allowed actions of the state, drawn with the session's generator.

    This is how the published data were explored: every action equally likely.
    """

    name = "random"

    def act(self, state: int, rng: np.random.Generator) -> int:
        allowed = np.flatnonzero(mdp.ACTION_MASK[state])
        return int(allowed[rng.integers(len(allowed))])

    def probabilities(self, state: int) -> np.ndarray | None:
        return mdp.ACTION_MASK[state] / mdp.ACTION_MASK[state].sum()


def schedule_table(actions: Sequence[str], turns: int) -> np.ndarray:
    """``FixedSchedule`` as a per-turn table: turn t plays actions[t mod len], or where it is not
    allowed, the first allowed action of the schedule."""
    idx = [mdp.ACTION_NAMES.index(a) for a in actions]
    table = np.zeros((turns, mdp.N_STATES, mdp.N_ACTIONS))
    for t in range(turns):
        a = idx[t % len(idx)]
        for s in range(mdp.N_STATES):
            ok = a if mdp.ACTION_MASK[s, a] else next(b for b in idx if mdp.ACTION_MASK[s, b])
            table[t, s, ok] = 1.0
    return table


# -- the plug-ins' entry points (policies.kinds) ------------------------------------------------------


def live_schedule(ctx: LiveContext) -> FixedSchedule:
    return FixedSchedule(list(ctx.settings.schedule))


def live_random(ctx: LiveContext) -> UniformRandom:
    return UniformRandom()


def offline_schedule(ctx: OfflineContext) -> TableSessions:
    """Exactly as the live schedule chooses."""
    return TableSessions(schedule_table(tuple(ctx.settings.schedule), ctx.turns), ctx.turns)


def offline_random(ctx: OfflineContext) -> TableSessions:
    """Exactly as the live uniform choice (over the allowed actions)."""
    return TableSessions(evaluation.uniform_policy(), ctx.turns)
