"""Wiring: builds the robot, answers, EEG monitor and policy a study asks for, and plays a session.

The only module of the session that knows the concrete adapters (``robot.naoqi``, the stand-in,
``answers``, ``eeg.monitor``, the policies); the engine sees them through ``ports`` only.
"""
from __future__ import annotations

import json
import secrets
import signal
import sys
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, TextIO

import numpy as np

from nao_trainer import __version__
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import ConfigError, DataError, Interrupted, RobotUnavailable, UserError
from nao_trainer.files import PROJECT_ROOT, read_json, write_text_atomic
from nao_trainer.ports import (AnswerSource, CommandQueue, EngagementMonitor, NullMonitor, Policy, Robot,
                               RobotConnectionLost, SessionObserver)
from nao_trainer.session.behaviors import Behaviors, load_behaviors
from nao_trainer.session.config import DESKTOP, MOCK, StudyConfig, is_robot_address, load_config
from nao_trainer.session.dialogue import Dialogue, load_dialogue
from nao_trainer.session.engine import EXIT_INTERRUPTED, EXIT_ROBOT_LOST, Session, who_stopped
from nao_trainer.session.record import CHECKPOINT, CHECKPOINT_FORMAT, SessionRecorder, ensure_output_dir, read_turns, versions
from nao_trainer.session.stage import leave_robot_safe
from nao_trainer.session.turn import SessionResult, summary_data

#: session.json statuses of a session that ended as planned: ``--resume`` refuses them.
FINISHED = ("completed", "stopped", "time limit")
LOOPBACK = ("127.0.0.1", "localhost", "::1")


@dataclass(frozen=True)
class RunOptions:
    """Things chosen on the command line that are not study configuration.

    ``keys``: read operator keys from the terminal (only when stdin is a terminal and answers do
    not come from the keyboard). ``console``: serve the supervisor console (also ``console.enabled``);
    ``console_bind`` given here is the explicit choice a non-loopback address needs. ``commands`` and
    ``observer`` let a program steer and watch the session (the keys and the console use the same queue).
    """

    quiet: bool = False
    keys: bool = False
    console: bool = False
    console_port: int | None = None
    console_bind: str | None = None
    resume: Path | None = None
    fresh_policy: bool = False
    commands: CommandQueue | None = None
    observer: SessionObserver | None = None


@contextmanager
def _signals_as_interrupt() -> Iterator[None]:
    """SIGTERM behaves like Ctrl-C (an ``Interrupted`` exception) while a session runs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise Interrupted(signal.Signals(signum).name)

    previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, handler),
                # Ctrl-C must stop a session even when started from a shell that ignores SIGINT (`&`).
                signal.SIGINT: signal.signal(signal.SIGINT, signal.default_int_handler)}
    try:
        yield
    finally:
        for signum, h in previous.items():
            signal.signal(signum, h)


@contextmanager
def _no_interrupts() -> Iterator[None]:
    """Shutdown must finish: a second Ctrl-C during it is ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def build_simulator(config: StudyConfig) -> UserSimulator:
    """The simulated participant's model: a fitted one (``participant_model.user_model``, ``--user-model``)
    or the config's level rates."""
    spec = config.participant_model.user_model
    if spec:
        try:
            from nao_trainer.learn.artifacts import load_simulator
        except ImportError as exc:
            raise ConfigError(f"user model {spec!r}: data-driven simulators are not available in this install ({exc})") from None
        shipped = PROJECT_ROOT / spec
        if spec.endswith(".json") and not Path(spec).is_absolute() and not Path(spec).exists() and shipped.exists():
            spec = str(shipped)  # a file shipped with the project (e.g. the demo's sim/participants/level4.json)
        return load_simulator(spec)
    pm = config.participant_model
    return UserSimulator.from_level_rates("config-levels", list(pm.success_by_level), list(pm.engagement_by_level))


def open_engagement_monitor(config: StudyConfig, session_dir: Path, rng: np.random.Generator) -> EngagementMonitor:
    """The EEG monitor of the study's ``eeg.mode`` ("off" -> ports.NullMonitor)."""
    eeg = config.eeg
    if eeg.mode == "off":
        return NullMonitor()  # without importing pylsl
    from nao_trainer.eeg.factory import open_monitor  # sets LSL's scope before its first stream object

    return open_monitor(eeg.mode, eeg, session_dir, rng, config.participant.pseudonym,
                        record_xdf=True,  # session.xdf beside the session's files (eeg.xdf: false turns it off)
                        # issue 17: a person answering or a real robot never takes a simulated stream for theirs
                        person=config.answers.input != "simulated" or is_robot_address(config.robot.url))


