"""`nao-trainer hardware-check --robot URL [--config STUDY]`: the robot check an operator runs in front of it."""
from __future__ import annotations

import argparse
from pathlib import Path
import sys

from nao_trainer.errors import ConfigError, RobotUnavailable
from nao_trainer.files import PROJECT_ROOT, write_text_atomic
from nao_trainer.session.config import DESKTOP, MOCK, load_config
from nao_trainer.robot.profile import diff, load_profile, record_profile


def register(sub) -> None:
    p = sub.add_parser(
        "hardware-check",
        help="in front of the robot: speech, beep, each head button, volume, mute, battery, Autonomous Life",
        description="Run in front of the robot before each participant: it says a test sentence and the letters "
                    "A, B, C and beeps (touch the front button if you heard them), then asks for each head "
                    "button in turn and reports each press and how long after the request it came. Shows the "
                    "system volume, mute, battery, Autonomous Life and NAOqi version and ends with one PASS or "
                    "FAIL line per item. Exit code 0 when all pass, 3 otherwise. See docs/how-to/before-first-participant.md.",
    )
    p.add_argument("--robot", metavar="URL", help="robot address (overrides robot.url): tcp://IP:9559 or tcps://IP:9503")
    p.add_argument("--config", metavar="FILE", help="study configuration (default: config/default.yaml)")
    p.add_argument("--timeout", type=float, default=20.0, metavar="S",
                   help="how long to wait for each button press (default 20 s)")
    p.add_argument("--record", metavar="FILE",
                   help="first store what the robot answers in FILE (a conformance profile: method signatures, "
                        "ALMemory values, measured say/playSine durations, wakeUp's result, languages, NAOqi "
                        "version, body type; the robot speaks, beeps, stands up and rests); serve it with "
                        "`nao-trainer mock-robot --profile FILE`")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nao_trainer.robot.hardware_check import run_hardware_check, verdict
    from nao_trainer.robot.naoqi import NaoqiRobot, redact_url

    if not 1 <= args.timeout <= 600:
        raise ConfigError(f"--timeout must be between 1 and 600 seconds, got {args.timeout:g}")
    config = load_config(args.config or PROJECT_ROOT / "config" / "default.yaml", {"robot.url": args.robot})
    url = config.robot.url
    if url in (MOCK, DESKTOP):
        raise ConfigError(f"hardware-check needs a robot address (robot.url is {url!r}): pass --robot tcp://IP:9559")
    print(f"hardware check of the robot at {redact_url(url)}", flush=True)
    with NaoqiRobot.connect(url, config.robot.connect_deadline_s) as robot:
        if args.record:
            _record(robot, args.record)
        items = run_hardware_check(robot, sys.stdout, args.timeout, config.robot.autonomous_life)
    print("", flush=True)
    for item in items:
        print(item.line(), flush=True)
    return verdict(items)


def _record(robot, path: str) -> None:
    """The conformance profile of ``robot`` in ``path`` (written whole, then the differences from the docs')."""
    from nao_trainer.ports import RobotCallFailed, RobotConnectionLost

    print("recording the robot's answers (it speaks, beeps, stands up and rests) ...", flush=True)
    try:
        profile = record_profile(robot)
    except (RobotConnectionLost, RobotCallFailed) as exc:  # nothing is written: a profile is recorded whole or not
        raise RobotUnavailable(f"--record {path}: the robot failed while being recorded ({exc}); nothing was "
                               "written: check the robot and its network, then run again") from None
    try:
        write_text_atomic(Path(path), profile.to_json())
    except OSError as exc:
        raise ConfigError(f"--record {path}: cannot write there ({exc.strerror}); choose another file") from None
    docs = load_profile(PROJECT_ROOT / "config" / "robot-profiles" / "naoqi-2.8-docs.json")
    lines = diff(profile, docs)
    print(f"recorded in {path}; {len(lines)} difference(s) from the NAOqi 2.8 documentation's profile:", flush=True)
    for line in lines:
        print(f"  {line}", flush=True)
