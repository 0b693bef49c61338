"""Pepper (NAOqi 2.5 / 2.9) as a robot model over the same NAOqi adapter: registered as ``pepper``.

From the NAOqi 2.8.5 SDK pages (``doc/``) unless marked as a guess to confirm with the conformance kit:

* postures: Pepper has no seated posture; ``naoqi/motion/alrobotposture.html`` lists Stand, StandInit,
  StandZero and Crouch for it; Crouch is its safe posture (a guess for "safe": confirm on the robot);
* answer buttons: Pepper's head has the same three tactile sensors under the same ALMemory keys as a NAO
  (``family/pepper_technical/...`` head touch sensors; ``naoqi/sensors/altouch.html``);
* Safeguard: ``ALAutonomousLife`` state ``safeguard`` (``naoqi/interaction/autonomouslife-api.html``)
  is entered when the robot's safety needs it (pushed, bumpers, wheels); the event
  ``AutonomousLife/State`` carries the new state. The session pauses while Pepper is in Safeguard and
  the operator resumes it;
* services: Pepper 2.9 lacks some NAO services (ALTracker among them) and plays audio differently:
  each optional one is probed with ``has_service``; without ``ALAnimatedSpeech`` the text is said
  plainly, without ``ALLeds`` the eye colours are skipped, each said once in one line;
* battery: a Pepper runs for hours on a charge ("up to 12 hours": a guess from the product sheet).
"""
from __future__ import annotations

from nao_trainer.core.settings import setting, settings
from nao_trainer.ports import BUTTON_LETTERS
from nao_trainer.robot.model import HealthKeys, RobotModel, Service

POSTURES = ("Stand", "StandInit", "StandZero", "Crouch")
SAFE_POSTURES = ("Crouch",)
#: Pepper's joints that hold it up (the hip and knee carry the torso on the wheeled base).
HOLD_JOINTS = ("HipPitch", "HipRoll", "KneePitch")


@settings
class PepperSettings:
    """``robot.model_settings`` of a Pepper."""

    full_battery_minutes: float = setting(600.0, kind=(int, float), min=5, max=1440,
                                          doc="minutes a full charge lasts in a session (check's estimate)")
    pause_on_safeguard: bool = setting(True, kind=bool,
                                       doc="pause the session while Autonomous Life is in safeguard")


class PepperModel(RobotModel):
    """A Pepper: no seated posture (a critically hot joint pauses the session), head buttons, Safeguard."""

    Settings = PepperSettings
    title = "Pepper"
    postures = POSTURES
    safe_postures = SAFE_POSTURES
    buttons = dict(BUTTON_LETTERS)
    health = HealthKeys(falling="ALMotion/RobotIsFalling", fallen="robotHasFallen", hot="HotDeviceDetected",
                        battery_low="ALBattery/BatteryLow",
                        battery_charge="BatteryChargeChanged", chest="ALChestButton/SimpleClickOccurred",
                        chest_double="ALChestButton/DoubleClickOccurred",
                        diagnosis="ALDiagnosis/RobotIsReady",
                        safeguard="AutonomousLife/State")
    services = (
        Service("ALTextToSpeech"), Service("ALAudioPlayer"), Service("ALRobotPosture"), Service("ALMotion"),
        Service("ALMemory"),
        Service("ALAnimatedSpeech", False, "the robot speaks without gestures"),
        Service("ALLeds", False, "the eye colours of the behaviors file are not shown"),
        Service("ALAutonomousLife", False, "Autonomous Life is left as found and Safeguard is not watched"),
        Service("ALAudioDevice", False, "the system volume and mute are not checked"),
        Service("ALBattery", False, "the battery is not checked"),
        Service("ALSystem", False, "the robot's name and NAOqi version are not recorded"),
        Service("ALBodyTemperature", False, "joint heat is not watched"),
        Service("ALTracker", False, "nothing: the task does not track faces (Pepper 2.9 has no ALTracker)"),
    )
    capabilities = frozenset({"fall", "chest_button", "tactile_answers", "safeguard"})
    joints = HOLD_JOINTS
    type_names = ("pepper", "juliette")

    def cool_posture(self) -> str | None:
        return None  # no seated posture: a critically hot joint pauses the session instead