def run_session(config: StudyConfig, options: RunOptions = RunOptions(), progress: TextIO | None = None,
                resume: "Resumption | None" = None) -> SessionResult:
    """Connect, play and record one session as the study says; returns its result.

    Raises ``UserError`` subclasses before anything is written (invalid files, robot unreachable:
    ``RobotUnavailable``, exit code 3). Ctrl-C ends with status "interrupted" and exit code 130
    after leaving the robot safe and closing the files. ``resume`` (from ``prepare_resume``)
    continues an interrupted session folder instead of creating one.
    """
    progress = None if options.quiet else (progress or sys.stderr)
    language = config.session.language
    dialogue = load_dialogue(config.session.dialogue_path)
    if dialogue.language != language:
        raise ConfigError(f"{dialogue.source}: dialogue language {dialogue.language!r} differs from session.language "
                          f"{language!r}; point session.dialogue at a {language} file")
    behaviors = load_behaviors(config.session.behaviors_path)
    seed = config.session.seed if resume is None else resume.seed
    seed = int(seed) if seed is not None else secrets.randbelow(2**31)
    simulator = build_simulator(config) if config.answers.input == "simulated" else None
    console_bind = _console_bind(config, options)
    from nao_trainer.session.policies import make_policy

    # Loaded once, before the robot moves: a missing or stale policy, or a torn/foreign learning-state
    # file, is found here. Per participant by default (policy.state_path); "{session}" = the session folder,
    # bound once the folder exists (_run_wired).
    policy = make_policy(config.policy.kind, list(config.policy.schedule), config.policy.learning,
                         config.policy_state_file(), config.policy.guidance, options.fresh_policy,
                         study=config)
    # Not closed on failure here: closing a learning policy saves it, and nothing is written before the robot answers.
    ensure_output_dir(config.output_dir())  # an unusable output folder is found before the robot moves
    preflight(config, progress)  # robot, disk and a required EEG stream, before any session folder exists

    with _signals_as_interrupt():
        return _run_wired(config, progress, dialogue, behaviors, seed, simulator, policy, options, resume, console_bind)


def _console_bind(config: StudyConfig, options: RunOptions) -> str | None:
    """The console's address, or None without a console. Not loopback only when asked on the command line."""
    if not (options.console or config.console.enabled):
        return None
    if options.console_bind:
        return options.console_bind
    if config.console.bind not in LOOPBACK:
        raise ConfigError(f"console.bind {config.console.bind!r}: the console serves only this machine unless "
                          "--console-bind ADDRESS is given on the command line")
    return config.console.bind


def preflight(config: StudyConfig, progress: TextIO | None) -> None:
    """The pre-session check (``session.check``) at the start of a run: a failed required check stops it
    with its own exit code before anything is written. EEG is judged here only when it is required (a
    missing optional stream is reported by the monitor, which then keeps looking)."""
    from nao_trainer.errors import EEGUnavailable
    from nao_trainer.session.check import check_disk, check_eeg, check_robot, plan_from_config

    plan = plan_from_config(config)
    checks = [lambda: check_disk(plan.output_dir), lambda: check_robot(plan)]
    if config.eeg.mode == "lsl" and config.eeg.required:
        checks.append(lambda: check_eeg(plan, config.eeg.processing.window_s + 0.5))
    errors = {"robot": RobotUnavailable, "eeg": EEGUnavailable, "disk": UserError}
    for check in checks:
        result = check()
        if result.exit_code:
            raise errors[result.kind](f"{result.detail}; {result.fix}" if result.fix else result.detail)
        if progress:
            print(f"check: {result.line()}", file=progress, flush=True)


