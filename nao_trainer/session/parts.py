"""What a session is built from, grouped: the ports (one value), the script, the random generators.

``session.wiring`` fills them from a study; tests fill them with fakes (tests/session/fakes.py).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nao_trainer.ports import (AnswerSource, CommandQueue, EngagementMonitor, NullHealth, NullMonitor, NullObserver,
                               NullUpkeep, Policy, Robot, RobotHealthWatch, RobotUpkeep, SessionObserver)
from nao_trainer.session.behaviors import Behaviors
from nao_trainer.tasks.base import Task, default_task
from nao_trainer.session.dialogue import Dialogue


@dataclass(frozen=True)
class SessionPorts:
    """The world as the session sees it: the ``ports`` Protocols, one value (``session.wiring`` builds them)."""

    robot: Robot
    answers: AnswerSource
    policy: Policy
    monitor: EngagementMonitor = field(default_factory=NullMonitor)
    commands: CommandQueue = field(default_factory=CommandQueue)
    observer: SessionObserver = field(default_factory=NullObserver)
    upkeep: RobotUpkeep = field(default_factory=NullUpkeep)  # Autonomous Life and motors, between turns
    health: RobotHealthWatch = field(default_factory=NullHealth)  # falls, heat, battery, chest button (robot.health)
    task: Task = field(default_factory=default_task)  # what is trained (``tasks.base.Task``; the study's ``task``)


@dataclass(frozen=True)
class Script:
    """What the robot says and how it moves (the study's dialogue and behaviors files)."""

    dialogue: Dialogue
    behaviors: Behaviors


@dataclass(frozen=True)
class Randomness:
    """The session's generators: ``session`` (sequences, dialogue variants), ``policy`` (the policy's
    choices) and ``others`` a checkpoint must carry too (the simulated participant's)."""

    session: np.random.Generator
    policy: np.random.Generator
    others: dict[str, np.random.Generator] = field(default_factory=dict)

    def by_name(self) -> dict[str, np.random.Generator]:
        return {"session": self.session, "policy": self.policy, **self.others}
