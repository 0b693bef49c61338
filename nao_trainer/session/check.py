"""The pre-session check (`nao-trainer check`, and the start of `nao-trainer run`).

Before a participant sits down: is the robot there with the services the task needs and an
audible voice, does the EEG headband stream with its electrodes on the skin (judged over a few
seconds with the same quality rules as the session's monitor), is there room on the disk. Each
check gives one ``CheckResult``: OK or FAIL, what was found and, when it failed, how to fix it.
A failed *required* check carries the exit code of its kind (3 robot, 4 EEG, 2 disk).
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from nao_trainer.core.engagement import QualityThresholds, window_quality
from nao_trainer.eeg.inlet import EEGInlet, resolve_all
from nao_trainer.eeg.settings import ambiguous_streams, simulated_refusal
from nao_trainer.errors import ConfigError, RobotUnavailable, UserError
from nao_trainer.ports import RobotCallFailed, RobotConnectionLost
from nao_trainer.robot.address import redact_url
from nao_trainer.robot.desktop import DesktopRobot
from nao_trainer.session.config_rules import LANGUAGES, is_robot_address
from nao_trainer.session.record import WRITE_CAUSES
from nao_trainer.robot.lifecycle import _ask, read_status, refused_life_line
from nao_trainer.robot.model import default_model
from nao_trainer.session.robot_setup import available_languages, missing_language_line

#: Exit codes of failed required checks, by kind (as `nao-trainer run` would fail later).
EXIT = {"robot": 3, "eeg": 4, "disk": 2}
#: Services every session calls; ALMemory is added for head-button answers.
TASK_SERVICES = ("ALTextToSpeech", "ALAnimatedSpeech", "ALAudioPlayer", "ALLeds", "ALRobotPosture", "ALMotion")
#: Below this system output volume (ALAudioDevice, 0-100) a participant may not hear the letters.
MIN_OUTPUT_VOLUME = 30
#: Below this battery charge (percent) a session may not last (a NAO runs roughly an hour on a charge).
MIN_BATTERY = 30
#: Free space a session needs with room to spare (raw EEG is ~15 MB an hour; logs are small).
MIN_FREE_MB = 200
#: How long the EEG check listens (seconds; at least one analysis window plus a second).
EEG_LISTEN_S = 3.0

#: What to do about a channel the quality rules reject, by reason (core.engagement.window_quality).
CHANNEL_FIXES = {
    "flat": "the electrode is off the skin: moisten it and press the headband on",
    "saturated": "the amplifier sits at its rail: re-seat the headband and check that electrode",
    "implausible amplitude": "movement or a loose electrode: tighten the headband and ask the participant to sit still",
    "non-finite": "the bridge sends invalid samples: restart it",
}


@dataclass(frozen=True)
class CheckResult:
    """One check: its kind ("robot", "eeg", "disk"), the outcome, what was found and the fix."""

    kind: str
    ok: bool
    detail: str
    fix: str = ""
    required: bool = True

    @property
    def exit_code(self) -> int:
        """Non-zero for a failed required check."""
        return 0 if self.ok or not self.required else EXIT[self.kind]

    def line(self) -> str:
        """``OK   robot  ...`` or ``FAIL eeg    ...; fix: ...`` (one line)."""
        text = f"{'OK' if self.ok else 'FAIL':<4} {self.kind:<5}  {self.detail}"
        if not self.ok and self.fix:
            text += f"; fix: {self.fix}"
        if not self.ok and not self.required:
            text += " (not required: the session runs without it)"
        return " ".join(text.split("\n"))


@dataclass(frozen=True)
class CheckPlan:
    """What to check, taken from a study configuration (``plan_from_config``)."""

    robot_url: str
    connect_deadline_s: float
    needs_buttons: bool
    eeg_mode: str
    eeg: Any  # eeg.settings.EEGSettings, or None when EEG is off
    output_dir: Path
    speed: float = 1.0
    write_dirs: tuple[Path, ...] = ()  # other folders the session writes (the participant's learning state)
    person: bool = False  # a person answers or a real robot plays: a simulated EEG stream fails (issue 17)
    model: Any = None  # robot.model.RobotModel (None: a NAO with its defaults)
    language: str = "en"  # session.language: its voice must be installed on the robot
    autonomous_life: str = "disabled"  # the state a session sets: a robot refusing setState fails ...
    allow_life_on: bool = False  # ... unless the study lets the session run with life on
    session_minutes: float | None = None  # how long a session of the study lasts (check's battery estimate)


def plan_from_config(config: Any) -> CheckPlan:
    """The checks a study configuration (``session.config.StudyConfig``) calls for."""
    return CheckPlan(robot_url=config.robot.url, connect_deadline_s=float(config.robot.connect_deadline_s),
                     needs_buttons=config.answers.input in ("tactile", "simulated"),
                     eeg_mode=config.eeg.mode, eeg=config.eeg, output_dir=config.output_dir(),
                     speed=float(config.timing.speed), write_dirs=_state_dirs(config),
                     person=config.answers.input != "simulated" or is_robot_address(config.robot.url),
                     model=config.robot.robot_model(), language=config.session.language,
                     autonomous_life=config.robot.autonomous_life, allow_life_on=config.robot.allow_life_on,
                     session_minutes=session_minutes(config))


def session_minutes(config: Any) -> float:
    """A session's length in minutes, estimated from the study: its time limit, else its turns at a mid-span turn
    (level announcement, letters, answer window used half, speech around it: ~6 s of it at a NAO's pace)."""
    if config.session.max_duration_s is not None:
        return float(config.session.max_duration_s) / 60
    timing = config.timing
    length = 5  # a mid-range sequence (core.task.LENGTHS spans 3..9 letters)
    turn_s = (timing.pause_before_level_s + length * (timing.letter_gap_s + 0.5)
              + timing.response_timeout_s(length) / 2 + 6.0)
    return (config.session.turns * turn_s + 60.0) / 60  # + greeting, instructions, practice, goodbye


def _state_dirs(config: Any) -> tuple[Path, ...]:
    """The participant's folder when the policy keeps a participant state there (its declaration says so)."""
    state = config.policy_state_file()
    return () if state is None else (state.parent,)


def run_checks(plan: CheckPlan, report: Callable[[CheckResult], None] | None = None,
               eeg_listen_s: float = EEG_LISTEN_S) -> list[CheckResult]:
    """Run every check of ``plan`` (disk, robot, EEG); ``report`` sees each result as it comes."""
    results = []
    for check in (lambda: check_disk(plan.output_dir, write_dirs=plan.write_dirs), lambda: check_robot(plan),
                  lambda: check_eeg(plan, eeg_listen_s)):
        result = check()
        results.append(result)
        if report is not None:
            report(result)
    return results


def exit_code(results: list[CheckResult]) -> int:
    """The exit code of the first failed required check, 0 when all required checks passed."""
    return next((r.exit_code for r in results if r.exit_code), 0)


# ------------------------------------------------------------------------------------------------
# Disk
# ------------------------------------------------------------------------------------------------


def check_disk(output_dir: Path, min_free_mb: float = MIN_FREE_MB, write_dirs: tuple[Path, ...] = ()) -> CheckResult:
    """Free space where the session folders go, and that every folder the session writes (the output
    folder, the participant's) can be written (the nearest existing parent when not created yet)."""
    folder = Path(output_dir)
    for target in (folder, *write_dirs):
        problem = _write_problem(Path(target))
        if problem:
            return CheckResult("disk", False, f"{target}: cannot write there ({problem[0]})", problem[1])
    probe = _existing(folder)
    try:
        free_mb = shutil.disk_usage(probe).free / 1e6
    except OSError as exc:
        return CheckResult("disk", False, f"{folder}: cannot read the free space ({exc.strerror})",
                           "choose another output folder (--out)")
    if free_mb < min_free_mb:
        return CheckResult("disk", False, f"{folder}: {free_mb:.0f} MB free, a session needs {min_free_mb:.0f} MB",
                           "free some space or choose another output folder (--out)")
    return CheckResult("disk", True, f"{folder}: {free_mb / 1000:.1f} GB free")


def _existing(folder: Path) -> Path:
    probe = folder
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return probe


def _write_problem(folder: Path) -> tuple[str, str] | None:
    """(cause, fix) when nothing can be written in ``folder`` (or where it will be created), else None.

    Tried, not inferred from the permission bits: a probe file is created and removed (root passes
    permission bits; a read-only file system, a full disk or a file in the way does not)."""
    probe = _existing(folder)
    if not probe.is_dir():
        return f"{probe} is a file, not a folder", "remove it or choose another folder"
    try:
        fd, name = tempfile.mkstemp(prefix=".nao-trainer-probe-", dir=probe)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        return WRITE_CAUSES.get(exc.errno or 0, (exc.strerror or str(exc), "choose another folder"))
    return None


# ------------------------------------------------------------------------------------------------
# Robot
# ------------------------------------------------------------------------------------------------


def check_robot(plan: CheckPlan) -> CheckResult:
    """The robot answers, offers the task's services and speaks loud enough."""
    if plan.robot_url == "desktop":
        return _check_desktop()
    standin = None
    url = plan.robot_url
    try:
        if url == "mock":
            from nao_trainer.robot.standin import StandIn  # heavy: qi

            standin = StandIn.start("tcp://127.0.0.1:0", speed=max(plan.speed, 1.0))
            url = standin.url
        return _check_naoqi(url, plan, "the stand-in (in-process)" if standin else None)
    finally:
        if standin is not None:
            standin.stop()


def _check_naoqi(url: str, plan: CheckPlan, label: str | None) -> CheckResult:
    from nao_trainer.robot.naoqi import NaoqiRobot  # heavy: qi

    where = label or redact_url(url)
    model = plan.model or default_model()
    try:
        robot = NaoqiRobot.connect(url, plan.connect_deadline_s, buttons=model.buttons)
    except ConfigError:  # a malformed address or a missing login: an input error (exit 2), not the robot's
        raise
    except UserError as exc:  # unreachable, unresolvable: the message says how to fix it
        return CheckResult("robot", False, str(exc))
    try:
        probe = model.probe(robot.has_service, plan.needs_buttons)
        if probe.missing:
            return CheckResult("robot", False, f"{where}: no {', '.join(probe.missing)} service ({model.title})",
                               "check robot.model, the robot's NAOqi version (2.8 or 2.9) and that it has finished booting")
        problem = _language_problem(robot, plan.language) or _life_problem(robot, plan)
        if problem:
            return CheckResult("robot", False, f"{where}: {problem[0]}", problem[1])
        result = _robot_status_result(where, len(probe.present), read_status(robot))
        if not result.ok:
            return result
        extra = [f"{model.title}; {line}" for line in probe.degraded]
        estimate, fix = _endurance(robot, model, plan)
        detail = "; ".join([result.detail, *extra, estimate])
        return CheckResult("robot", not fix, detail, fix)
    except (RobotConnectionLost, RobotUnavailable, RobotCallFailed) as exc:
        return CheckResult("robot", False, f"{where}: {exc}", "check the robot and its network, then try again")
    finally:
        robot.close()


def _language_problem(robot: Any, language: str) -> tuple[str, str] | None:
    """(what, fix) when ``language``'s voice is not installed on the robot (ALTextToSpeech.getAvailableLanguages)."""
    name = LANGUAGES[language]
    installed = available_languages(robot)
    if installed is None or name in installed:
        return None
    line = missing_language_line(language, name, installed)
    what, _, fix = line.partition(": ")
    return what, fix


def _life_problem(robot: Any, plan: CheckPlan) -> tuple[str, str] | None:
    """(what, fix) when the robot refuses ALAutonomousLife.setState and the study wants life off without
    allowing it on: asked with the state it is in already, so ``check`` changes nothing."""
    if plan.autonomous_life != "disabled" or plan.allow_life_on or not robot.has_service("ALAutonomousLife"):
        return None
    try:
        state = robot.call("ALAutonomousLife", "getState")
        robot.call("ALAutonomousLife", "setState", state)
    except RobotCallFailed as exc:
        line = refused_life_line("disabled", f"RobotCallFailed: {exc}")
        what, _, fix = line.partition("; ")
        return what, fix
    return None


def _endurance(robot: Any, model: Any, plan: CheckPlan) -> tuple[str, str]:
    """Will a session of the study's length last on this battery charge and with these joint temperatures?
    (estimate line, fix; the fix is empty when it will).

    Both are estimates, guesses to confirm on a robot, and the line says so:

    * battery: the charge (``ALBattery.getBatteryCharge``, percent) times ``full_battery_minutes`` (a full charge's
      minutes in a session) against the session's length (``session_minutes``);
    * heat: the warmest joint that carries the robot (``model.joints``; ``Device/SubDeviceList/<joint>/Temperature/
      Sensor/Value``, °C, http://doc.aldebaran.com/2-8/family/nao_technical/lola/actuator_sensor_names.html) is
      projected linearly: now + ``heat_c_per_min`` x the session's minutes, as if the robot stood stiff the whole
      session (no cooling between turns, no sitting). It fails when the projection reaches ``hot_joint_c``, the
      temperature where the status turns hot (1) and NAO starts limiting the stiffness; a joint whose status is
      already non-null (``.../Temperature/Sensor/Status``) fails as hot now."""
    charge = _ask(lambda: robot.call("ALBattery", "getBatteryCharge"))
    hot, temps = [], {}
    for joint in model.joints:
        status = _ask(lambda j=joint: robot.call("ALMemory", "getData", f"Device/SubDeviceList/{j}/Temperature/Sensor/Status"))
        if isinstance(status, (int, float)) and status >= 1:
            hot.append(f"{joint} (status {int(status)})")
        value = _ask(lambda j=joint: robot.call("ALMemory", "getData", f"Device/SubDeviceList/{j}/Temperature/Sensor/Value"))
        if isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value):
            temps[joint] = float(value)
    need = plan.session_minutes
    parts, fix = [], ""
    if charge is not None and need is not None:
        lasts = float(charge) / 100 * model.full_battery_minutes()
        parts.append(f"battery {int(charge)}% lasts ~{lasts:.0f} min, the session needs ~{need:.0f} min")
        if lasts < need:
            fix = (f"charge the robot first (about {need / model.full_battery_minutes() * 100:.0f}% is needed), "
                   "or shorten the session (session.turns / session.max_duration_s)")
    if hot:
        parts.append(f"hot joints now: {', '.join(hot)}")
        fix = fix or (f"let the robot cool 15-20 minutes with its motors off ({model.title} sitting or resting) "
                      "before a session: standing heats the legs further")
    elif temps and need is not None:
        joint, now_c = max(temps.items(), key=lambda item: item[1])
        rate, limit = model.heat_c_per_min(), model.hot_joint_c()
        then_c = now_c + rate * need
        parts.append(f"{joint} {now_c:.0f} °C now, ~{then_c:.0f} °C after ~{need:.0f} min standing (estimate: "
                     f"+{rate:g} °C/min, hot at ~{limit:.0f} °C)")
        if then_c >= limit:
            fix = fix or (f"{joint} would be hot after ~{max(0.0, limit - now_c) / rate:.0f} min of standing: let the "
                          f"robot cool with its motors off ({model.title} sitting or resting) first, or shorten the "
                          "session (session.turns / session.max_duration_s)")
    return ("; ".join(parts) or "battery and joint temperatures unknown"), fix