def _run_wired(config: StudyConfig, progress: TextIO | None, dialogue: Dialogue, behaviors: Behaviors, seed: int,
               simulator: UserSimulator | None, policy: Policy, options: RunOptions, resume: "Resumption | None",
               console_bind: str | None) -> SessionResult:
    """``run_session`` once the files and the policy are loaded: connect, wire the ports, play, clean up."""
    from nao_trainer.robot.naoqi import NaoqiRobot, redact_url

    session_ss, policy_ss, participant_ss, eeg_ss = np.random.SeedSequence(seed).spawn(4)
    input_kind = config.answers.input
    speed = config.timing.speed
    url = config.robot.url
    standin = robot = recorder = monitor = answers = buttons = keys = console = None
    policy_to_close: Policy | None = None  # closed (and a learning policy saved) only once the folder exists
    session: Session | None = None
    status, code, error, summary = "error", 1, "", ""
    commands = options.commands or CommandQueue()
    result: SessionResult | None = None
    try:
        if url == MOCK:
            from nao_trainer.robot.standin import StandIn

            standin = StandIn.start("tcp://127.0.0.1:0", speed=speed)
            connect_url = standin.url
        else:
            connect_url = url
        if url == DESKTOP:
            robot = _desktop_robot(input_kind, speed, progress)
        else:
            if progress:
                print(f"connecting to the robot at {'the stand-in ' + connect_url if standin else redact_url(connect_url)} ...",
                      file=progress, flush=True)
            robot = NaoqiRobot.connect(connect_url, config.robot.connect_deadline_s, None,
                                       debounce_s=config.answers.debounce_s / speed)
        # Only now that the robot answered does anything get written.
        recorder = SessionRecorder(config.output_dir(), config.participant.pseudonym)
        if resume is None:
            path = recorder.open({
                "nao_trainer": __version__, "versions": versions(), "seed": seed,
                "robot": "stand-in (in-process)" if standin else repr(robot) if url == DESKTOP else redact_url(url),
                "input": input_kind, "policy": config.policy.kind,
                "user_model": simulator.name if simulator else None,
                "config": config.snapshot(), "argv": sys.argv[1:],
            })
        else:
            path = recorder.reopen(resume.folder, {"after_turn": resume.checkpoint["completed"], "argv": sys.argv[1:]})
            resume.recover_row(recorder)
        if progress:
            print(f"session folder: {path}" + (f" (resumed after turn {resume.checkpoint['completed']})" if resume else ""),
                  file=progress, flush=True)
        if url == DESKTOP:
            robot.record_audio_to(path / "audio")
        policy_state = _policy_state(policy, config, options.fresh_policy, progress)
        observer = options.observer
        if console_bind is not None:
            try:
                from nao_trainer.console.server import Console
            except ImportError as exc:
                raise ConfigError(f"--console needs the console extra ({exc}); install it with "
                                  "pip install -e '.[console]'") from None

            console = Console.start(commands, console_bind, options.console_port if options.console_port is not None
                                    else config.console.port, recorder.event)
            observer = console.hub if observer is None else _Both(console.hub, observer)
            recorder.event("console", url=console.url, bind=console_bind)  # never the token
            if progress:
                if console_bind not in LOOPBACK:
                    print(f"warning: the console listens on {console_bind}: anyone who can reach this address "
                          "and has the link can steer the session", file=progress, flush=True)
                print(f"console: {console.link} (open it in a browser on this machine)", file=progress, flush=True)
        monitor = open_engagement_monitor(config, path, np.random.default_rng(eeg_ss))
        if config.eeg.mode != "off" and progress:  # which headband this session listens to (events.jsonl too)
            print(f"EEG ({config.eeg.mode}): {monitor.describe()}", file=progress, flush=True)
        participant_rng = np.random.default_rng(participant_ss)
        answers, buttons = _make_answers(config, robot, standin, connect_url, simulator, monitor, participant_rng,
                                         progress)
        policy_rng = np.random.default_rng(policy_ss)
        policy.bind_state_dir(path)
        policy_to_close = policy
        if options.keys and input_kind != "keyboard":
            from nao_trainer.console.keys import KeyReader

            keys = KeyReader.start_if_terminal(commands, progress)
        session = Session(config, robot, answers, policy, recorder, dialogue, behaviors, np.random.default_rng(session_ss),
                          policy_rng, monitor, progress, commands=commands, observer=observer,
                          rngs={"participant": participant_rng},
                          resume=None if resume is None else dict(resume.checkpoint, rows_before=resume.rows),
                          policy_state=policy_state)
        if console is not None:
            console.hub.set_sources(eeg=monitor.live, elapsed=session.elapsed_s)
        try:
            code = session.run()
        except (KeyboardInterrupt, Interrupted) as exc:
            session.interrupted_by_operator(who_stopped(exc))
            code = EXIT_INTERRUPTED
        status, error = session.status, session.error
    except (KeyboardInterrupt, Interrupted):
        status, code = "interrupted", EXIT_INTERRUPTED
    except RobotConnectionLost as exc:  # dropped while setting up (buttons): nothing was played yet
        status, code, error = "robot lost", EXIT_ROBOT_LOST, str(exc)
        raise RobotUnavailable(f"lost the robot while starting the session: {exc}") from None
    except UserError as exc:  # e.g. a required EEG stream missing: recorded, then reported by the CLI
        status, code, error = "error", exc.exit_code, str(exc)
        raise
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        with _no_interrupts():
            if keys is not None:
                keys.close()  # the terminal is restored first, whatever happens next
            if session is not None and status != "completed":
                session.leave_safe()
            elif session is None and robot is not None and status != "completed":
                leave_robot_safe(robot, behaviors, config.robot.posture_speed, recorder)
            for closer in (answers, policy_to_close, monitor, buttons):
                _close_quietly(closer, recorder)
            if robot is not None:
                _close_quietly(robot, recorder)
            if session is not None and session.completed:
                summary = str(policy.status().get("summary", ""))  # e.g. the user model the participant matched
            if recorder is not None and recorder.is_open:
                if standin is not None:
                    _write_transcript(recorder.path, standin.transcript(), append=resume is not None)
                if summary:
                    recorder.event("policy_summary", summary=summary)
                recorder.close(status, code, total_score=session.total if session else 0, error=error,
                               policy_summary=summary or None,
                               eeg_stream=getattr(monitor, "stream_identity", None))  # issue 17: which stream, simulated?
            if standin is not None:
                standin.stop()
            result = SessionResult(recorder.path if recorder else None, status, code, session.rows if session else [],
                                   seed, error, policy_summary=summary)
            if console is not None:
                console.hub.notify("summary", summary_data(result))
                console.stop()
    assert result is not None
    return result


