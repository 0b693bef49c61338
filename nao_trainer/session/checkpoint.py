"""Checkpoint and resumption: after each recorded turn the session writes what a resumed session
needs to continue exactly there (``--resume``), and restores it on resumption.

The checkpoint holds the counters (``Standing``), the session seconds played, the turn's row, every
random generator's state, the policy's snapshot and a pending operator override. ``Checkpointer``
is a part of ``session.engine.Session``: it touches only the recorder, the policy and the generators.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from nao_trainer.core import mdp, task
from nao_trainer.core.settings import short
from nao_trainer.ports import Policy, Transition
from nao_trainer.session.record import TURN_COLUMNS, SessionRecorder

#: The largest score one turn can bring or cost (equation (1)): bounds a checkpoint's total.
MAX_TURN_SCORE = max(abs(task.score(level, ok)) for level in task.LEVELS for ok in (True, False))


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

    def write(self, standing: Standing, row: dict[str, Any], elapsed_s: float, override: int | None,
              learn: Transition | None = None) -> None:
        """After each recorded turn: everything a resumed session needs to continue exactly here.

        ``learn``: the turn's transition when the policy has not observed it yet (the turn is written
        before the participant's learning state, so a failed state save loses no turn); a resumption
        hands it to the policy after restoring the snapshot.
        """
        self.rec.checkpoint({
            "completed": standing.completed, "total": standing.total, "mdp_state": standing.mdp_state,
            "last_success": standing.last_success, "elapsed_s": round(elapsed_s, 3), "row": row,
            "rng": {name: g.bit_generator.state for name, g in self.rngs.items()},
            "policy": self.policy.snapshot(), "override": override,
            "learn": None if learn is None else asdict(learn),
        })

    def restore(self, cp: dict[str, Any]) -> Restored:
        """Put the generators and the policy back as ``cp`` says; returns the counters and the rest."""
        for name, state in cp["rng"].items():
            if name in self.rngs:
                self.rngs[name].bit_generator.state = state
        self.policy.restore(cp.get("policy"))
        if cp.get("learn"):  # the turn was recorded, its learning not yet saved
            self.policy.observe(Transition(**cp["learn"]))
        standing = Standing(int(cp["completed"]), int(cp["total"]), int(cp["mdp_state"]), cp["last_success"])
        return Restored(standing, cp.get("override"), float(cp.get("elapsed_s", 0.0)), list(cp.get("rows_before", [])))


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _rng_problem(name: str, state: Any) -> str | None:
    try:
        np.random.default_rng(0).bit_generator.state = state
    except (TypeError, ValueError, KeyError, OverflowError):
        return f"rng.{name} is not a random generator's state"
    return None


def checkpoint_problem(cp: Any, turns: int, learns: bool, rows_on_disk: int,
                       columns: tuple[str, ...] = TURN_COLUMNS) -> str | None:
    """Why checkpoint ``cp`` cannot be resumed from (one line), or None.

    ``turns``: the session's length; ``learns``: the policy keeps a state (its snapshot must be there);
    ``rows_on_disk``: the last completed turn in turns.csv (the checkpoint's turn, or the one before
    when a kill came between the checkpoint and its row).
    """
    if not isinstance(cp, dict):
        return "not a checkpoint (a JSON object expected)"
    for key in ("completed", "total", "mdp_state", "last_success", "elapsed_s", "row", "rng", "policy"):
        if key not in cp:
            return f"key '{key}' is missing"
    completed, total = cp["completed"], cp["total"]
    if not _is_int(completed) or not 1 <= completed <= turns:
        return f"completed must be a turn number 1..{turns}, got {completed!r}"
    if not _is_int(total) or abs(total) > completed * MAX_TURN_SCORE:
        return f"total must be an integer a session of {completed} turn(s) can score, got {total!r}"
    if not _is_int(cp["mdp_state"]) or not 0 <= cp["mdp_state"] < mdp.START:
        return f"mdp_state must be a turn state 0..{mdp.START - 1}, got {cp['mdp_state']!r}"
    if not isinstance(cp["last_success"], bool):
        return f"last_success must be true/false, got {cp['last_success']!r}"
    elapsed = cp["elapsed_s"]
    if not isinstance(elapsed, (int, float)) or isinstance(elapsed, bool) or not math.isfinite(elapsed) or elapsed < 0:
        return f"elapsed_s must be a number of seconds >= 0, got {elapsed!r}"
    row = cp["row"]
    if not isinstance(row, dict) or row.get("turn") != completed or not set(row) <= set(columns):  # the task's columns
        return "row is not the row of the checkpoint's turn"
    override = cp.get("override")
    if override is not None and (not _is_int(override) or not 0 <= override < mdp.N_ACTIONS):
        return f"override must be an action 0..{mdp.N_ACTIONS - 1} or null, got {override!r}"
    rngs = cp["rng"]
    if not isinstance(rngs, dict) or not {"session", "policy"} <= set(rngs):
        return "rng must hold the session's and the policy's generator states"
    for name, state in rngs.items():
        problem = _rng_problem(str(name), state)
        if problem:
            return problem
    if learns and not (isinstance(cp["policy"], dict) and cp["policy"]):
        return f"policy must hold the learning policy's state, got {short(cp['policy'])}"
    learn = cp.get("learn")
    if learn is not None and (not isinstance(learn, dict) or set(learn) != {f for f in Transition.__dataclass_fields__}):
        return "learn is not a transition"
    if rows_on_disk not in (completed, completed - 1):
        return (f"completed is {completed} but turns.csv ends at turn {rows_on_disk}: the checkpoint does not "
                "belong to these rows")
    return None