def _robot_status_result(where: str, n_services: int, status: Any) -> CheckResult:
    """The robot's system volume and mute (ALAudioDevice, not the speech gain, which stays 1.0 when the
    robot is muted), its battery, Autonomous Life and NAOqi version in one line; FAIL on what a session cannot fix."""
    detail = f"{where}: {n_services} services the task needs; {status.describe()}"
    if status.muted:
        return CheckResult("robot", False, detail, "unmute the robot (ALAudioDevice.muteAudioOut(false), or its web "
                           "page), then check again")
    if status.output_volume is not None and status.output_volume < MIN_OUTPUT_VOLUME:
        return CheckResult("robot", False, detail, f"raise the robot's volume to {MIN_OUTPUT_VOLUME}% or more "
                           "(ALAudioDevice.setOutputVolume, its web page, or the head buttons' volume gesture)")
    if status.battery is not None and status.battery < MIN_BATTERY:
        return CheckResult("robot", False, detail, f"charge the robot to {MIN_BATTERY}% or more before a session")
    return CheckResult("robot", True, detail)


def _check_desktop() -> CheckResult:
    try:
        robot = DesktopRobot.start()
    except UserError as exc:
        return CheckResult("robot", False, str(exc))
    try:
        where = "the sound device" if robot.player else "WAV files in the session folder (no sound device)"
        return CheckResult("robot", True, f"desktop: espeak-ng speaks, audio goes to {where}")
    finally:
        robot.close()


