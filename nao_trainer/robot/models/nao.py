"""The NAO (V5/V6, NAOqi 2.8) as a robot model: registered as ``nao`` (``registry.BUILTIN``).

Each value names the NAOqi 2.8.5 SDK page it follows (``doc/`` of the SDK):

* postures: ``naoqi/motion/alrobotposture.html`` (Crouch, LyingBack, LyingBelly, Sit, SitRelax, Stand,
  StandInit, StandZero); the safe ones are those a NAO can be left in with its motors off;
* answer buttons: the three head tactile sensors ``FrontTactilTouched``, ``MiddleTactilTouched``,
  ``RearTactilTouched`` (``naoqi/sensors/altouch.html``: 1.0 on touch, 0.0 on release);
* falls: ``ALMotion/RobotIsFalling`` and ``robotHasFallen``, raised when the fall manager starts and
  finishes (``naoqi/motion/reflexes-fall-manager.html``);
* heat: ``HotDeviceDetected`` (``naoqi/sensors/albodytemperature.html``: a joint, actuator or the battery
  with a non-null temperature status); at critical status the motors are set off and the robot rests
  (``naoqi/motion/reflexes-diagnosis.html``);
* battery: ``ALBattery/BatteryLow`` ("raised when the battery level is low and will soon need charging", in the
  NAOqi 2.5 ``naoqi/sensors/albattery-api.html``) is deprecated: the 2.8 documentation lists it among the events
  removed in NAOqi 2.8.6 (``news/2.8/whatsnew2.8.6.html``, "Removal of deprecated modules, events, and methods")
  while ``naoqi/sensors/albattery.html`` still speaks of "a BatteryLow notification"; that a 2.8.5 NAO raises it
  is a guess (the conformance kit records it: ``events`` in a profile). So ``BatteryChargeChanged`` (the percentage
  remaining, 2.8 ``naoqi/sensors/albattery-api.html``) is watched too: at or below ``battery_low_percent`` (a
  guess) it counts as battery low;
* chest button: one click makes NAO say its name and IP (``naoqi/sensors/alchestbutton.html``);
  ``ALChestButton/SimpleClickOccurred`` and, for a double click, ``ALChestButton/DoubleClickOccurred``
  (``naoqi/sensors/alchestbutton-api.html``). What a double click does, the 2.8 pages disagree on: the stiffness
  is removed (``alchestbutton.html``) or Autonomous Life is set off and on
  (``family/nao_user_guide/chest_button_usages.html``); the session sets back either before the next turn.
"""
from __future__ import annotations

from nao_trainer.core.settings import setting, settings
from nao_trainer.ports import BUTTON_LETTERS
from nao_trainer.robot.model import HealthKeys, RobotModel, Service

POSTURES = ("Stand", "StandInit", "StandZero", "Crouch", "Sit", "SitRelax", "LyingBelly", "LyingBack")
SAFE_POSTURES = ("Crouch", "Sit", "SitRelax")
#: The joints that carry a standing NAO (they heat first: ``check`` reads their temperature).
LEG_JOINTS = ("LHipPitch", "RHipPitch", "LKneePitch", "RKneePitch", "LAnklePitch", "RAnklePitch")
#: The services every session calls (a missing one fails ``check``).
TASK_SERVICES = ("ALTextToSpeech", "ALAnimatedSpeech", "ALAudioPlayer", "ALLeds", "ALRobotPosture", "ALMotion",
                 "ALMemory")


@settings
class NaoSettings:
    """``robot.model_settings`` of a NAO."""

    cool_posture: str = setting("Sit", kind=str, choices=SAFE_POSTURES,
                                doc="where a NAO with a hot joint (critical) waits between turns")
    full_battery_minutes: float = setting(60.0, kind=(int, float), min=5, max=1440,
                                          doc="minutes a full charge lasts in a session (check's estimate; "
                                              "about an hour of activity; measure yours)")
    battery_low_percent: int = setting(15, kind=int, min=1, max=50,
                                       doc="a charge (percent, BatteryChargeChanged) at or below which the session "
                                           "ends after the turn in flight, as on BatteryLow (a guess)")
    heat_c_per_min: float = setting(1.0, kind=(int, float), min=0.01, max=20,
                                    doc="how fast (°C a minute) a standing NAO's leg joints warm (check's heat "
                                        "projection; a guess: measure yours)")
    hot_joint_c: float = setting(70.0, kind=(int, float), min=30, max=150,
                                 doc="the leg joint temperature (°C) where NAO starts limiting stiffness (check's heat "
                                     "projection; a guess: read Temperature/Sensor/Value when the status turns 1)")


class NaoModel(RobotModel):
    """A NAO: stands or sits, answers on its three head buttons, can fall, has a chest button."""

    Settings = NaoSettings
    title = "NAO"
    postures = POSTURES
    safe_postures = SAFE_POSTURES
    buttons = dict(BUTTON_LETTERS)
    health = HealthKeys(falling="ALMotion/RobotIsFalling", fallen="robotHasFallen", hot="HotDeviceDetected",
                        battery_low="ALBattery/BatteryLow",
                        battery_charge="BatteryChargeChanged", chest="ALChestButton/SimpleClickOccurred",
                        chest_double="ALChestButton/DoubleClickOccurred",
                        diagnosis="ALDiagnosis/RobotIsReady")
    services = tuple(Service(name) for name in TASK_SERVICES) + (
        Service("ALAutonomousLife", False, "Autonomous Life is left as found"),
        Service("ALAudioDevice", False, "the system volume and mute are not checked"),
        Service("ALBattery", False, "the battery is not checked"),
        Service("ALSystem", False, "the robot's name and NAOqi version are not recorded"),
        Service("ALBodyTemperature", False, "joint heat is not watched"),
    )
    capabilities = frozenset({"sit", "fall", "chest_button", "tactile_answers"})
    joints = LEG_JOINTS
    type_names = ("nao",)