class _Both:
    """Two observers (the console and a program's own)."""

    def __init__(self, a: SessionObserver, b: SessionObserver) -> None:
        self.a, self.b = a, b

    def notify(self, kind: str, data: dict) -> None:
        self.a.notify(kind, data)
        self.b.notify(kind, data)


def _policy_state(policy: Policy, config: StudyConfig, fresh: bool, progress: TextIO | None) -> dict[str, Any] | None:
    """Which learning state the policy starts from (the session logs it as ``policy_state``), None when it does not learn."""
    if not (config.policy.learning and config.policy.kind.startswith("usp:")):
        return None
    from nao_trainer.learn.usp import LivePolicy

    assert isinstance(policy, LivePolicy)
    loaded, target = policy.loaded_from, config.policy_state_file()
    if progress and target is not None:
        print(f"policy state: {target} ({'continued' if loaded else 'new'})", file=progress, flush=True)
    return {"policy": policy.name, "loaded_from": str(loaded) if loaded else "trained policy",
            "saves_to": str(target) if target else "session folder", "fresh": fresh,
            "turns_learned": policy.payload["live"]["turns_learned"]}


# ----------------------------------------------------------------------------------------------
# Resuming an interrupted session (run --resume)
# ----------------------------------------------------------------------------------------------


@dataclass
class Resumption:
    """What ``prepare_resume`` found in an interrupted session folder."""

    folder: Path
    seed: int
    checkpoint: dict[str, Any]
    rows: list[dict[str, Any]]  # completed rows already on disk, typed like the session's own
    missing_row: dict[str, Any] | None  # the checkpoint's row when a kill came between the two writes

    def recover_row(self, recorder: SessionRecorder) -> None:
        if self.missing_row is not None:
            recorder.turn(self.missing_row)
            recorder.event("row_recovered", turn=self.missing_row["turn"], source=CHECKPOINT)
            self.rows.append(self.missing_row)


