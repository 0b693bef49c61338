"""Policies the session can follow without learning: a fixed schedule and a seeded uniform one.

Both implement ``ports.Policy``. Learned, user-specific policies (``usp:CLUSTER[:METHOD]``) come
from ``nao_trainer.learn.usp``, the personalised pipeline (``personalised``) from
``nao_trainer.learn.personalised``; both are imported only when asked for.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.errors import ConfigError
from nao_trainer.ports import Policy, Transition

if TYPE_CHECKING:
    from nao_trainer.session.config import StudyConfig


class FixedSchedule:
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

    def observe(self, transition: Transition) -> None:
        pass

    def bind_state_dir(self, folder: Path) -> None:
        pass  # nothing to save

    def status(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


class UniformRandom:
    """Uniform over the allowed actions of the state, drawn with the session's generator.

    This is how the published data were explored: every action equally likely.
    """

    name = "random"

    def act(self, state: int, rng: np.random.Generator) -> int:
        allowed = np.flatnonzero(mdp.ACTION_MASK[state])
        return int(allowed[rng.integers(len(allowed))])

    def observe(self, transition: Transition) -> None:
        pass

    def bind_state_dir(self, folder: Path) -> None:
        pass  # nothing to save

    def status(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


def make_policy(spec: str, schedule: Sequence[str], learning: bool, state_path: Path | None,
                study: "StudyConfig | None" = None) -> Policy:
    """The policy named by ``spec``: "schedule", "random", "usp:CLUSTER[:METHOD]" or "personalised"
    (which needs the ``study``: participant, output folder, turns and its ``policy`` settings)."""
    if spec == "personalised":
        if study is None:
            raise ConfigError("policy 'personalised' needs the study configuration")
        try:
            from nao_trainer.learn.personalised import load_personalised
        except ImportError as exc:
            raise ConfigError(f"policy {spec!r}: learned policies are not available in this install ({exc}); "
                              "use --policy schedule or random") from None
        pol = study.policy
        return load_personalised(study.output_dir(), study.participant.pseudonym, study.session.turns,
                                 pol.assessment, float(pol.kappa), float(pol.margin), learning, pol.fresh)
    if spec == "schedule":
        return FixedSchedule(schedule)
    if spec == "random":
        return UniformRandom()
    if spec.startswith("usp:"):
        try:
            from nao_trainer.learn.usp import load_policy
        except ImportError as exc:
            raise ConfigError(f"policy {spec!r}: learned policies are not available in this install ({exc}); "
                              "use --policy schedule or random") from None
        return load_policy(spec, learning, state_path)
    raise ConfigError(f"policy {spec!r}: use 'schedule', 'random', 'personalised' or 'usp:CLUSTER[:METHOD]'")
