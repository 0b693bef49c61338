"""The policy ``alternate``: plays its levels in turn (``policy.alternate_levels``), through nao-trainer's seam.

Everything it needs from nao-trainer is public: the declaration (``PolicyKind``), the settings declaration
(``core.settings``), a stateless live policy's base and the offline form of a table policy.
"""
from __future__ import annotations

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.core.settings import setting, settings
from nao_trainer.policies.base import StatelessPolicy, TableSessions
from nao_trainer.policies.plugin import PolicyKind


def _levels(value: list) -> str | None:
    return None if value and all(1 <= x <= 4 for x in value) else "must list levels 1..4"


@settings
class AlternateSettings:
    alternate_levels: tuple[int, ...] = setting((1, 3), kind=list, item=int, check=_levels,
                                                doc="the levels played in turn")


class Alternate(StatelessPolicy):
    """``ports.Policy``: turn t plays level levels[t mod len]."""

    name = "alternate"

    def __init__(self, levels: tuple[int, ...]) -> None:
        self.levels = tuple(levels)
        self.turn = 0

    def act(self, state: int, rng: np.random.Generator) -> int:
        level = self.levels[self.turn % len(self.levels)]
        self.turn += 1
        return level - 1  # actions 0..3 are levels 1..4

    def probabilities(self, state: int) -> np.ndarray | None:
        out = np.zeros(mdp.N_ACTIONS)
        out[self.levels[self.turn % len(self.levels)] - 1] = 1.0
        return out

    def snapshot(self) -> dict | None:
        return {"turn": self.turn}

    def restore(self, data: dict | None) -> None:
        if data:
            self.turn = int(data["turn"])


def live(ctx) -> Alternate:
    return Alternate(ctx.settings.alternate_levels)


def offline(ctx) -> TableSessions:
    table = np.zeros((ctx.turns, mdp.N_STATES, mdp.N_ACTIONS))
    for t in range(ctx.turns):
        table[t, :, ctx.settings.alternate_levels[t % len(ctx.settings.alternate_levels)] - 1] = 1.0
    return TableSessions(table, ctx.turns)


ALTERNATE = PolicyKind("alternate", "plays its levels in turn (a lab's plug-in)", live="tiny_lab_plugins.policy:live",
                       offline="tiny_lab_plugins.policy:offline", settings=AlternateSettings)
