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
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, TextIO

import numpy as np

from nao_trainer import __version__
from nao_trainer.core.psychometric import SPAN_RATE, span_rate
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.answers.inputs import KeyboardAnswers, TactileAnswers
from nao_trainer.answers.simulated import SimulatedParticipant, StandInButtons
from nao_trainer.console.keys import KeyReader
from nao_trainer import registry
from nao_trainer.eeg.factory import open_monitor  # pylsl-free: it sets LSL's scope before loading pylsl
from nao_trainer.errors import ConfigError, EEGUnavailable, Interrupted, RobotUnavailable, UserError
from nao_trainer.files import PROJECT_ROOT, write_text_atomic
from nao_trainer.learn.artifacts import load_simulator
from nao_trainer.policies.factory import make_policy
from nao_trainer.ports import (AnswerSource, CommandQueue, EngagementMonitor, NullHealth, NullMonitor, NullObserver,
                               NullUpkeep, Policy, Robot, RobotConnectionLost, RobotHealthWatch, RobotUpkeep,
                               SessionObserver)
from nao_trainer.robot.address import redact_url
from nao_trainer.tasks.base import Task, table_fields
from nao_trainer.session.behaviors import Behaviors, load_behaviors
from nao_trainer.session.check import check_disk, check_eeg, check_robot, plan_from_config
from nao_trainer.session.config import DESKTOP, MOCK, StudyConfig, is_robot_address
from nao_trainer.session.dialogue import Dialogue, load_dialogue
from nao_trainer.session.participant import check_pseudonym, session_lock
from nao_trainer.session.engine import EXIT_RECORD_INCOMPLETE, EXIT_INTERRUPTED, EXIT_ROBOT_LOST, Session
from nao_trainer.session.operator import who_stopped
from nao_trainer.session.parts import Randomness, Script, SessionPorts
from nao_trainer.session.record import SessionRecorder, ensure_output_dir, os_error_in, versions, write_failure
from nao_trainer.session.resume import Resumption
from nao_trainer.session.robot_setup import RobotSetup, connect_robot
from nao_trainer.session.stage import leave_robot_safe
from nao_trainer.session.turn import SessionResult, summary_data
from nao_trainer.robot.health import HealthWatch

LOOPBACK = ("127.0.0.1", "localhost", "::1")


@dataclass(frozen=True)
class RunOptions:
    """Things chosen on the command line that are not study configuration.

    ``keys``: read operator keys from the terminal (only when stdin is a terminal and answers do
    not come from the keyboard). ``console``: serve the supervisor console (also ``console.enabled``);
    ``console_bind`` given here is the explicit choice a non-loopback address needs. ``commands`` and
    ``observer`` let a program steer and watch the session (the keys and the console use the same queue).
    A console beyond loopback is served over TLS (a self-signed certificate made at start) unless
    ``console_insecure``; ``console_tls`` asks for TLS on loopback too.
    """

    quiet: bool = False
    keys: bool = False
    console: bool = False
    console_port: int | None = None
    console_bind: str | None = None
    console_insecure: bool = False
    console_tls: bool = False
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


def dialogue_for(config: StudyConfig) -> Path:
    """The study's dialogue file; the task's own (``Task.dialogue_file``) when the study keeps the shipped default
    (the sequence task's words would tell an n-back participant the wrong rules)."""
    own = getattr(registry.load("task", config.task.name), "dialogue_file", None)
    shipped = (PROJECT_ROOT / "dialogue" / "en.yaml").resolve()
    if own is not None and Path(config.session.dialogue_path).resolve() == shipped:
        return Path(own)
    return Path(config.session.dialogue_path)


def build_simulator(config: StudyConfig) -> UserSimulator:
    """The simulated participant's model: a fitted one (``participant_model.user_model``, ``--user-model``)
    or the config's level rates."""
    spec = config.participant_model.user_model
    if spec:
        shipped = PROJECT_ROOT / spec
        if spec.endswith(".json") and not Path(spec).is_absolute() and not Path(spec).exists() and shipped.exists():
            spec = str(shipped)  # a file shipped with the project (e.g. the demo's sim/participants/level4.json)
        return load_simulator(spec)
    pm = config.participant_model
    own = getattr(config.task.build_task(), "level_success", None)  # a task with its own simulated observer
    if own is not None:
        return UserSimulator.from_level_rates(f"{config.task.name}-observer", list(own()), list(pm.engagement_by_level))
    return UserSimulator.from_level_rates("config-levels", list(pm.success_by_level), list(pm.engagement_by_level))


