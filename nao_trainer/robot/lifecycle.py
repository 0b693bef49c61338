"""Autonomous Life and the motors around a session, and what a NAO reports about itself.

A NAO boots with Autonomous Life "solitary": it turns its head to sounds and faces, an activity
taking focus resets LEDs and voice and wakes the motors, and a hand held on the head (the answer
buttons) 1 s stops the activity, 3 s puts it to sleep (NAOqi 2.8.5 SDK:
``naoqi/interaction/autonomouslife-api.html``, ``family/nao_user_guide/activity_nao.html``,
``sleep_nao.html``). ``TaskLife`` records the state found, sets the study's state for the task
(default "disabled"), wakes the motors before the first posture (``ALMotion.wakeUp``), and at the
end rests them (``ALMotion.rest``: crouch, motors off) and restores the state found.

The state to restore is also written on the robot (ALMemory key ``MARKER_KEY``) and cleared once
restored: a session killed with SIGKILL cannot restore anything, and the next ``run`` or ``check``
finds the marker, says so and restores the state the killed session had found.
"""
from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from typing import Any, Callable

from nao_trainer.errors import RobotUnavailable
from nao_trainer.ports import RobotCallFailed, RobotConnectionLost

log = logging.getLogger(__name__)

#: ALMemory key holding the Autonomous Life state a running (or killed) session must restore.
MARKER_KEY = "NaoTrainer/AutonomousLifeToRestore"
UNCHANGED = "unchanged"


@dataclass(frozen=True)
class RobotStatus:
    """What the robot says about itself; None where it cannot tell (service missing, refused)."""

    name: str | None = None
    naoqi_version: str | None = None
    autonomous_life: str | None = None
    awake: bool | None = None
    output_volume: int | None = None
    muted: bool | None = None
    battery: int | None = None
    left_by_earlier_session: str | None = None  # the state an unrestored (killed) session had found

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def describe(self) -> str:
        """One line for an operator."""
        def show(v: Any, fmt: str = "{}") -> str:
            return "unknown" if v is None else fmt.format(v)
        parts = [f"{show(self.name)} (NAOqi {show(self.naoqi_version)})",
                 f"volume {show(self.output_volume, '{}%')}" + (" MUTED" if self.muted else ""),
                 f"battery {show(self.battery, '{}%')}", f"Autonomous Life {show(self.autonomous_life)}",
                 "motors on" if self.awake else "motors off" if self.awake is False else "motors unknown"]
        if self.left_by_earlier_session:
            parts.append(f"left by an earlier session that did not end (found {self.left_by_earlier_session!r}; "
                         "the next session restores it)")
        return ", ".join(parts)


def _ask(call: Callable[[], Any]) -> Any:
    try:
        return call()
    except (RobotCallFailed, RobotUnavailable) as exc:  # MissingService is a RobotUnavailable
        log.debug("robot status: %s", exc)
        return None


def read_marker(robot: Any) -> str | None:
    """The state an earlier session left to restore, None when there is none."""
    value = _ask(lambda: robot.call("ALMemory", "getData", MARKER_KEY))
    return value if isinstance(value, str) and value else None


def read_status(robot: Any) -> RobotStatus:
    """Name, NAOqi version, Autonomous Life, motors, system volume and mute, battery (RobotConnectionLost propagates)."""
    def num(v: Any) -> int | None:
        return None if v is None else int(v)
    awake = _ask(lambda: robot.call("ALMotion", "robotIsWakeUp"))
    muted = _ask(lambda: robot.call("ALAudioDevice", "isAudioOutMuted"))
    return RobotStatus(
        name=_ask(lambda: robot.call("ALSystem", "robotName")),
        naoqi_version=_ask(lambda: robot.call("ALSystem", "systemVersion")),
        autonomous_life=_ask(lambda: robot.call("ALAutonomousLife", "getState")),
        awake=None if awake is None else bool(awake),
        output_volume=num(_ask(lambda: robot.call("ALAudioDevice", "getOutputVolume"))),
        muted=None if muted is None else bool(muted),
        battery=num(_ask(lambda: robot.call("ALBattery", "getBatteryCharge"))),
        left_by_earlier_session=read_marker(robot),
    )