# ------------------------------------------------------------------------------------------------
# EEG
# ------------------------------------------------------------------------------------------------


def check_eeg(plan: CheckPlan, listen_s: float = EEG_LISTEN_S) -> CheckResult:
    """The EEG stream is there and each scalp channel is clean most of the time over ``listen_s``.

    The device (``eeg.device``) says how its stream is found and judged (its montage); a device that makes
    its stream in this process (a BrainFlow board, also the synthetic one) is opened and listened to."""
    if plan.eeg_mode == "off":
        return CheckResult("eeg", True, "EEG off (eeg.mode: off)", required=False)
    settings = plan.eeg
    device = settings.eeg_device()
    simulated = plan.eeg_mode == "simulated"
    if simulated and not device.opens_in_process:
        return CheckResult("eeg", True, f"a {device.montage(True).board} is started with the session (no electrodes "
                           "to check)", required=False)
    required = bool(settings.required) and not simulated
    try:
        source = device.open(settings, np.random.default_rng(0), simulated=simulated)
    except UserError as exc:  # the board is not there, the library is missing: what and how to fix
        return CheckResult("eeg", False, str(exc), "", required)
    try:
        return _check_source(plan, settings, source, required, listen_s)
    finally:
        source.stop()


def _check_source(plan: CheckPlan, settings: Any, source: Any, required: bool, listen_s: float) -> CheckResult:
    query, montage = source.query, source.montage
    infos = resolve_all(query, settings.processing.resolve_timeout_s, settings.lsl_scope)
    info = query.pick(infos)
    many = ambiguous_streams(query.describe(), query.source_id, [(i.name(), i.source_id()) for i in infos])
    if many:  # issue 17: a session could take the wrong headband
        return CheckResult("eeg", False, many, "pin one: eeg.source_id: ID in the study file, or --eeg-source-id ID",
                           required)
    if info is None:
        return CheckResult("eeg", False, f"no EEG stream ({query.describe()}) found by LSL in scope "
                           f"{settings.lsl_scope!r} within {settings.processing.resolve_timeout_s:g} s",
                           f"{settings.eeg_device().start_hint}; check eeg.stream_name / eeg.source_id", required)
    try:
        inlet = EEGInlet.open(info, settings.lsl_scope, montage=montage)
    except Exception as exc:  # noqa: BLE001 - irregular rate, vanished: report, do not crash the check
        return CheckResult("eeg", False, f"EEG stream {info.name()!r} (source_id {info.source_id()!r}) cannot be "
                           f"used: {exc}", "check the headband bridge", required)
    refusal = simulated_refusal(inlet.identity(), settings) if plan.person else ""
    if refusal:  # the session would refuse it too (exit 4)
        inlet.close()
        head, _, fix = refusal.partition(": its engagement would be recorded as theirs; ")
        return CheckResult("eeg", False, head + ": its engagement would be recorded as theirs", fix, True)
    try:
        kind = f"{inlet.acquisition}, " if inlet.simulated else ""
        board = f"{montage.board}: " if source.producer is not None else ""
        found = (f"{board}stream {inlet.name!r} ({kind}source_id {inlet.source_id!r}, {inlet.fs:g} Hz, "
                 f"{len(inlet.scalp_labels)} scalp channels)")
        x = _listen(inlet, max(listen_s, settings.processing.window_s + 1.0))
    finally:
        inlet.close()
    if len(x) < inlet.fs * settings.processing.window_s:
        return CheckResult("eeg", False, f"{found} sent {len(x)} samples in {listen_s:g} s",
                           "the headband is paired but not streaming: restart the bridge", required)
    return _contact_result(found, x, inlet.fs, inlet.scalp_labels, settings.processing, required, montage.thresholds)