def open_engagement_monitor(config: StudyConfig, session_dir: Path, rng: np.random.Generator,
                            simulator: UserSimulator | None = None) -> EngagementMonitor:
    """The EEG monitor of the study's ``eeg.mode`` ("off" -> ports.NullMonitor).

    A simulated Muse starts at the simulated participant's resting engagement (``simulator``), so the
    baseline phase shows what the participant model implies at rest."""
    eeg = config.eeg
    if eeg.mode == "off":
        return NullMonitor()  # without importing pylsl
    rest = {} if simulator is None else {"rest_target": simulator.rest_engagement()}
    return open_monitor(eeg.mode, eeg, session_dir, rng, config.participant.pseudonym,
                        record_xdf=True,  # session.xdf beside the session's files (eeg.xdf: false turns it off)
                        # a person answering or a real robot never takes a simulated stream for theirs
                        person=config.answers.input != "simulated" or is_robot_address(config.robot.url), **rest)


def run_session(config: StudyConfig, options: RunOptions = RunOptions(), progress: TextIO | None = None,
                resume: Resumption | None = None) -> SessionResult:
    """Connect, play and record one session as the study says; returns its result.

    Raises ``UserError`` subclasses before anything is written (invalid files, robot unreachable:
    ``RobotUnavailable``, exit code 3). Ctrl-C ends with status "interrupted" and exit code 130
    after leaving the robot safe and closing the files. ``resume`` (from ``prepare_resume``)
    continues an interrupted session folder instead of creating one.
    """
    progress = None if options.quiet else (progress or sys.stderr)
    check_pseudonym(config)  # refused in one line when a person answers and nobody entered a pseudonym
    language = config.session.language
    dialogue = load_dialogue(dialogue_for(config))
    if dialogue.language != language:
        raise ConfigError(f"{dialogue.source}: dialogue language {dialogue.language!r} differs from session.language "
                          f"{language!r}; point session.dialogue at a {language} file")
    behaviors = load_behaviors(config.session.behaviors_path)
    check_postures(config, behaviors)
    try:  # a plug-in's console fields must be among its columns: said before the robot connects or a file is written
        table_fields(config.task.build_task())
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    seed = config.session.seed if resume is None else resume.seed
    seed = int(seed) if seed is not None else secrets.randbelow(2**31)
    simulator = build_simulator(config) if config.answers.input == "simulated" else None
    console_bind = _console_bind(config, options)
    with session_lock(config, progress):  # one session at a time per participant state
        # Loaded once, before the robot moves: a missing or stale policy, or a torn/foreign learning-state
        # file, is found here. Per participant by default (policy.state_path); "{session}" = the session folder,
        # bound once the folder exists (_run_wired).
        policy = make_policy(config.policy, config.participant.pseudonym, config.output_dir(),
                             turns=config.session.turns, fresh=options.fresh_policy, task=config.task.build_task())
        if resume is not None:
            resume.check_policy(policy)  # a tampered learning state is refused before anything is written
        # Not closed on failure here: closing a learning policy saves it, and nothing is written before the robot answers.
        ensure_output_dir(config.output_dir())  # an unusable output folder is found before the robot moves
        preflight(config, progress)  # robot, disk and a required EEG stream, before any session folder exists
        with _signals_as_interrupt():
            return _run_wired(config, progress, dialogue, behaviors, seed, simulator, policy, options, resume,
                              console_bind)


