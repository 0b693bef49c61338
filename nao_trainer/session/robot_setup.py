"""The robot around the task: Autonomous Life, motors and the link watchdog's pace for one session.

``robot.lifecycle.TaskLife`` does the calls (it records the state found, sets the study's, restores it);
this part ties it to the study's ``robot`` section and to the session's record: what happens before the
session folder exists is kept and written into ``session.json`` (``robot_setup``), the rest goes to
``events.jsonl`` as it happens.
"""
from __future__ import annotations

from typing import Any, TextIO

from nao_trainer.errors import ConfigError, RobotUnavailable
from nao_trainer.ports import Robot, RobotCallFailed
from nao_trainer.robot.address import redact_url
from nao_trainer.robot.desktop import DesktopRobot
from nao_trainer.robot.lifecycle import TaskLife
from nao_trainer.robot.model import RobotModel
from nao_trainer.session.config import DESKTOP, RobotSection, StudyConfig
from nao_trainer.session.config_rules import LANGUAGES
from nao_trainer.session.record import SessionRecorder


class RobotSetup:
    """Puts a NAO in the study's state for the task; ``prepare`` returns the ``TaskLife`` to ``leave()``."""

    def __init__(self, recorder: SessionRecorder) -> None:
        self.recorder = recorder
        self.status: dict[str, Any] | None = None  # robot name, NAOqi version, volume, battery, life found
        self.early: list[dict[str, Any]] = []  # set-up events before the session folder exists

    def report(self, name: str, **data: Any) -> None:
        if self.recorder.is_open:
            self.recorder.event(name, **data)
        else:
            self.early.append({"event": name, **data})

    def prepare(self, robot: Any, section: RobotSection, language: str = "en", needs_buttons: bool = True,
                progress: TextIO | None = None) -> TaskLife:
        """The model's services probed (a missing optional one degrades, in one line), the speech language set,
        Autonomous Life to the study's state and the motors on (``TaskLife.enter``), the link watchdog's pace;
        after a reconnection the same state is applied again, and between turns it is kept
        (``TaskLife.between_turns``)."""
        model = section.robot_model()
        probe_model(robot, model, needs_buttons, self.report, progress)
        set_language(robot, model, language, self.report)
        robot.link_check_s, robot.link_deadline_s = float(section.link_check_s), float(section.link_deadline_s)
        life = TaskLife(robot, section.autonomous_life, section.rest_at_end, self.report,
                        allow_life_on=section.allow_life_on)
        self.status = life.enter().as_dict()
        robot.after_reconnect.append(life.reapply)
        return life


def probe_model(robot: Any, model: RobotModel, needs_buttons: bool, report: Any, progress: TextIO | None) -> None:
    """RobotUnavailable when a service the task needs is missing; an optional one missing degrades (one line)."""
    try:
        probe = model.probe(robot.has_service, needs_buttons)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if probe.missing:
        raise RobotUnavailable(f"the robot at {redact_url(robot.url)} ({model.title}) offers no "
                               f"{', '.join(probe.missing)} service: check robot.model and the robot's NAOqi version")
    robot.without = {s.name for s in model.services if not s.required and s.name not in probe.present}
    for line in probe.degraded:
        report("robot_degraded", detail=line)
        if progress:
            print(f"robot: {line}", file=progress, flush=True)


def set_language(robot: Any, model: RobotModel, language: str, report: Any) -> None:
    """Set ``session.language`` as the robot's speech language; one line naming the installed ones when missing."""
    name = LANGUAGES[language]
    installed = available_languages(robot)
    if installed is not None and name not in installed:
        raise RobotUnavailable(missing_language_line(language, name, installed))
    robot.call("ALTextToSpeech", "setLanguage", name)
    report("speech_language", language=language, naoqi=name)


def available_languages(robot: Any) -> list[str] | None:
    try:
        return [str(x) for x in robot.call("ALTextToSpeech", "getAvailableLanguages")]
    except RobotCallFailed:
        return None


def missing_language_line(language: str, name: str, installed: list[str]) -> str:
    return (f"session.language {language!r} needs the robot's {name} voice, but it has only "
            f"{', '.join(installed) or 'none'}: install {name} on the robot (its web page or Choregraphe) or "
            "choose an installed language (session.language and a dialogue file in it)")


def connect_robot(config: StudyConfig, url: str, standin: bool, progress: TextIO | None) -> Robot:
    """The robot the study names: the laptop (``desktop``) or a NAO (or the stand-in) over qi at ``url``."""
    if config.robot.url == DESKTOP:
        return desktop_robot(config.answers.input, config.timing.speed, progress)
    from nao_trainer.robot.naoqi import NaoqiRobot  # heavy: qi

    if progress:
        print(f"connecting to the robot at {'the stand-in ' + url if standin else redact_url(url)} ...",
              file=progress, flush=True)
    return NaoqiRobot.connect(url, config.robot.connect_deadline_s, None,
                              debounce_s=config.answers.debounce_s / config.timing.speed,
                              buttons=config.robot.robot_model().buttons)


def desktop_robot(input_kind: str, speed: float, progress: TextIO | None) -> Robot:
    """The laptop as the robot (``--robot desktop``); refuses head-button answers it cannot give."""
    if input_kind == "tactile":
        raise ConfigError("--robot desktop has no head buttons: answer with --input keyboard (or simulated)")
    robot = DesktopRobot.start(speed)
    if progress:
        where = "the sound device" if robot.player else "WAV files in the session folder's audio/ (no sound device)"
        print(f"the laptop plays the robot: speech through espeak-ng, sound to {where}", file=progress, flush=True)
    return robot
