"""The robot's health during a session: falls, heat, the diagnosis, a low battery, the chest button, Safeguard.

``HealthWatch`` subscribes the ALMemory events the robot model declares (``RobotModel.health``) through the
NAOqi adapter (``NaoqiRobot.watch``: qi signals, subscribed again after a reconnection) and turns each value
into a ``ports.HealthEvent``; the session drains them between states (``ports.RobotHealthWatch``) and decides
(``session.health``). Callbacks run on qi threads: they only append under a lock.

What each value means (NAOqi 2.8.5 SDK pages; a shape not documented is a guess, marked, to confirm with
``nao-trainer hardware-check --record``):

* ``ALMotion/RobotIsFalling`` / ``robotHasFallen``: the fall manager started / finished
  (``naoqi/motion/reflexes-fall-manager.html``); the value is not used;
* ``HotDeviceDetected``: raised when a joint, actuator or the battery has a non-null temperature status
  (``naoqi/sensors/albodytemperature.html``). The value's shape is a guess: a list of device names, or of
  ``[name, status]`` pairs with the temperature status 1 (hot), 2 (very hot), 3 (critical: stiffness off);
  both are read; without a status the level is "warning";
* ``ALBattery/BatteryLow``: "the battery level is low and will soon need charging", status always True (NAOqi
  2.5 ``naoqi/sensors/albattery-api.html``); deprecated, removed in NAOqi 2.8.6 (2.8 ``news/2.8/whatsnew2.8.6.html``),
  so that a 2.8.5 NAO raises it is a guess to confirm with the kit;
* ``BatteryChargeChanged``: the percentage remaining (2.8 ``naoqi/sensors/albattery-api.html``); at or below the
  model's ``battery_low_percent`` (a guess) it is read as battery low, once (whichever of the two comes first);
* ``ALChestButton/SimpleClickOccurred``: one click; NAO then says its name and IP
  (``naoqi/sensors/alchestbutton.html``);
* ``ALChestButton/DoubleClickOccurred``: a double click (``naoqi/sensors/alchestbutton-api.html``); NAO then
  removes its stiffness (``naoqi/sensors/alchestbutton.html``) or sets Autonomous Life off and on
  (``family/nao_user_guide/chest_button_usages.html``): the pages disagree, the kit tells;
* ``ALDiagnosis/RobotIsReady``: read as False when the diagnosis finds a failure ALMotion reacts to
  (``naoqi/motion/reflexes-diagnosis.html``). Its 2.8 page (``naoqi/diagnosis/aldiagnosis-api.html``) says it is
  "raised when the active diagnosis, automatically launched after the NAOqi startup, is finished", True if no
  critical error: so mid-session it may come only after a NAOqi restart, not on a passive-diagnosis failure; a
  guess to confirm with the kit;
* ``AutonomousLife/State``: the new Autonomous Life state (``naoqi/interaction/autonomouslife-api.html``);
  only "safeguard" is reported.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable

from nao_trainer.ports import HealthEvent

log = logging.getLogger(__name__)

#: Temperature status -> severity (0 normal is never raised).
_STATUS = {1: "warning", 2: "warning", 3: "critical"}


def _hot_parts(value: Any) -> list[tuple[str, int | None]]:
    """(device, status or None) from a ``HotDeviceDetected`` value of either guessed shape."""
    parts: list[tuple[str, int | None]] = []
    items = value if isinstance(value, (list, tuple)) else [value]
    for item in items:
        if isinstance(item, (list, tuple)) and item:
            status = None
            if len(item) > 1:
                try:
                    status = int(item[1])
                except (TypeError, ValueError):
                    status = None
            parts.append((str(item[0]), status))
        elif isinstance(item, str) and item:
            parts.append((item, None))
    return parts


def read_event(kind: str, value: Any, battery_low_percent: int = 15) -> HealthEvent | None:
    """The ``HealthEvent`` of one ALMemory value for watched ``kind`` (``RobotModel.health``), None to ignore;
    ``battery_low_percent``: the charge a ``battery_charge`` value counts as battery low at."""
    now = time.monotonic()
    shown = value if isinstance(value, (bool, int, float, str, list, dict)) or value is None else str(value)
    if kind == "falling":
        return HealthEvent("falling", "warning", "the robot is falling", at=now, value=shown)
    if kind == "fallen":
        return HealthEvent("fallen", "critical", "the robot has fallen", at=now, value=shown)
    if kind == "hot":
        parts = _hot_parts(value)
        if not parts:
            return HealthEvent("hot", "warning", "a device is hot (not named)", at=now, value=shown)
        worst = max(parts, key=lambda p: p[1] or 0)
        severity = _STATUS.get(worst[1] or 1, "critical" if (worst[1] or 0) > 3 else "warning")
        names = ", ".join(p[0] for p in parts)
        return HealthEvent("hot", severity, f"{names} {'critically ' if severity == 'critical' else ''}hot",
                           part=worst[0], at=now, value=shown)
    if kind == "battery_low":
        return HealthEvent("battery_low", "critical", "battery low: it will soon need charging", at=now, value=shown)
    if kind == "battery_charge":
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value <= battery_low_percent:
            return HealthEvent("battery_low", "critical", f"battery low ({value:g}%): it will soon need charging",
                               at=now, value=shown)
        return None
    if kind == "chest":
        return HealthEvent("chest", "info", "chest button pressed (NAO says its name and IP aloud)", at=now,
                           value=shown)
    if kind == "chest_double":
        return HealthEvent("chest_double", "warning", "chest button double-clicked (NAO removes its stiffness, or "
                           "switches Autonomous Life off and on)", at=now, value=shown)
    if kind == "diagnosis":
        if value is False or value == 0:
            return HealthEvent("diagnosis", "critical", "the diagnosis found a failure (the robot protects itself)",
                               at=now, value=shown)
        return HealthEvent("diagnosis", "info", "the diagnosis says the robot is ready again", at=now, value=shown)
    if kind == "safeguard":
        if str(value) == "safeguard":
            return HealthEvent("safeguard", "critical", "Autonomous Life went to safeguard (the robot protects itself)",
                               at=now, value=shown)
        return None
    return None


class HealthWatch:
    """Watches the model's health events on ``robot`` (a ``NaoqiRobot``); implements ``ports.RobotHealthWatch``."""

    def __init__(self, robot: Any, model: Any, on_event: Callable[[HealthEvent], None] | None = None) -> None:
        self.robot = robot
        self.model = model
        self._lock = threading.Lock()
        self._pending: list[HealthEvent] = []
        self._on_event = on_event
        self._battery_low_seen = False
        self.watched = [key for _, key in model.health.items()]

    @classmethod
    def start(cls, robot: Any, model: Any) -> "HealthWatch":
        watch = cls(robot, model)
        robot.watch({key: watch._handler(kind) for kind, key in model.health.items()})
        return watch

    def _handler(self, kind: str) -> Callable[[Any], None]:
        def handle(value: Any) -> None:
            event = read_event(kind, value, self.model.battery_low_percent())
            if event is None:
                return
            with self._lock:
                if event.kind == "battery_low" and self._battery_low_seen:
                    return  # BatteryLow and a low BatteryChargeChanged say the same: once
                self._battery_low_seen = self._battery_low_seen or event.kind == "battery_low"
                self._pending.append(event)
            if self._on_event is not None:
                self._on_event(event)
        return handle

    def pending(self) -> list[HealthEvent]:
        with self._lock:
            events, self._pending = self._pending, []
        return events

    def close(self) -> None:
        try:
            self.robot.unwatch_all()
        except Exception as exc:  # noqa: BLE001 - closing anyway
            log.debug("unwatching the robot's health: %s", exc)
