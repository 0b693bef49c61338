"""Getting a lost robot back: reconnection with exponential backoff, bounded by ``robot.max_reconnect_s``.

``Reconnector`` is a part of ``session.engine.Session`` (its ``paused`` state); it touches the robot,
the clock, the record and the stage (which says the robot is back).
"""
from __future__ import annotations

from nao_trainer.errors import RobotUnavailable
from nao_trainer.ports import CommandQueue, Robot, RobotCallFailed, RobotConnectionLost
from nao_trainer.session.config import RobotSection
from nao_trainer.session.record import SessionRecorder
from nao_trainer.session.reporting import SessionLog
from nao_trainer.session.stage import Clock, Stage


class Reconnector:
    """Reconnect the robot with exponential backoff (wall seconds) until ``robot.max_reconnect_s``."""

    def __init__(self, robot: Robot, settings: RobotSection, clock: Clock, recorder: SessionRecorder, log: SessionLog,
                 stage: Stage) -> None:
        self.robot = robot
        self.settings = settings
        self.clock = clock
        self.rec = recorder
        self.log = log
        self.stage = stage
        self.commands: CommandQueue | None = None  # the operator's: a stop ends the attempts
        self.stopped = False  # the operator stopped the session while the robot was away

    def _stop_asked(self, wait_s: float) -> bool:
        """Wait ``wait_s`` before the next attempt (at most ``robot.backoff_max_s``) and look at the operator's
        commands before and after: True (and ``stopped`` set) once a stop is queued: the robot is away, so
        nothing else can act."""
        for waited in (False, True):
            if self.commands is not None and "stop" in self.commands.kinds():
                self.stopped = True
                return True
            if not waited:
                self.clock.sleep(wait_s)
        return False

    def reconnect(self) -> bool:
        """True once the robot answers again (and says so), False when the time is up."""
        r = self.settings
        deadline = self.clock.now() + r.max_reconnect_s
        backoff, attempt = r.backoff_initial_s, 0
        while (remaining := deadline - self.clock.now()) > 0:
            if self._stop_asked(min(backoff, remaining)):
                return False
            attempt += 1
            try:
                self.robot.reconnect(max(0.5, min(r.connect_deadline_s, deadline - self.clock.now())))
                self.rec.event("reconnected", attempt=attempt)
                self.log.say(f"robot back after {attempt} attempt(s): resuming")
                self.stage.say("resumed", behavior="greeting")
                return True
            except (RobotUnavailable, RobotConnectionLost, RobotCallFailed) as exc:
                self.rec.event("reconnect_failed", attempt=attempt, error=str(exc), next_wait_s=min(backoff * 2, r.backoff_max_s))
                backoff = min(backoff * 2, r.backoff_max_s)
        return False