class TaskLife:
    """Autonomous Life and motors for one session: ``enter()`` at the start, ``leave()`` at the end.

    ``report(name, **data)`` gets what was done (the session's events.jsonl). Failures are reported,
    not raised: a robot without ALAutonomousLife still runs the task.
    """

    def __init__(self, robot: Any, task_state: str = "disabled", rest_at_end: bool = True,
                 report: Callable[..., None] | None = None, wake: bool = True, allow_life_on: bool = False) -> None:
        self.robot = robot
        self.allow_life_on = allow_life_on
        #: Why the motors must stay as they are (the robot fell: never woken until the operator says it is up).
        self.motors_held: str | None = None
        self.wake = wake
        self.task_state = task_state
        self.rest_at_end = rest_at_end
        self.report = report or (lambda name, **data: None)
        self.found: str | None = None  # the state to restore
        self.entered = False

    def enter(self) -> RobotStatus:
        """Record the state (or the one an unrestored session had found), set the task's, wake the motors."""
        status = read_status(self.robot)
        self.found = status.left_by_earlier_session or status.autonomous_life
        if status.left_by_earlier_session:
            self.report("robot_left_unrestored", autonomous_life_found=status.autonomous_life,
                        to_restore=status.left_by_earlier_session)
        if self.found is not None and self.task_state != UNCHANGED:
            self._write_marker(self.found)
        self._apply(first=True)
        self.entered = True
        return status

    def _apply(self, first: bool = False) -> None:
        if self.task_state != UNCHANGED and self.found is not None:
            if not self._do("set_autonomous_life",
                            lambda: self.robot.call("ALAutonomousLife", "setState", self.task_state),
                            state=self.task_state) and first and self._refusal_stops():
                self._write_marker("")  # nothing was changed: nothing to restore
                raise RobotUnavailable(refused_life_line(self.task_state, self.last_error))
        if self.wake and self.motors_held is None:
            woke = self._do("wake_up", lambda: self.robot.call("ALMotion", "wakeUp", timeout_s=60.0))
            if first and not woke and not is_lost(self.last_error):
                raise RobotUnavailable(
                    f"the robot refused to wake up ({self.last_error}): a NAO rests and refuses after a critical "
                    "heat or a motor fault (naoqi/motion/reflexes-diagnosis.html); let it cool 15-20 minutes with "
                    "its motors off, then run `nao-trainer check` again")

    def _refusal_stops(self) -> bool:
        """A refused setState stops the start when the study wants life off and does not allow it on."""
        return self.task_state == "disabled" and not self.allow_life_on and not is_lost(self.last_error)

    def hold_motors(self, why: str | None) -> None:
        """``why``: keep the motors as they are (a fall) until called with None (the operator says it is up)."""
        self.motors_held = why
        self.report("motors_held" if why else "motors_released", why=why)

    def reapply(self) -> None:
        """After a reconnection (the robot may have rebooted into "solitary"): the task's state again."""
        if self.entered:
            self._apply()

    def between_turns(self) -> list[str]:
        """Between two turns: the task's state back if something changed it (``ports.RobotUpkeep``).

        Autonomous Life can be switched on mid-session from the robot's web page or Choregraphe, and
        a double click of the chest button removes the stiffness (NAOqi 2.8 ``ALChestButton``: "At
        double click, the stiffness is removed"): with life on, a hand resting on the answer buttons
        would then put NAO to sleep; with the motors off, NAO does not gesture. Two cheap calls; each
        change found is reported and undone. Returns what was set back ("Autonomous Life <state
        found>", "motors off"); the session also asks after a refused call, to tell a robot put to sleep (replay the
        turn) from one that cannot do the task. Never raises: a lost link is the next call's to notice."""
        fixed: list[str] = []
        if not self.entered:
            return fixed
        try:
            if self.task_state != UNCHANGED and self.found is not None:
                state = self.robot.call("ALAutonomousLife", "getState")
                if (state == "disabled") != (self.task_state == "disabled"):  # life on moves between its
                    # own states (solitary, interactive, safeguard) by itself: only off versus on matters
                    self.report("autonomous_life_changed", found=state, task=self.task_state)
                    if self._do("set_autonomous_life",
                                lambda: self.robot.call("ALAutonomousLife", "setState", self.task_state),
                                state=self.task_state):
                        fixed.append(f"Autonomous Life {state}")
            if self.wake and self.motors_held is None and not self.robot.call("ALMotion", "robotIsWakeUp"):
                self.report("motors_found_off")
                if self._do("wake_up", lambda: self.robot.call("ALMotion", "wakeUp", timeout_s=60.0)):
                    fixed.append("motors off")
        except (RobotCallFailed, RobotUnavailable, RobotConnectionLost) as exc:
            log.debug("between turns: %s", exc)
        return fixed

    def leave(self) -> None:
        """Rest the motors (unless the study says not to) and restore Autonomous Life; never raises."""
        if not self.entered:
            return
        if not self.robot.is_connected():
            self.report("robot_not_restored", why="robot not connected", autonomous_life=self.found)
            return
        if self.rest_at_end:
            self._do("rest", lambda: self.robot.call("ALMotion", "rest", timeout_s=60.0))
        if self.task_state != UNCHANGED and self.found is not None:
            if self._do("restore_autonomous_life",
                        lambda: self.robot.call("ALAutonomousLife", "setState", self.found), state=self.found):
                self._write_marker("")
        self.entered = False

    def _write_marker(self, value: str) -> None:
        self._do("robot_marker", lambda: self.robot.call("ALMemory", "insertData", MARKER_KEY, value), value=value)

    last_error: str = ""

    def _do(self, name: str, call: Callable[[], Any], **data: Any) -> bool:
        """Run ``call``; False (reported ``<name>_failed``) when refused, or when it answered False (``wakeUp``
        returns whether it succeeded: a robot resting after a critical heat refuses)."""
        try:
            result = call()
        except (RobotCallFailed, RobotUnavailable, RobotConnectionLost) as exc:
            self.last_error = f"{type(exc).__name__}: {exc}"
            self.report(f"{name}_failed", error=str(exc), **data)
            return False
        if result is False:
            self.last_error = f"{name} answered False"
            self.report(f"{name}_failed", error="the robot answered False (refused)", **data)
            return False
        self.report(name, **data)
        return True


def is_lost(error: str) -> bool:
    return error.startswith("RobotConnectionLost")


def refused_life_line(state: str, error: str) -> str:
    """The one line for a robot that refuses ``ALAutonomousLife.setState``."""
    why = error.split(": ", 1)[-1] if error else "refused"
    return (f"the robot refused to set Autonomous Life to {state!r} ({why}); a NAO refuses until its getting-started "
            "wizard is finished: open the robot's web page (its IP in a browser) and finish it, or let the session run "
            "with life on: robot.allow_life_on: true")
