"""Checkpoint and resumption: after each recorded turn the session writes what a resumed session
needs to continue exactly there (``--resume``), and restores it on resumption.

The checkpoint holds the counters (``Standing``), the session seconds played, the turn's row, every
random generator's state, the policy's snapshot and a pending operator override. ``Checkpointer``
is a part of ``session.engine.Session``: it touches only the recorder, the policy and the generators.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.ports import Policy
from nao_trainer.session.record import SessionRecorder


@dataclass(frozen=True)
class Standing:
    """Where the session stands after its last recorded turn."""

    completed: int = 0
    total: int = 0
    mdp_state: int = mdp.START
    last_success: bool | None = None


@dataclass(frozen=True)
class Restored:
    """What a checkpoint gives back to the session on resumption."""

    standing: Standing
    override: int | None
    elapsed_s: float
    rows: list[dict[str, Any]]


class Checkpointer:
    """Write a checkpoint per recorded turn; restore the generators and the policy from one."""

    def __init__(self, recorder: SessionRecorder, policy: Policy, rngs: dict[str, np.random.Generator]) -> None:
        self.rec = recorder
        self.policy = policy
        self.rngs = rngs  # every generator a checkpoint carries, by name

    def write(self, standing: Standing, row: dict[str, Any], elapsed_s: float, override: int | None) -> None:
        """After each recorded turn: everything a resumed session needs to continue exactly here."""
        self.rec.checkpoint({
            "completed": standing.completed, "total": standing.total, "mdp_state": standing.mdp_state,
            "last_success": standing.last_success, "elapsed_s": round(elapsed_s, 3), "row": row,
            "rng": {name: g.bit_generator.state for name, g in self.rngs.items()},
            "policy": self.policy.snapshot(), "override": override,
        })

    def restore(self, cp: dict[str, Any]) -> Restored:
        """Put the generators and the policy back as ``cp`` says; returns the counters and the rest."""
        for name, state in cp["rng"].items():
            if name in self.rngs:
                self.rngs[name].bit_generator.state = state
        self.policy.restore(cp.get("policy"))
        standing = Standing(int(cp["completed"]), int(cp["total"]), int(cp["mdp_state"]), cp["last_success"])
        return Restored(standing, cp.get("override"), float(cp.get("elapsed_s", 0.0)), list(cp.get("rows_before", [])))
