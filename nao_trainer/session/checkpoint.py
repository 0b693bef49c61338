"""Checkpoint and resumption: after each recorded turn the session writes what a resumed session
needs to continue exactly there (``--resume``), and restores it on resumption.

The checkpoint holds the counters, the MDP state, the last outcome, the session seconds played,
the turn's row, every random generator's state, the policy's snapshot and a pending operator
override. ``Checkpoints`` is a part of ``session.engine.Session``.
"""
from __future__ import annotations

from typing import Any

import numpy as np


class Checkpoints:
    """Write a checkpoint per recorded turn; resume from one."""

    _rngs: dict[str, np.random.Generator]  # every generator a checkpoint carries, by name
    _resume: dict[str, Any] | None  # the checkpoint to resume from, until it is used
    _elapsed_before: float  # session seconds played before a resumption
    # the session's, used here
    completed: int
    total: int
    mdp_state: int
    last_success: bool | None
    rows: list[dict[str, Any]]
    _override: int | None
    _reason: str | None
    _t0: float
    rec: Any
    policy: Any
    monitor: Any
    stage: Any
    clock: Any
    behaviors: Any

    def _init_checkpoints(self, rngs: dict[str, np.random.Generator], resume: dict[str, Any] | None) -> None:
        self._rngs = rngs
        self._resume = resume
        self._elapsed_before = 0.0

    def _checkpoint(self, row: dict[str, Any]) -> None:
        """After each recorded turn: everything a resumed session needs to continue exactly here."""
        self.rec.checkpoint({
            "completed": self.completed, "total": self.total, "mdp_state": self.mdp_state,
            "last_success": self.last_success, "elapsed_s": round(self.elapsed_s(), 3), "row": row,
            "rng": {name: g.bit_generator.state for name, g in self._rngs.items()},
            "policy": self.policy.snapshot(), "override": self._override,
        })

    def _resume_from_checkpoint(self) -> str:
        """A resumed session: restore the state of the last completed turn and go to the next turn."""
        cp, self._resume = self._resume, None
        assert cp is not None
        for name, state in cp["rng"].items():
            if name in self._rngs:
                self._rngs[name].bit_generator.state = state
        self.policy.restore(cp.get("policy"))
        self.completed, self.total = int(cp["completed"]), int(cp["total"])
        self.mdp_state, self.last_success = int(cp["mdp_state"]), cp["last_success"]
        self._override = cp.get("override")
        self._elapsed_before = float(cp.get("elapsed_s", 0.0))
        self._t0 = self.clock.now()
        self.rows = list(cp.get("rows_before", []))
        self.rec.event("resumed", after_turn=self.completed, total=self.total, elapsed_s=self._elapsed_before)
        self.monitor.mark("session_resumed")
        self.stage.posture(self.behaviors.start_posture)
        # An utterance the uninterrupted session did not have: its own generator, not the session's.
        self.stage.say("resumed", behavior="greeting", rng=np.random.default_rng(self.completed))
        self._reason = f"resumed after turn {self.completed}"
        return "resume_session"