def prepare_resume(folder: Path) -> tuple[StudyConfig, Resumption]:
    """The configuration and state to continue ``folder``; ``DataError`` in one line when it cannot be resumed."""
    folder = Path(folder).resolve()
    fix = "start a new session instead"
    if not (folder / "session.json").is_file():
        raise DataError(f"{folder}: not a session folder (no session.json); give the folder a session wrote")
    info = read_json(folder / "session.json", DataError)
    status = info.get("status")
    if status in FINISHED:
        raise DataError(f"{folder}: the session is complete (status {status!r}); nothing to resume, {fix}")
    if info.get("nao_trainer") != __version__:
        raise DataError(f"{folder}: written by nao-trainer {info.get('nao_trainer')}, this is {__version__}; "
                        f"resume it with that version or {fix}")
    checkpoint = read_json(folder / CHECKPOINT, DataError,
                           "no completed turn to resume from (no checkpoint)", fix)
    if checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise DataError(f"{folder / CHECKPOINT}: unknown format {checkpoint.get('format')!r}; {fix}")
    snap = info.get("config") or {}
    sources = snap.get("sources") or []
    if not sources:
        raise DataError(f"{folder}/session.json: no configuration snapshot; {fix}")
    config = load_config(sources[-1], snap.get("overrides") or {}, default=sources[0])
    if config.text_sha256 != snap.get("sha256") or config.values != snap.get("values"):
        changed = ", ".join(sources)
        raise DataError(f"{folder}: the configuration changed since the session started (hash of {changed} "
                        f"and the session's flags differs from session.json); restore those files or {fix}")
    if int(checkpoint["completed"]) >= config.session.turns:
        raise DataError(f"{folder}: all {config.session.turns} turns are recorded; nothing to resume, {fix}")
    rows = [_typed_row(r) for r in read_turns(folder) if r["success"] in ("True", "False")]
    last = max((int(r["turn"]) for r in rows), default=0)
    missing = checkpoint["row"] if last < int(checkpoint["completed"]) else None
    return config, Resumption(folder, int(info["seed"]), checkpoint, rows, missing)


def _typed_row(row: dict[str, str]) -> dict[str, Any]:
    """A turns.csv row read back with the types the session's own rows have (for its summary)."""
    def num(v: str, kind: type) -> Any:
        return None if v in ("", None) else kind(v)

    out: dict[str, Any] = dict(row)
    out.update(turn=int(row["turn"]), level=int(row["level"]), feedback=int(row["feedback"]),
               success=row["success"] == "True", score=num(row["score"], int), engagement=num(row["engagement"], float))
    return out


def _desktop_robot(input_kind: str, speed: float, progress: TextIO | None) -> Robot:
    """The laptop as the robot (``--robot desktop``); refuses head-button answers it cannot give."""
    from nao_trainer.robot.desktop import DesktopRobot

    if input_kind == "tactile":
        raise ConfigError("--robot desktop has no head buttons: answer with --input keyboard (or simulated)")
    robot = DesktopRobot.start(speed)
    if progress:
        where = "the sound device" if robot.player else "WAV files in the session folder's audio/ (no sound device)"
        print(f"the laptop plays the robot: speech through espeak-ng, sound to {where}", file=progress, flush=True)
    return robot


def _make_answers(config: StudyConfig, robot: Robot, standin: Any, url: str, simulator: UserSimulator | None,
                  monitor: EngagementMonitor, rng: np.random.Generator,
                  progress: TextIO | None = None) -> tuple[AnswerSource, Any]:
    from nao_trainer.answers.inputs import KeyboardAnswers, TactileAnswers
    from nao_trainer.answers.simulated import SimulatedParticipant, StandInButtons

    speed = config.timing.speed
    debounce, grace = config.answers.debounce_s / speed, config.timing.grace_s / speed
    kind = config.answers.input
    if kind == "tactile":
        return TactileAnswers(robot, debounce, grace), None
    if kind == "keyboard":  # key events do not bounce (the keyboard's firmware debounces)
        return KeyboardAnswers(None, 0.0, grace, echo=progress), None
    assert simulator is not None
    buttons = None
    press = standin.press if standin is not None else None
    if press is None and url != DESKTOP:
        buttons = StandInButtons.probe(url)
        press = buttons
    if press is None:  # a real robot: hand the answers over directly
        return SimulatedParticipant(simulator, rng, speed, monitor), None
    inner = TactileAnswers(robot, debounce, grace)
    return SimulatedParticipant(simulator, rng, speed, monitor, press=press, inner=inner,
                                min_gap_s=max(0.3, 4 * config.answers.debounce_s)), buttons


def _close_quietly(obj: Any, recorder: SessionRecorder | None) -> None:
    if obj is None or not hasattr(obj, "close"):
        return
    try:
        obj.close()
    except Exception as exc:  # noqa: BLE001 - one failing close must not skip the others
        print(f"nao-trainer: warning: closing {type(obj).__name__} failed: {exc}", file=sys.stderr)
        if recorder is not None and recorder.is_open:
            recorder.event("close_failed", what=type(obj).__name__, error=str(exc))


def _write_transcript(path: Path | None, transcript: list[dict[str, Any]], append: bool = False) -> None:
    if path is None:
        return
    target = path / "robot_transcript.jsonl"
    before = target.read_text(encoding="utf-8") if append and target.exists() else ""
    write_text_atomic(target, before + "".join(json.dumps(entry, default=str) + "\n" for entry in transcript))
