"""The robot around the task: Autonomous Life, motors and the link watchdog's pace for one session.

``robot.lifecycle.TaskLife`` does the calls (it records the state found, sets the study's, restores it);
this part ties it to the study's ``robot`` section and to the session's record: what happens before the
session folder exists is kept and written into ``session.json`` (``robot_setup``), the rest goes to
``events.jsonl`` as it happens.
"""
from __future__ import annotations

from typing import Any, TextIO

from nao_trainer.errors import ConfigError
from nao_trainer.ports import Robot
from nao_trainer.robot.address import redact_url
from nao_trainer.robot.desktop import DesktopRobot
from nao_trainer.robot.lifecycle import TaskLife
from nao_trainer.session.config import DESKTOP, RobotSection, StudyConfig
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

    def prepare(self, robot: Any, section: RobotSection) -> TaskLife:
        """Autonomous Life to the study's state and the motors on (``TaskLife.enter``), the link watchdog's pace;
        after a reconnection the same state is applied again, and between turns it is kept
        (``TaskLife.between_turns``)."""
        robot.link_check_s, robot.link_deadline_s = float(section.link_check_s), float(section.link_deadline_s)
        life = TaskLife(robot, section.autonomous_life, section.rest_at_end, self.report)
        self.status = life.enter().as_dict()
        robot.after_reconnect.append(life.reapply)
        return life


def connect_robot(config: StudyConfig, url: str, standin: bool, progress: TextIO | None) -> Robot:
    """The robot the study names: the laptop (``desktop``) or a NAO (or the stand-in) over qi at ``url``."""
    if config.robot.url == DESKTOP:
        return desktop_robot(config.answers.input, config.timing.speed, progress)
    from nao_trainer.robot.naoqi import NaoqiRobot  # heavy: qi

    if progress:
        print(f"connecting to the robot at {'the stand-in ' + url if standin else redact_url(url)} ...",
              file=progress, flush=True)
    return NaoqiRobot.connect(url, config.robot.connect_deadline_s, None,
                              debounce_s=config.answers.debounce_s / config.timing.speed)


def desktop_robot(input_kind: str, speed: float, progress: TextIO | None) -> Robot:
    """The laptop as the robot (``--robot desktop``); refuses head-button answers it cannot give."""
    if input_kind == "tactile":
        raise ConfigError("--robot desktop has no head buttons: answer with --input keyboard (or simulated)")
    robot = DesktopRobot.start(speed)
    if progress:
        where = "the sound device" if robot.player else "WAV files in the session folder's audio/ (no sound device)"
        print(f"the laptop plays the robot: speech through espeak-ng, sound to {where}", file=progress, flush=True)
    return robot
