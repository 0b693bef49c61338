"""What a real NAO does around the task's calls: Autonomous Life, motors, system volume, battery, identity.

NAOqi 2.8.5 SDK documentation (``doc/`` of the SDK; pages named in docs/how-to/robot.md):

* ``ALAutonomousLife`` (``naoqi/interaction/autonomouslife-api.html``): states ``solitary``,
  ``interactive``, ``safeguard``, ``disabled``; a NAO boots ``solitary``; a manual change from
  ``interactive`` to ``solitary`` fails. With life on, a hand held on the head 1 s stops the running
  activity, 3 s puts NAO to sleep (``family/nao_user_guide/activity_nao.html``, ``sleep_nao.html``).
* ``ALMotion`` (``naoqi/motion/control-stiffness-api.html``): ``wakeUp`` sets the motors on and
  goes to an initial posture, ``rest`` goes to a safe crouch and sets the motors off,
  ``robotIsWakeUp``. ``ALRobotPosture.goToPosture`` returns whether the posture was reached:
  with the motors off the joints do not move, so it is not (modelled: False, posture unchanged).
* ``ALAudioDevice`` (``naoqi/audio/alaudiodevice-api.html``): ``getOutputVolume`` 0-100,
  ``setOutputVolume``, ``isAudioOutMuted``, ``muteAudioOut``.
* ``ALBattery.getBatteryCharge`` (percent), ``ALSystem.robotName`` / ``systemVersion``.

* A fall (``Control.fall``): the fall manager raises ``ALMotion/RobotIsFalling``, sets the stiffness off and
  raises ``robotHasFallen`` (``naoqi/motion/reflexes-fall-manager.html``); the stand-in lies ``LyingBelly``.
* Heat (``Control.heat``): ``HotDeviceDetected`` with ``[[joint, status]]`` (the value's shape is a guess to
  confirm with the conformance kit); at status 3 (critical) the motors go off and ``ALMotion.wakeUp`` answers
  False until the joint cools (``naoqi/motion/reflexes-diagnosis.html``; "True if the call succeeded",
  ``naoqi/motion/control-stiffness-api.html``).
* A low battery (``Control.battery_low``): ``BatteryChargeChanged`` with the charge (``naoqi/sensors/albattery-api.html``)
  and, below NAOqi 2.8.6 (which removed it: ``news/2.8/whatsnew2.8.6.html``), ``ALBattery/BatteryLow`` True (a guess).
* ``ALAutonomousLife.setState`` refused with "Calls to the setState method are not currently allowed" when
  ``Control.refuse_life`` is on (seen on robots whose getting-started wizard was not finished).

Modelling choices (not documented behaviour): asleep, the stand-in refuses speech and sound with
"NAO is asleep" until ``wakeUp`` runs, Autonomous Life is set again, or a head button is touched
(the touch wakes it and does not reach the task)."""
from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field

os.environ.setdefault("QI_LOG_LEVEL", "silent")  # qi logs to fd 1 otherwise; must precede `import qi`
import qi  # noqa: E402

from nao_trainer.robot.standin.recorder import Recorder  # noqa: E402

LIFE_STATES = ("solitary", "interactive", "safeguard", "disabled")
#: A hand on the head this long (robot seconds) stops the activity / puts NAO to sleep, with life on.
STOP_ACTIVITY_HOLD_S, SLEEP_HOLD_S = 1.0, 3.0
NAOQI_VERSION = "2.8.5.10"
#: A joint's temperature (°C) until ``Control.warm`` sets it: a rested robot in a room, a guess to confirm with the
#: conformance kit (it records ``Device/SubDeviceList/LKneePitch/Temperature/Sensor/Value``).
JOINT_C = 35.0


def raises_battery_low(version: str) -> bool:
    """Whether a NAOqi of ``version`` raises ``ALBattery/BatteryLow`` (removed in 2.8.6: ``Control.battery_low``)."""
    return _version(version) < (2, 8, 6)


def _version(version: str) -> tuple[int, ...]:
    parts = []
    for part in str(version).split(".")[:3]:
        digits = "".join(ch for ch in part if ch.isdigit())
        parts.append(int(digits) if digits else 0)
    return tuple(parts)


@dataclass
class Body:
    """The robot's state shared by the services; thread-safe through ``lock``."""

    life: str = "solitary"
    motors_on: bool = False
    posture: str = "Crouch"
    asleep: bool = False
    volume: int = 60
    muted: bool = False
    battery: int = 85
    name: str = "nao-standin"
    version: str = NAOQI_VERSION
    model: str = "nao"  # the robot model the stand-in plays (nao, pepper)
    #: Installed speech languages: a guess (a NAO ships English plus the languages bought; confirm with the kit).
    languages: list = field(default_factory=lambda: ["English", "French"])
    fallen: bool = False
    hot: dict = field(default_factory=dict)  # joint -> temperature status 1..3
    #: joint -> temperature (°C) set by ``Control.warm``; the others read ``JOINT_C``.
    temperatures: dict = field(default_factory=dict)
    life_refused: bool = False
    chest_double: str = "stiffness"  # what a double click of the chest button does (Control.chest)
    #: Events this robot never raises nor declares (a recorded profile's ``events`` that are False).
    silent_events: set = field(default_factory=set)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def check_awake(self, what: str) -> None:
        """RuntimeError (a refused call) while NAO sleeps."""
        with self.lock:
            if self.asleep:
                raise RuntimeError(f"{what}: NAO is asleep (a hand was held on its head with Autonomous Life on); "
                                   "wake it with ALMotion.wakeUp or ALAutonomousLife.setState")

    def fall_asleep(self) -> None:
        with self.lock:
            self.asleep, self.motors_on, self.posture, self.life = True, False, "Crouch", "disabled"

    def wake(self) -> None:
        with self.lock:
            self.asleep = False