def check_postures(config: StudyConfig, behaviors: Behaviors) -> None:
    """The behaviors file's postures exist on the study's robot model (one line naming the file and the fix)."""
    if config.robot.url == DESKTOP:
        return
    model = config.robot.robot_model()
    for which, posture in (("start", behaviors.start_posture), ("end", behaviors.end_posture),
                           ("safe", behaviors.safe_posture)):
        problem = model.check_posture(which, posture)
        if problem:
            raise ConfigError(f"{config.session.behaviors_path}: {problem} (or point session.behaviors at a "
                              f"file for {model.title})")


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
    plan = plan_from_config(config)
    checks = [lambda: check_disk(plan.output_dir, write_dirs=plan.write_dirs), lambda: check_robot(plan)]
    if config.eeg.mode == "lsl" and config.eeg.required:
        checks.append(lambda: check_eeg(plan, config.eeg.processing.window_s + 0.5))
    errors = {"robot": RobotUnavailable, "eeg": EEGUnavailable, "disk": UserError}
    for check in checks:
        result = check()
        if result.exit_code:
            raise errors[result.kind](f"{result.detail}; {result.fix}" if result.fix else result.detail)
        if progress:
            print(f"check: {result.line()}", file=progress, flush=True)


@dataclass
class _Outcome:
    """How a wired session ended, filled in as it goes (the closers read it)."""

    seed: int
    status: str = "error"
    code: int = 1
    error: str = ""
    summary: str = ""  # what the policy concluded
    session: Session | None = None
    monitor: Any = None  # the EEG monitor, for the stream's identity in session.json
    span_rate: float = SPAN_RATE  # the study's target rate, else 75 % (core.psychometric.span_rate)
    task: Any = None  # the task played

    def result(self, recorder: SessionRecorder) -> SessionResult:
        session = self.session
        return SessionResult(recorder.path, self.status, self.code, session.rows if session else [], self.seed,
                             self.error, policy_summary=self.summary, span_rate=self.span_rate, task=self.task)


def _run_wired(config: StudyConfig, progress: TextIO | None, dialogue: Dialogue, behaviors: Behaviors, seed: int,
               simulator: UserSimulator | None, policy: Policy, options: RunOptions, resume: Resumption | None,
               console_bind: str | None) -> SessionResult:
    """``run_session`` once the files and the policy are loaded: connect, wire the ports, play, clean up.

    Every adapter is built inside one ``ExitStack``: it is closed in the reverse order of building,
    whatever happens (the record is closed last but the stand-in, so every close is logged in it)."""
    out = _Outcome(seed, span_rate=span_rate(config.policy.objective))
    task = config.task.build_task()
    out.task = task
    recorder = SessionRecorder(config.output_dir(), config.participant.pseudonym, columns=task.columns)
    stack = ExitStack()
    try:
        _play(stack, out, recorder, config, progress, dialogue, behaviors, simulator, policy, options, resume,
              console_bind, task)
    except (KeyboardInterrupt, Interrupted):
        out.status, out.code = "interrupted", EXIT_INTERRUPTED
    except RobotConnectionLost as exc:  # dropped while setting up (buttons): nothing was played yet
        out.status, out.code, out.error = "robot lost", EXIT_ROBOT_LOST, str(exc)
        raise RobotUnavailable(f"lost the robot while starting the session: {exc}") from None
    except Exception as exc:
        failed = os_error_in(exc)  # a write failed (full disk, read-only, too many open files), maybe wrapped
        if failed is not None:
            error = write_failure(failed, recorder.path)
            out.status, out.code, out.error = "error", error.exit_code, str(error)
            raise error from None
        if isinstance(exc, UserError):  # e.g. a required EEG stream missing: recorded, then reported by the CLI
            out.status, out.code, out.error = "error", exc.exit_code, str(exc)
        else:
            out.error = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        with _no_interrupts():  # shutdown must finish
            stack.close()
    return out.result(recorder)


