"""The conformance kit: what a robot answers, recorded, served by the stand-in, and compared.

``record_profile(robot)`` (``nao-trainer hardware-check --record FILE``) stores what a real robot answers to
what the project asks: the signature of every method it calls (from qi's ``metaObject``), the values of the
ALMemory keys it reads, whether it declares each event the session watches, the measured ``say`` and ``playSine`` durations against the text and the tone,
``ALMotion.wakeUp``'s result, the installed speech languages, the NAOqi version and the body type.
``nao-trainer mock-robot --profile FILE`` serves the stand-in with those answers (``Profile.apply``), and
``diff`` lists where two profiles differ; ``config/robot-profiles/naoqi-2.8-docs.json`` is the profile the
NAOqi 2.8 documentation implies, each value citing its page (or marked a guess), and a test diffs the
stand-in's defaults against it, so a lab's recorded file shows every guess of the stand-in that was wrong.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from nao_trainer.errors import ConfigError
from nao_trainer.robot.model import default_model, model_called

FORMAT = "nao-trainer robot profile 1"
#: Every NAOqi method the project calls, by service (robot.naoqi, robot.lifecycle, session.check, robot_setup).
CALLS: dict[str, tuple[str, ...]] = {
    "ALTextToSpeech": ("say", "setLanguage", "getLanguage", "getAvailableLanguages", "getVolume", "stopAll"),
    "ALAnimatedSpeech": ("say",),
    "ALAudioPlayer": ("playSine", "stopAll"),
    "ALLeds": ("fadeRGB",),
    "ALRobotPosture": ("goToPosture", "getPostureList"),
    "ALMotion": ("wakeUp", "rest", "robotIsWakeUp"),
    "ALMemory": ("subscriber", "getData", "insertData", "getEventList"),
    "ALAutonomousLife": ("getState", "setState"),
    "ALAudioDevice": ("getOutputVolume", "isAudioOutMuted"),
    "ALBattery": ("getBatteryCharge",),
    "ALSystem": ("robotName", "systemVersion"),
}
#: ALMemory keys the project reads (getData), besides the head buttons.
MEMORY_KEYS = ("FrontTactilTouched", "MiddleTactilTouched", "RearTactilTouched", "RobotConfig/Body/Type",
               "Device/SubDeviceList/LKneePitch/Temperature/Sensor/Status",
               "Device/SubDeviceList/LKneePitch/Temperature/Sensor/Value")
#: What ``record_profile`` says and the tone it plays to time them.
SAY_TEXT = "One two three four five six seven eight nine ten."
TONE_HZ, TONE_S = 880, 0.5


@dataclass
class Profile:
    """What one robot answers. ``cites``: a page (or "guess: ...") per field, for profiles written from the docs."""

    source: str = ""
    naoqi_version: str | None = None
    body_type: str | None = None
    languages: list[str] | None = None
    wake_up_result: bool | None = None
    say_s_per_char: float | None = None
    play_sine_extra_s: float | None = None  # playSine's return minus the tone (latency + blocking), round trip off
    memory: dict[str, Any] = field(default_factory=dict)
    #: Each ALMemory event the session watches (the NAO model's health keys) -> whether the robot declares it
    #: (``ALMemory.getEventList``): a robot without ``ALBattery/BatteryLow`` (NAOqi 2.8.6 and later) shows False.
    events: dict[str, bool] = field(default_factory=dict)
    signatures: dict[str, list[str]] = field(default_factory=dict)  # "Service.method" -> ["(params)return", ...]
    without: list[str] = field(default_factory=list)  # services of CALLS the robot lacks
    cites: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps({"format": FORMAT, **asdict(self)}, indent=2, sort_keys=True, default=str) + "\n"

    # -- served by the stand-in --------------------------------------------------------------------

    def apply(self, body: Any) -> None:
        """The stand-in's body answers as this robot did (version, languages, model, the body type)."""
        if self.naoqi_version:
            body.version = self.naoqi_version
        if self.languages:
            body.languages = list(self.languages)
        if self.body_type:
            body.model = model_called(self.body_type) or self.body_type
        body.silent_events = {event for event, declared in self.events.items() if not declared}

    def apply_services(self, services: dict[str, Any]) -> None:
        """Speech pace and the beep's extra time as measured; the memory values read."""
        tts, player, memory = services.get("ALTextToSpeech"), services.get("ALAudioPlayer"), services.get("ALMemory")
        if self.say_s_per_char is not None:
            for name in ("ALTextToSpeech", "ALAnimatedSpeech"):
                if name in services:
                    services[name].seconds_per_character = float(self.say_s_per_char)
        if self.play_sine_extra_s is not None and player is not None:
            player.latency_s = max(0.0, float(self.play_sine_extra_s))
        if memory is not None:
            for key, value in self.memory.items():
                memory.emit(key, value)
        del tts


