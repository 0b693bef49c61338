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


class StatelessPolicy:
    """Defaults of ``ports.Policy`` for a policy that does not learn: nothing to save, guide or restore."""

    def observe(self, transition: Transition) -> None:
        pass

    def bind_state_dir(self, folder: Path) -> None:
        pass  # nothing to save

    def close(self) -> None:
        pass

    def probabilities(self, state: int) -> np.ndarray | None:
        return None

    def guide(self, state: int, action: int) -> None:
        pass  # the override is played; nothing to learn

    def snapshot(self) -> dict | None:
        return None

    def restore(self, data: dict | None) -> None:
        pass

    def status(self) -> dict[str, Any]:
        return {}  # nothing to report beyond the record


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


def make_policy(spec: str, schedule: Sequence[str], learning: bool, state_path: Path | None,
                guidance: float = 0.0, fresh: bool = False, study: "StudyConfig | None" = None) -> Policy:
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
        # Beside a usp's policy_state.json in the participant's folder, unless policy.state_path names a file.
        path = state_path.with_name("personalised.json") if state_path is not None and not pol.state_path \
            else state_path
        return load_personalised(path, study.participant.pseudonym, study.session.turns, pol.assessment,
                                 float(pol.kappa), float(pol.margin), learning, fresh, guidance=guidance)
    if spec == "bayes":  # the exact Bayes-adaptive planner (policies/bayes.py)
        from nao_trainer.policies.bayes import load_bayes

        path = state_path.with_name("bayes.json") if state_path is not None and not study.policy.state_path \
            else state_path
        return load_bayes(path, study.participant.pseudonym, study.session.turns, study.policy.objective, fresh)
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
        return load_policy(spec, learning, state_path, guidance=guidance, fresh=fresh)
    raise ConfigError(f"policy {spec!r}: use 'schedule', 'random', 'personalised', 'bayes' or 'usp:CLUSTER[:METHOD]'")