def _play(stack: ExitStack, out: _Outcome, recorder: SessionRecorder, config: StudyConfig, progress: TextIO | None,
          dialogue: Dialogue, behaviors: Behaviors, simulator: UserSimulator | None, policy: Policy,
          options: RunOptions, resume: Resumption | None, console_bind: str | None, task: Task) -> None:
    """Build the adapters in order, each one's closer pushed on ``stack`` as soon as it exists; play."""
    session_ss, policy_ss, participant_ss, eeg_ss = np.random.SeedSequence(out.seed).spawn(4)
    standin = _start_standin(stack, config)
    stack.callback(_close_record, recorder, out, policy, standin, resume is not None)
    connect_url = standin.url if standin else config.robot.url
    robot = connect_robot(config, connect_url, standin is not None, progress)
    stack.callback(_close_quietly, robot, recorder, out)
    setup = RobotSetup(recorder)
    upkeep: RobotUpkeep = NullUpkeep()
    health: RobotHealthWatch = NullHealth()
    if config.robot.url != DESKTOP:  # Autonomous Life and motors as the study says; kept; restored at the end
        upkeep = setup.prepare(robot, config.robot, config.session.language,
                               config.answers.input in ("tactile", "simulated"), progress)
        stack.callback(upkeep.leave)
        health = _watch_health(robot, config)
        stack.callback(_close_quietly, health, recorder, out)
    stack.callback(_leave_robot_safe, out, robot, behaviors, config, recorder)
    commands = options.commands if options.commands is not None else CommandQueue()  # an empty queue is falsy
    # The console's port is taken before the folder exists: a port in use leaves no empty session folder.
    observer = _start_console(stack, out, recorder, config, options, commands, console_bind, progress) \
        if console_bind is not None else options.observer
    # Only now that the robot answered (and the console listens) does anything get written.
    path = _open_record(recorder, config, out.seed, robot, standin is not None, simulator, resume, progress, setup)
    if config.robot.url == DESKTOP:
        robot.record_audio_to(path / "audio")
    policy_state = _policy_state(policy, config, options.fresh_policy, progress)
    monitor = open_engagement_monitor(config, path, np.random.default_rng(eeg_ss), simulator)
    stack.callback(_close_quietly, monitor, recorder, out)
    out.monitor = monitor
    if config.eeg.mode != "off" and progress:  # which headband this session listens to (events.jsonl too)
        print(f"EEG ({config.eeg.mode}): {monitor.describe()}", file=progress, flush=True)
    participant_rng = np.random.default_rng(participant_ss)
    answers, buttons = _make_answers(config, robot, standin, connect_url, simulator, monitor, participant_rng, progress,
                                     task)
    stack.callback(_close_quietly, buttons, recorder, out)
    stack.callback(_close_quietly, answers, recorder, out)
    policy.bind_state_dir(path)
    stack.callback(_close_policy, policy, out, recorder)  # closed (a learning policy saved) once the folder exists
    ports = SessionPorts(robot, answers, policy, monitor, commands, observer or NullObserver(), upkeep, health, task)
    session = Session(config, ports, recorder, Script(dialogue, behaviors),
                      Randomness(np.random.default_rng(session_ss), np.random.default_rng(policy_ss),
                                 {"participant": participant_rng}),
                      progress=progress, resume=None if resume is None else dict(resume.checkpoint, rows_before=resume.rows),
                      policy_state=policy_state)
    out.session = session
    stack.callback(_leave_session_safe, out)
    if options.keys and config.answers.input != "keyboard":
        keys = KeyReader.start_if_terminal(commands, progress)
        stack.callback(_close_quietly, keys, recorder, out)  # the terminal is restored first, whatever happens next
    if isinstance(observer, _ConsoleObserver):
        observer.console.hub.set_sources(eeg=monitor.live, elapsed=session.wall_elapsed_s)
    try:
        out.code = session.run()
    except (KeyboardInterrupt, Interrupted) as exc:
        session.interrupted_by_operator(who_stopped(exc))
        out.code = EXIT_INTERRUPTED
    out.status, out.error = session.status, session.error
    _report_lost_events(out, recorder)


def _report_lost_events(out: "_Outcome", recorder: SessionRecorder) -> None:
    """A session whose events.jsonl could not be written says so: in its error (the summary's status line
    and session.json) and, when it otherwise completed, with exit code ``EXIT_RECORD_INCOMPLETE``. Its status
    stays what the session did (every turn is in turns.csv: a study counts it)."""
    lost = recorder.events_lost()
    if not lost:
        return
    out.error = f"{out.error}; {lost}" if out.error else lost
    if out.code == 0:
        out.code = EXIT_RECORD_INCOMPLETE


def _watch_health(robot: Robot, config: StudyConfig) -> RobotHealthWatch:
    """Falls, heat, the diagnosis, a low battery and the chest button, as the robot model declares them."""
    return HealthWatch.start(robot, config.robot.robot_model())