def _listen(inlet: Any, seconds: float) -> np.ndarray:
    chunks = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        x, _ = inlet.pull(min(0.2, max(0.01, deadline - time.monotonic())))
        if len(x):
            chunks.append(x)
    return np.concatenate(chunks) if chunks else np.empty((0, len(inlet.scalp_index)))


def channel_quality(x: np.ndarray, fs: float, window_s: float, hop_s: float,
                    thresholds: QualityThresholds = QualityThresholds()) -> tuple[np.ndarray, list[str]]:
    """Per channel: the fraction of analysis windows the monitor's rules call clean, and the commonest reason."""
    n = int(round(window_s * fs))
    hop = max(1, int(round(hop_s * fs)))
    starts = range(0, max(1, len(x) - n + 1), hop)
    clean = np.zeros(x.shape[1])
    reasons: list[dict[str, int]] = [{} for _ in range(x.shape[1])]
    for start in starts:
        ok, why = window_quality(x[start:start + n], fs, thresholds)
        clean += ok
        for c, reason in enumerate(why):
            if reason:
                reasons[c][reason] = reasons[c].get(reason, 0) + 1
    worst = [max(r, key=r.get) if r else "" for r in reasons]
    return clean / len(starts), worst


def _contact_result(found: str, x: np.ndarray, fs: float, labels: tuple[str, ...], processing: Any,
                    required: bool, thresholds: QualityThresholds = QualityThresholds()) -> CheckResult:
    fraction, worst = channel_quality(x, fs, processing.window_s, processing.hop_s, thresholds)
    good = fraction >= processing.min_quality
    parts = [f"{label} {f:.0%}" + ("" if ok else f" ({why})") for label, f, ok, why in zip(labels, fraction, good, worst)]
    detail = f"{found}: contact {', '.join(parts)}"
    if good.sum() >= processing.min_clean_channels and good.all():
        return CheckResult("eeg", True, detail, required=required)
    fixes = "; ".join(f"{label}: {CHANNEL_FIXES.get(why, why)}" for label, ok, why in zip(labels, good, worst) if not ok)
    if good.sum() >= processing.min_clean_channels:  # usable, but say which electrode to fix
        return CheckResult("eeg", True, f"{detail}; {fixes}", required=required)
    return CheckResult("eeg", False, f"{detail}: fewer than {processing.min_clean_channels} clean channels",
                       fixes, required)
