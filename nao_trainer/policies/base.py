"""What every live policy shares: the stateless defaults and the supervisor's guidance.

**Guidance.** A supervisor's override toward action ``a`` in state ``s`` is counted, ``n(s, a)``.
With weight ``g`` (``policy.guidance``) the counts become extra value for whatever plays the
overridden actions::

    G(s) = g * share(s) * (max V - min V + 1),   share(s) = sum_a pi(a | s) n(s, a) / n(s)

where ``V`` are the values the policy chooses among in ``s`` (a learner's action values over the
allowed actions, or the personaliser's candidates' expected values) and ``pi`` what each choice
plays (an action plays itself: ``share = n(s, .) / n(s)``). Scaled by the spread of the values,
it means the same in every state: with ``g >= 1`` an action (or a candidate that always plays
it) the supervisor always chose in ``s`` is preferred there by at least ``g`` value points. The
learners' tables learn only from outcomes (off-policy); guidance changes the choice, not them.

Where a participant's state lives, and its set-aside on ``--fresh-policy``: ``policies.participant_state``.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nao_trainer.core import evaluation, mdp, processes
from nao_trainer.ports import Transition

#: Notices for the user (a returning participant, a state set aside); shown on stderr by Python's
#: last-resort handler when nothing else is configured, like the adapters' warnings.
log = logging.getLogger("nao_trainer.policies")


class Guidance:
    """The supervisor's overrides ``n(s, a)`` and their weight ``g`` (the rule of the module docstring)."""

    def __init__(self, weight: float, counts: np.ndarray | None = None) -> None:
        self.weight = float(weight)
        self.counts = np.zeros((mdp.N_STATES, mdp.N_ACTIONS), dtype=np.int64) if counts is None else \
            np.array(counts, dtype=np.int64)

    def record(self, state: int, action: int) -> None:
        self.counts[state, action] += 1

    def active(self, state: int) -> bool:
        """Whether guidance changes the choice in ``state`` (a weight, and an override there)."""
        return bool(self.weight and self.counts[state].any())

    def bonus(self, state: int, values: np.ndarray, plays: Sequence[np.ndarray] | None = None) -> np.ndarray | None:
        """``G(s)``: per action (``plays`` None) or per choice (``plays[c]`` = what choice c plays in
        ``state``), spread over ``values``; None when guidance does not change the choice here."""
        n = self.counts[state]
        total = n.sum()
        if not (self.weight and total):
            return None
        share = n / total if plays is None else np.array([row @ n for row in plays]) / total
        return self.weight * share * (float(values.max() - values.min()) + 1.0)

    def pairs(self) -> dict[str, int]:
        """The counts as ``{"s,a": n}`` over the pairs guided at least once (the policy file's form)."""
        return {f"{s},{a}": int(self.counts[s, a]) for s, a in zip(*np.nonzero(self.counts))}

    @classmethod
    def from_pairs(cls, weight: float, pairs: dict[str, int] | None) -> "Guidance":
        guidance = cls(weight)
        for key, n in (pairs or {}).items():
            s, a = (int(x) for x in key.split(","))
            guidance.counts[s, a] = int(n)
        return guidance


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


class TableSessions:
    """The offline form of a policy that is a table (per turn or not): the same table every session
    (``policies.plugin``: ``start(n, session)`` returns a ``core.evaluation.EpisodePolicy``)."""

    def __init__(self, table: np.ndarray, turns: int) -> None:
        self.table = np.asarray(table, dtype=float)
        self.turns = int(turns)

    def start(self, n: int, session: int) -> Any:
        policy = evaluation.TablePolicy(self.table)
        policy.reset(n, processes.get("paper"))
        return policy