def _start_standin(stack: ExitStack, config: StudyConfig) -> Any:
    """The in-process stand-in of ``--robot mock`` (None otherwise); stopped last of all."""
    if config.robot.url != MOCK:
        return None
    from nao_trainer.robot.standin import StandIn  # heavy: qi

    standin = StandIn.start("tcp://127.0.0.1:0", speed=config.timing.speed, model=_standin_model(config))
    stack.callback(standin.stop)
    return standin


def _standin_model(config: StudyConfig) -> str:
    """The robot the in-process stand-in plays: the study's model when the stand-in can play it, else a NAO."""
    from nao_trainer.robot.standin.services import played  # heavy: qi

    return played(config.robot.model)


def _open_record(recorder: SessionRecorder, config: StudyConfig, seed: int, robot: Robot, standin: bool,
                 simulator: UserSimulator | None, resume: Resumption | None, progress: TextIO | None,
                 setup: RobotSetup) -> Path:
    """Create the session folder (or reopen the resumed one); returns its path."""
    url = config.robot.url
    if resume is None:
        if standin:
            shown = "stand-in (in-process)"
        elif url == DESKTOP:
            shown = repr(robot)
        else:
            shown = redact_url(url)
        path = recorder.open({
            "nao_trainer": __version__, "versions": versions(), "seed": seed, "robot": shown,
            "robot_status": setup.status,  # name, NAOqi version, volume, battery, Autonomous Life found
            "robot_setup": setup.early,  # what was done to the robot before session_start
            "input": config.answers.input, "policy": config.policy.kind,
            "user_model": simulator.name if simulator else None,
            "config": config.snapshot(), "argv": sys.argv[1:],
        })
    else:
        path = recorder.reopen(resume.folder, {"after_turn": resume.checkpoint["completed"], "argv": sys.argv[1:]})
        resume.recover_row(recorder)
    if progress:
        print(f"session folder: {path}" + (f" (resumed after turn {resume.checkpoint['completed']})" if resume else ""),
              file=progress, flush=True)
    return path


@dataclass
class _ConsoleObserver:
    """The console's hub, and a program's own observer when there is one."""

    console: Any
    other: SessionObserver | None

    def notify(self, kind: str, data: dict) -> None:
        self.console.hub.notify(kind, data)
        if self.other is not None:
            self.other.notify(kind, data)


def _start_console(stack: ExitStack, out: _Outcome, recorder: SessionRecorder, config: StudyConfig,
                   options: RunOptions, commands: CommandQueue, bind: str, progress: TextIO | None) -> _ConsoleObserver:
    """Serve the supervisor console; at the end it shows the summary, then stops."""
    try:
        from nao_trainer.console.launch import open_console
    except ImportError as exc:
        raise ConfigError(f"--console needs the console extra ({exc}); install it with "
                          "pip install -e '.[console]'") from None
    port = options.console_port if options.console_port is not None else config.console.port
    console = open_console(commands, bind, port, recorder.event, progress, options.console_insecure, options.console_tls)
    stack.callback(_stop_console, console, out, recorder)
    return _ConsoleObserver(console, options.observer)


# -- closers (each pushed on the stack by the step that built its resource) -----------------------


def _stop_console(console: Any, out: _Outcome, recorder: SessionRecorder) -> None:
    console.log_rejections()  # how many refused requests were not logged one by one (the record is still open)
    console.hub.notify("summary", summary_data(out.result(recorder)))
    console.stop()


def _leave_session_safe(out: _Outcome) -> None:
    if out.session is not None and out.status != "completed":
        out.session.leave_safe()


def _leave_robot_safe(out: _Outcome, robot: Robot, behaviors: Behaviors, config: StudyConfig,
                      recorder: SessionRecorder) -> None:
    """Safe posture when no session was built to do it (a failure while setting up)."""
    if out.session is None and out.status != "completed":
        leave_robot_safe(robot, behaviors, config.robot.posture_speed, recorder)


