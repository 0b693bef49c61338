"""Getting a lost robot back: reconnection with exponential backoff, bounded by ``robot.max_reconnect_s``.

``Reconnector`` is a part of ``session.engine.Session`` (its ``paused`` state); it touches the robot,
the clock and the record. Before and after each wait it asks the session's ``between_attempts`` (the operator's
commands while the robot is away: a stop ends the attempts, a pause and a resume act at once); the session says
that the robot is back.
"""
from __future__ import annotations

from typing import Callable

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
        #: The session's look at the operator's commands between attempts: True to stop (a stop is queued);
        #: None: only a queued stop is looked for.
        self.between_attempts: Callable[[], bool] | None = None
        self.stopped = False  # the operator stopped the session while the robot was away
        self.attempts = 0  # how many attempts the last successful reconnection took

    def _stop_wanted(self) -> bool:
        if self.between_attempts is not None:
            return self.between_attempts()
        return self.commands is not None and "stop" in self.commands.kinds()

    def _stop_asked(self, wait_s: float) -> bool:
        """Wait ``wait_s`` before the next attempt (at most ``robot.backoff_max_s``) and look at the operator's
        commands before and after: True (and ``stopped`` set) once a stop is queued."""
        for waited in (False, True):
            if self._stop_wanted():
                self.stopped = True
                return True
            if not waited:
                self.clock.sleep(wait_s)
        return False

    def reconnect(self) -> bool:
        """True once the robot answers again, False when the time is up or the operator stopped."""
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
                self.attempts = attempt  # the session says the robot is back (and what it does then)
                return True
            except (RobotUnavailable, RobotConnectionLost, RobotCallFailed) as exc:
                self.rec.event("reconnect_failed", attempt=attempt, error=str(exc), next_wait_s=min(backoff * 2, r.backoff_max_s))
                backoff = min(backoff * 2, r.backoff_max_s)
        return False