@qi.multiThreaded()
class AutonomousLife:
    """ALAutonomousLife: getState / setState; leaving ``disabled`` wakes the motors, as an activity would."""

    def __init__(self, rec: Recorder, body: Body) -> None:
        self._rec, self._body = rec, body

    @qi.bind(qi.String, [])
    def getState(self) -> str:
        """The life state (http://doc.aldebaran.com/2-8/naoqi/interaction/autonomouslife-api.html)."""
        with self._body.lock:
            return self._body.life

    @qi.bind(qi.Void, [qi.String])
    def setState(self, state: str) -> None:
        """Set the life state; a manual change from interactive to solitary fails
        (http://doc.aldebaran.com/2-8/naoqi/interaction/autonomouslife-api.html).

        Guesses to confirm with the conformance kit: leaving ``disabled`` sets the motors on and stands, and the refusal
        "not currently allowed" (``Control.refuse_life``; seen on robots whose getting-started wizard was not finished,
        not documented)."""
        self._rec.record("ALAutonomousLife", "setState", [state])
        with self._body.lock:
            refused = self._body.life_refused
        if refused:
            raise RuntimeError("ALAutonomousLife::setState: Calls to the setState method are not currently allowed")
        if state not in LIFE_STATES:
            raise RuntimeError(f"ALAutonomousLife::setState: unknown state {state!r} (states: {', '.join(LIFE_STATES)})")
        with self._body.lock:
            if self._body.life == "interactive" and state == "solitary":
                raise RuntimeError("ALAutonomousLife::setState: a manual change from interactive to solitary fails")
            self._body.life = state
            self._body.asleep = False
            if state in ("solitary", "interactive"):  # life takes the robot: motors on, standing
                self._body.motors_on, self._body.posture = True, "Stand"


@qi.multiThreaded()
class AudioDevice:
    """ALAudioDevice: the system's output volume (0-100) and mute, not the speech engine's gain."""

    def __init__(self, rec: Recorder, body: Body) -> None:
        self._rec, self._body = rec, body

    @qi.bind(qi.Int32, [])
    def getOutputVolume(self) -> int:
        """The system's output volume 0-100 (http://doc.aldebaran.com/2-8/naoqi/audio/alaudiodevice-api.html)."""
        with self._body.lock:
            return self._body.volume

    @qi.bind(qi.Void, [qi.Int32])
    def setOutputVolume(self, volume: int) -> None:
        """Set the system's output volume 0-100 (http://doc.aldebaran.com/2-8/naoqi/audio/alaudiodevice-api.html)."""
        self._rec.record("ALAudioDevice", "setOutputVolume", [volume])
        if not 0 <= volume <= 100:
            raise RuntimeError(f"ALAudioDevice::setOutputVolume: volume must be 0..100, got {volume}")
        with self._body.lock:
            self._body.volume = int(volume)

    @qi.bind(qi.Bool, [])
    def isAudioOutMuted(self) -> bool:
        """Whether the audio output is muted (http://doc.aldebaran.com/2-8/naoqi/audio/alaudiodevice-api.html)."""
        with self._body.lock:
            return self._body.muted

    @qi.bind(qi.Void, [qi.Bool])
    def muteAudioOut(self, muted: bool) -> None:
        """Mute or unmute the audio output (http://doc.aldebaran.com/2-8/naoqi/audio/alaudiodevice-api.html)."""
        self._rec.record("ALAudioDevice", "muteAudioOut", [muted])
        with self._body.lock:
            self._body.muted = bool(muted)


@qi.multiThreaded()
class Battery:
    """ALBattery: the charge in percent."""

    def __init__(self, body: Body) -> None:
        self._body = body

    @qi.bind(qi.Int32, [])
    def getBatteryCharge(self) -> int:
        """The charge in percent (http://doc.aldebaran.com/2-8/naoqi/sensors/albattery-api.html); a battery that never
        drains by itself is a guess to confirm with the conformance kit."""
        with self._body.lock:
            return self._body.battery


@qi.multiThreaded()
class System:
    """ALSystem: the robot's name and NAOqi version."""

    def __init__(self, body: Body) -> None:
        self._body = body

    @qi.bind(qi.String, [])
    def robotName(self) -> str:
        """The robot's name (http://doc.aldebaran.com/2-8/naoqi/core/alsystem-api.html)."""
        return self._body.name

    @qi.bind(qi.String, [])
    def systemVersion(self) -> str:
        """The NAOqi version (http://doc.aldebaran.com/2-8/naoqi/core/alsystem-api.html)."""
        return self._body.version


@qi.multiThreaded()
class BodyTemperature:
    """ALBodyTemperature (naoqi/sensors/albodytemperature.html): it raises ``HotDeviceDetected`` (the control
    service's ``heat`` does, through ALMemory); ``getTemperatureDiagnosis`` summarises the hot joints (the
    return shape is a guess: ``[[joint, status], ...]``)."""

    def __init__(self, body: Body) -> None:
        self._body = body

    @qi.bind(qi.Dynamic, [])
    def getTemperatureDiagnosis(self) -> list:
        """The hot joints (http://doc.aldebaran.com/2-8/naoqi/sensors/albodytemperature.html); the return shape ``[[joint,
        status], ...]`` is a guess to confirm with the conformance kit."""
        with self._body.lock:
            return [[joint, status] for joint, status in sorted(self._body.hot.items())]

    @qi.bind(qi.Void, [qi.Bool])
    def setEnableNotifications(self, enabled: bool) -> None:
        """Switch the temperature notifications on or off
        (http://doc.aldebaran.com/2-8/naoqi/sensors/albodytemperature.html); the stand-in always notifies (a guess to
        confirm with the conformance kit)."""
        pass