def load_profile(path: str | Path) -> Profile:
    """A profile file (JSON); one ConfigError line when it is not one."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the robot profile ({exc.strerror}); check the path") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}:{exc.lineno}: not a robot profile (invalid JSON: {exc.msg}); record one with "
                          "`nao-trainer hardware-check --record FILE`") from None
    if not isinstance(data, dict) or data.pop("format", None) != FORMAT:
        raise ConfigError(f"{path}: not a robot profile (no 'format: {FORMAT}'); record one with "
                          "`nao-trainer hardware-check --record FILE`")
    known = set(Profile.__dataclass_fields__)
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{path}: unknown key {unknown[0]!r} in the robot profile; valid: {', '.join(sorted(known))}")
    return Profile(**data)


def _signatures(meta: dict[str, Any], wanted: tuple[str, ...]) -> dict[str, list[str]]:
    found: dict[str, list[str]] = {}
    for info in meta.get("methods", {}).values():
        name = info.get("name")
        if name in wanted:
            found.setdefault(name, []).append(f"{info.get('parametersSignature')}{info.get('returnSignature')}")
    return {name: sorted(sigs) for name, sigs in found.items()}


def record_profile(robot: Any, source: str = "", speed: float = 1.0) -> Profile:
    """What ``robot`` (a connected ``NaoqiRobot``) answers. It speaks one sentence, plays a 0.5 s tone and calls
    ``ALMotion.wakeUp`` (the robot stiffens and stands), then ``ALMotion.rest``. ``speed``: a stand-in's time
    factor (durations are given in robot seconds); 1 for a robot."""
    from nao_trainer.robot.lifecycle import _ask

    profile = Profile(source=source or f"recorded from {robot.url} at {time.strftime('%Y-%m-%d %H:%M:%S %Z')}")
    for service, methods in CALLS.items():
        if not robot.has_service(service):
            profile.without.append(service)
            continue
        meta = robot._service(service).metaObject()  # local: the proxy holds its service's meta object
        for name, sigs in _signatures(meta, methods).items():
            profile.signatures[f"{service}.{name}"] = sigs
    for key in MEMORY_KEYS:
        value = _ask(lambda k=key: robot.call("ALMemory", "getData", k))
        if value is not None:
            profile.memory[key] = value
    declared = _ask(lambda: robot.call("ALMemory", "getEventList"))
    if declared is not None:
        names = {str(x) for x in declared}
        profile.events = {key: key in names for _, key in default_model().health.items()}
    profile.naoqi_version = _ask(lambda: robot.call("ALSystem", "systemVersion"))
    profile.body_type = profile.memory.get("RobotConfig/Body/Type")
    languages = _ask(lambda: robot.call("ALTextToSpeech", "getAvailableLanguages"))
    profile.languages = None if languages is None else [str(x) for x in languages]
    rtt = robot.ping(robot.timeouts.default_s)
    t0 = time.monotonic()
    robot.say(SAY_TEXT)
    profile.say_s_per_char = round(max(0.0, time.monotonic() - t0 - rtt) * speed / len(SAY_TEXT), 3)
    timing = robot.beep(TONE_HZ, TONE_S, 0.3)  # robot seconds: a stand-in scales it itself
    profile.play_sine_extra_s = round(max(0.0, (timing.returned - timing.start - timing.rtt_s) * speed - TONE_S), 2)
    profile.wake_up_result = bool(robot.call("ALMotion", "wakeUp", timeout_s=60.0) is not False)
    _ask(lambda: robot.call("ALMotion", "rest", timeout_s=60.0))
    return profile


def diff(ours: Profile, theirs: Profile, documented_only: bool = False) -> list[str]:
    """One line per value where ``ours`` differs from ``theirs`` (``theirs.cites`` says where each comes from);
    ``documented_only``: only values ``theirs`` cites a page for (not those it marks as a guess)."""
    lines: list[str] = []

    def cite(key: str) -> str:
        return theirs.cites.get(key, theirs.cites.get(key.split("[")[0], ""))

    def keep(key: str) -> bool:
        return not documented_only or (bool(cite(key)) and not cite(key).startswith("guess"))

    def note(key: str, a: Any, b: Any) -> None:
        if a != b and keep(key):
            where = f" ({cite(key)})" if cite(key) else ""
            lines.append(f"{key}: stand-in/ours {a!r}, robot/theirs {b!r}{where}")

    for key in ("naoqi_version", "body_type", "languages", "wake_up_result", "say_s_per_char", "play_sine_extra_s"):
        if getattr(theirs, key) is not None:
            note(key, getattr(ours, key), getattr(theirs, key))
    for key in sorted(theirs.memory):
        note(f"memory[{key}]", ours.memory.get(key), theirs.memory[key])
    for key in sorted(theirs.events):
        note(f"events[{key}]", ours.events.get(key), theirs.events[key])
    for key in sorted(theirs.signatures):
        note(f"signatures[{key}]", ours.signatures.get(key), theirs.signatures[key])
    note("without", sorted(ours.without), sorted(theirs.without))
    return lines


def standin_profile(speed: float = 10.0, profile: Profile | None = None) -> Profile:
    """The stand-in's own answers (its defaults, or ``profile``'s), recorded over qi like a robot's; timed at
    ``speed`` and the durations scaled back to robot time."""
    from nao_trainer.robot.naoqi import NaoqiRobot
    from nao_trainer.robot.standin import StandIn

    standin = StandIn.start(speed=speed, profile=profile)
    try:
        robot = NaoqiRobot.connect(standin.url, 10.0)
        try:
            return record_profile(robot, "the stand-in's defaults" if profile is None else f"the stand-in playing "
                                  f"{profile.source}", speed)
        finally:
            robot.close()
    finally:
        standin.stop()