def _close_policy(policy: Policy, out: _Outcome, recorder: SessionRecorder) -> None:
    """Close the policy (a learning one saves its state), then read what it concluded."""
    _close_quietly(policy, recorder, out)
    if out.session is not None and out.session.completed:
        out.summary = str(policy.status().get("summary", ""))  # e.g. the user model the participant matched


def _close_record(recorder: SessionRecorder, out: _Outcome, policy: Policy, standin: Any, resumed: bool) -> None:
    """The final session.json (status, exit code, why), after every other close was logged."""
    if not recorder.is_open:
        return
    if standin is not None:
        try:
            _write_transcript(recorder.path, standin.transcript(), append=resumed)
        except OSError as exc:  # the session's own failure (if any) is what gets reported
            recorder.event("close_failed", what="robot_transcript.jsonl", error=str(exc))
    if out.summary:
        recorder.event("policy_summary", summary=out.summary)
    xdf = getattr(out.monitor, "xdf_problem", "")  # session.xdf cut short (known once the monitor closed)
    if xdf:
        out.error = f"{out.error}; {xdf}" if out.error else xdf
        if out.code == 0:
            out.code = EXIT_RECORD_INCOMPLETE
    result = out.result(recorder)
    recorder.close(out.status, out.code, total_score=out.session.total if out.session else 0, error=out.error,
                   policy_summary=out.summary or None,
                   eeg_turns=result.eeg_turns if result.eeg_on else None,  # how many counted turns had EEG
                   span=result.span_record(),  # the span at the study's rate (docs/how-to/session.md), None without turns
                   eeg_stream=getattr(out.monitor, "stream_identity", None),  # which stream; simulated or not
                   eeg_gaps=_eeg_gaps(out.monitor))  # each dropout of the headband's stream, and the turns it hit


def _eeg_gaps(monitor: Any) -> list[dict[str, Any]] | None:
    """The monitor's gaps (``eeg.monitor.LslMonitor.gap_report``), None when EEG is off."""
    report = getattr(monitor, "gap_report", None)
    return report() if callable(report) else None


def _policy_state(policy: Policy, config: StudyConfig, fresh: bool, progress: TextIO | None) -> dict[str, Any] | None:
    """Which learning state the policy starts from (the session logs it as ``policy_state``), None when it does not learn."""
    report = getattr(policy, "state_report", None)  # a learned policy says where its learning state comes from
    if not (config.policy.learning and callable(report)):
        return None
    target = config.policy_state_file()
    out = report(target, fresh)
    if progress and target is not None:
        print(f"policy state: {target} ({'continued' if policy.loaded_from else 'new'})", file=progress, flush=True)
    return out


def _make_answers(config: StudyConfig, robot: Robot, standin: Any, url: str, simulator: UserSimulator | None,
                  monitor: EngagementMonitor, rng: np.random.Generator,
                  progress: TextIO | None = None, task: Task | None = None) -> tuple[AnswerSource, Any]:
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
        return SimulatedParticipant(simulator, rng, speed, monitor, task=task), None
    inner = TactileAnswers(robot, debounce, grace)
    return SimulatedParticipant(simulator, rng, speed, monitor, press=press, inner=inner,
                                min_gap_s=max(0.3, 4 * config.answers.debounce_s), task=task), buttons


def _close_quietly(obj: Any, recorder: SessionRecorder | None, out: "_Outcome | None" = None) -> None:
    """Close ``obj``; a failure is logged and (unless the session already failed, and says why) warned about."""
    if obj is None or not hasattr(obj, "close"):
        return
    try:
        obj.close()
    except Exception as exc:  # noqa: BLE001 - one failing close must not skip the others
        if out is None or out.status != "error":
            print(f"nao-trainer: warning: closing {type(obj).__name__} failed: {exc}", file=sys.stderr)
        if recorder is not None and recorder.is_open:
            recorder.event("close_failed", what=type(obj).__name__, error=str(exc))


def _write_transcript(path: Path | None, transcript: list[dict[str, Any]], append: bool = False) -> None:
    if path is None:
        return
    target = path / "robot_transcript.jsonl"
    before = target.read_text(encoding="utf-8") if append and target.exists() else ""
    write_text_atomic(target, before + "".join(json.dumps(entry, default=str) + "\n" for entry in transcript))
