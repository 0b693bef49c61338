"""What the session does when the robot reports on its health (``ports.HealthEvent``, from ``robot.health``).

``HealthDesk`` is a part of ``session.engine.Session``: between states it drains the robot's health events;
each becomes an ``events.jsonl`` line (``robot_health``), an EEG marker (``robot_<kind>``), a line for the
operator and a console event, and a decision:

* a fall (or a failed diagnosis, or Pepper's Safeguard): the session pauses (an operator pause, source
  "robot") and the motors are held: nothing wakes them until the operator resumes, which says the robot is
  up; then the next turn wakes them (``ALMotion.wakeUp``, its result honoured) and replays the interrupted turn;
* heat at warning: the operator is told to let the robot sit between turns (naming the joint); at critical
  the robot goes to the model's cooling posture before the next turn (a NAO sits), or, without one
  (Pepper), the session pauses;
* BatteryLow: the turn in flight finishes, then the session ends cleanly (status "battery low", goodbye)
  with what to do;
* a chest-button press during a turn: the turn is marked invalid and replayed (an operator "repeat", source
  "robot": before the answer is scored the turn is recorded as interrupted and played again; once it is being
  scored it is recorded invalid, never learned from, and its action played again next), since NAO spoke its
  name and IP over the trial;
* a double click of the chest button: NAO removes its stiffness or switches Autonomous Life off and on (the 2.8
  pages disagree); during a turn, the turn is marked invalid and replayed as for one click, and before the next
  turn (the replay) the robot is set back either way (``RobotUpkeep.between_turns``: motors woken, life set back).
"""
from __future__ import annotations

from typing import Any

from nao_trainer.ports import CommandQueue, EngagementMonitor, HealthEvent, RobotUpkeep, SessionObserver
from nao_trainer.session.machine import IN_TURN
from nao_trainer.session.record import SessionRecorder
from nao_trainer.session.reporting import SessionLog

#: What the operator reads per kind (after the event's own detail).
ADVICE = {
    "falling": "",
    "fallen": "paused; the motors stay off: stand the robot up (check it), then resume",
    "hot_warning": "let it sit between turns, or pause a few minutes",
    "hot_critical": "",
    "battery_low": "the session ends after this turn: charge the robot (plug it in) before the next session",
    "chest": "",
    "chest_double": "",
    "diagnosis": "paused; the motors stay as they are: check the robot (its web page, Diagnosis), then resume",
    "safeguard": "paused while the robot protects itself: clear its surroundings, then resume",
}
#: The kinds that pause the session and hold the motors until the operator resumes.
PAUSING = ("fallen", "diagnosis", "safeguard")


class HealthDesk:
    """Drains the robot's health events and decides; the session asks it between states."""

    def __init__(self, health: Any, upkeep: RobotUpkeep, commands: CommandQueue, log: SessionLog,
                 recorder: SessionRecorder, monitor: EngagementMonitor, observer: SessionObserver,
                 cool_posture: str | None, pause_on_safeguard: bool = True) -> None:
        self.health, self.upkeep, self.commands = health, upkeep, commands
        self.log, self.rec, self.monitor, self.observer = log, recorder, monitor, observer
        self.cool_posture = cool_posture
        self.pause_on_safeguard = pause_on_safeguard
        self.battery_low = False
        self.hot_critical: str | None = None  # the joint to cool (sit before the next turn), once
        self.cooled = False
        self.held: str | None = None  # why the motors are held

    def take(self, state: str, turn: Any) -> None:
        """Drain and decide (called between states, on the session's thread)."""
        for event in self.health.pending():
            self._one(event, state, turn)

    def _one(self, event: HealthEvent, state: str, turn: Any) -> None:
        number = turn.number if turn is not None else None
        in_trial = turn is not None and not turn.recorded and state in IN_TURN
        key = f"{event.kind}_{event.severity}" if event.kind == "hot" else event.kind
        advice = ADVICE.get(key, "")
        if event.kind == "hot" and event.severity == "critical":
            advice = (f"the robot goes to {self.cool_posture} before the next turn; let it cool after the session"
                      if self.cool_posture else "paused: the robot has no seated posture; let it cool, then resume")
        if event.kind == "chest":
            advice = "the turn is replayed (the robot spoke over it)" if in_trial else "no trial was running"
        if event.kind == "chest_double":
            advice = (("the turn is replayed; " if in_trial else "")
                      + "the motors and Autonomous Life are set back before the next turn")
        if event.kind == "safeguard" and not self.pause_on_safeguard:
            advice = "reported only (robot.model_settings.pause_on_safeguard: false)"
        self.rec.event("robot_health", kind=event.kind, severity=event.severity, detail=event.detail, part=event.part,
                       value=event.value, state=state, turn=number, decision=advice)
        self.monitor.mark(f"robot_{event.kind}", number)
        self.observer.notify("robot_health", {"kind": event.kind, "severity": event.severity, "detail": event.detail,
                                              "part": event.part, "advice": advice, "turn": number})
        self.log.say(f"robot: {event.detail}" + (f": {advice}" if advice else ""))
        self._decide(event, in_trial, turn)

    def _decide(self, event: HealthEvent, in_trial: bool, turn: Any = None) -> None:
        kind = event.kind
        if kind in PAUSING and event.severity == "critical" and (kind != "safeguard" or self.pause_on_safeguard):
            self._hold_and_pause(event.detail)
        elif kind == "hot" and event.severity == "critical":
            if self.cool_posture:
                self.hot_critical = event.part or "a joint"
            else:
                self._hold_and_pause(event.detail)
        elif kind == "battery_low":
            self.battery_low = True
        elif kind in ("chest", "chest_double") and in_trial:
            # Marked invalid now (never learned from, even if it is recorded before the repeat acts: in score or
            # record the repeat waits, then plays the same action again); before that it is interrupted and replayed.
            # A double click's stiffness (or life) change is set back by the upkeep before the replay.
            why = "chest button " + ("double-clicked" if kind == "chest_double" else "pressed") + " during the trial"
            turn.invalid = True
            turn.notes.append(f"invalid (robot): {why}")
            self.commands.submit("repeat", {"reason": why}, source="robot")

    def _hold_and_pause(self, why: str) -> None:
        if self.held is None:
            self.upkeep.hold_motors(why)
        self.held = why
        self.commands.submit("pause", {"reason": why}, source="robot")

    def resumed(self) -> None:
        """The operator resumed: the robot is up again (the next turn may wake its motors)."""
        if self.held is not None:
            self.held = None
            self.upkeep.hold_motors(None)

    def before_turn(self, stage: Any) -> str | None:
        """Between two turns: "battery_low" when the session must end now; sits a critically hot robot once."""
        if self.battery_low:
            return "battery_low"
        if self.hot_critical is not None and not self.cooled and self.cool_posture:
            self.cooled = True
            reached = stage.posture(self.cool_posture)
            self.rec.event("cooling_posture", posture=self.cool_posture, joint=self.hot_critical,
                           reached=reached is not False)
            self.log.say(f"robot: {self.hot_critical} critically hot: {self.cool_posture} for the rest of the session")
        return None
