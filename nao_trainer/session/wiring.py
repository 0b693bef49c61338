"""Wiring: builds the robot, answers, EEG monitor and policy a study asks for, and plays a session.

The only module of the session that knows the concrete adapters (``robot.naoqi``, the stand-in,
``answers``, ``eeg.monitor``, the policies); the engine sees them through ``ports`` only.
"""
from __future__ import annotations

import dataclasses
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
from nao_trainer.errors import ConfigError, Interrupted, RobotUnavailable, UserError
from nao_trainer.files import write_text_atomic
from nao_trainer.ports import AnswerSource, EngagementMonitor, NullMonitor, Policy, Robot, RobotConnectionLost
from nao_trainer.session.behaviors import Behaviors, load_behaviors
from nao_trainer.session.config import StudyConfig
from nao_trainer.session.dialogue import Dialogue, load_dialogue
from nao_trainer.session.engine import EXIT_INTERRUPTED, EXIT_ROBOT_LOST, Session, who_stopped
from nao_trainer.session.record import SessionRecorder, ensure_output_dir, versions
from nao_trainer.session.stage import leave_robot_safe
from nao_trainer.session.turn import SessionResult

@dataclass(frozen=True)
class RunOptions:
    """Things chosen on the command line that are not study configuration."""

    quiet: bool = False


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
        return load_simulator(spec)
    pm = config.participant_model
    return UserSimulator.from_level_rates("config-levels", list(pm.success_by_level), list(pm.engagement_by_level))


def open_engagement_monitor(config: StudyConfig, session_dir: Path, rng: np.random.Generator) -> EngagementMonitor:
    """The EEG monitor of the study's ``eeg.mode`` ("off" -> ports.NullMonitor)."""
    eeg = config.eeg
    if eeg.mode == "off":
        return NullMonitor()  # without importing pylsl
    from nao_trainer.eeg.monitor import open_monitor  # sets LSL's scope before its first stream object

    return open_monitor(eeg.mode, dataclasses.asdict(eeg), session_dir, rng, config.participant.pseudonym)


def run_session(config: StudyConfig, options: RunOptions = RunOptions(), progress: TextIO | None = None) -> SessionResult:
    """Connect, play and record one session as the study says; returns its result.

    Raises ``UserError`` subclasses before anything is written (invalid files, robot unreachable:
    ``RobotUnavailable``, exit code 3). Ctrl-C ends with status "interrupted" and exit code 130
    after leaving the robot safe and closing the files.
    """
    progress = None if options.quiet else (progress or sys.stderr)
    language = config.session.language
    dialogue = load_dialogue(config.session.dialogue_path)
    if dialogue.language != language:
        raise ConfigError(f"{dialogue.source}: dialogue language {dialogue.language!r} differs from session.language "
                          f"{language!r}; point session.dialogue at a {language} file")
    behaviors = load_behaviors(config.session.behaviors_path)
    seed = config.session.seed
    seed = int(seed) if seed is not None else secrets.randbelow(2**31)
    simulator = build_simulator(config) if config.answers.input == "simulated" else None
    from nao_trainer.session.policies import make_policy

    # Loaded once, before the robot moves: a missing or stale policy, or a torn/foreign learning-state
    # file, is found here. Without policy.state_path a learning policy saves into the session folder,
    # which gets its path once the folder exists (_run_wired).
    policy = make_policy(config.policy.kind, list(config.policy.schedule), config.policy.learning,
                         config.policy.state_file, config)
    # Not closed on failure here: closing a learning policy saves it, and nothing is written before the robot answers.
    ensure_output_dir(config.output_dir())  # an unusable output folder is found before the robot moves

    with _signals_as_interrupt():
        return _run_wired(config, progress, dialogue, behaviors, seed, simulator, policy)


def _run_wired(config: StudyConfig, progress: TextIO | None, dialogue: Dialogue,
               behaviors: Behaviors, seed: int, simulator: UserSimulator | None, policy: Policy) -> SessionResult:
    """``run_session`` once the files and the policy are loaded: connect, wire the ports, play, clean up."""
    from nao_trainer.robot.naoqi import NaoqiRobot, redact_url

    session_ss, policy_ss, participant_ss, eeg_ss = np.random.SeedSequence(seed).spawn(4)
    input_kind = config.answers.input
    speed = config.timing.speed
    url = config.robot.url
    standin = robot = recorder = monitor = answers = buttons = None
    policy_to_close: Policy | None = None  # closed (and a learning policy saved) only once the folder exists
    session: Session | None = None
    status, code, error, summary = "error", 1, "", ""
    try:
        if url == "mock":
            from nao_trainer.robot.standin import StandIn

            standin = StandIn.start("tcp://127.0.0.1:0", speed=speed)
            connect_url = standin.url
        else:
            connect_url = url
        if progress:
            print(f"connecting to the robot at {'the stand-in ' + connect_url if standin else redact_url(connect_url)} ...",
                  file=progress, flush=True)
        robot = NaoqiRobot.connect(connect_url, config.robot.connect_deadline_s, None,
                                   debounce_s=config.answers.debounce_s / speed)
        # Only now that the robot answered does anything get written.
        recorder = SessionRecorder(config.output_dir(), config.participant.pseudonym)
        path = recorder.open({
            "nao_trainer": __version__, "versions": versions(), "seed": seed,
            "robot": "stand-in (in-process)" if standin else redact_url(url),
            "input": input_kind, "policy": config.policy.kind,
            "user_model": simulator.name if simulator else None,
            "config": config.snapshot(), "argv": sys.argv[1:],
        })
        if progress:
            print(f"session folder: {path}", file=progress, flush=True)
        monitor = open_engagement_monitor(config, path, np.random.default_rng(eeg_ss))
        answers, buttons = _make_answers(config, robot, standin, connect_url, simulator, monitor,
                                         np.random.default_rng(participant_ss))
        policy_rng = np.random.default_rng(policy_ss)
        policy.bind_state_dir(path)
        policy_to_close = policy
        session = Session(config, robot, answers, policy, recorder, dialogue, behaviors, np.random.default_rng(session_ss),
                          policy_rng, monitor, progress)
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
                    _write_transcript(recorder.path, standin.transcript())
                if summary:
                    recorder.event("policy_summary", summary=summary)
                recorder.close(status, code, total_score=session.total if session else 0, error=error,
                               policy_summary=summary or None)
            if standin is not None:
                standin.stop()
    return SessionResult(recorder.path if recorder else None, status, code, session.rows if session else [], seed, error,
                         summary)


def _make_answers(config: StudyConfig, robot: Robot, standin: Any, url: str, simulator: UserSimulator | None,
                  monitor: EngagementMonitor, rng: np.random.Generator) -> tuple[AnswerSource, Any]:
    from nao_trainer.answers.inputs import KeyboardAnswers, TactileAnswers
    from nao_trainer.answers.simulated import SimulatedParticipant, StandInButtons

    speed = config.timing.speed
    debounce, grace = config.answers.debounce_s / speed, config.timing.grace_s / speed
    kind = config.answers.input
    if kind == "tactile":
        return TactileAnswers(robot, debounce, grace), None
    if kind == "keyboard":  # key events do not bounce (the keyboard's firmware debounces)
        return KeyboardAnswers(None, 0.0, grace), None
    assert simulator is not None
    buttons = None
    press = standin.press if standin is not None else None
    if press is None:
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


def _write_transcript(path: Path | None, transcript: list[dict[str, Any]]) -> None:
    if path is None:
        return
    write_text_atomic(path / "robot_transcript.jsonl", "".join(json.dumps(entry, default=str) + "\n" for entry in transcript))
