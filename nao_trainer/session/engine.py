"""The session engine: one training session as a ``transitions`` state machine.

The states and transitions are data (``session.machine``); each state has a handler ``_do_<state>``
that works through the ports (robot via ``session.stage.Stage``, answers, EEG monitor, policy) and
returns the next trigger. Interruptions are uniform:

* a lost robot (``RobotConnectionLost``) -> ``paused``: the turn in flight is recorded as
  interrupted, the robot reconnected with exponential backoff and the turn replayed; after
  ``robot.max_reconnect_s`` the session ends (``aborted``, exit code 3);
* a refused call the task needs (``RobotCallFailed``: speech, beep) ends it as a robot error (exit 3);
* Ctrl-C or SIGTERM -> ``aborted``: the robot is silenced, exit code 130;
* operator commands (``session.operator``) act between states: pause, resume, stop (exit code 5);
  ``session.max_duration_s`` ends the session between turns (status "time limit", exit 0).

A turn (``core.mdp``): ``select_action`` (policy, new turn state and sequence), ``feedback`` (RF
actions), ``announce``, ``speak_sequence``, ``beep`` (the answer window opens), ``await_answer``,
``score`` (equation (1)), ``record`` (turns.csv, fsynced; the policy observes the transition).
The parts of ``Session`` in their own modules: ``session.operator`` (commands), ``session.checkpoint``
(``--resume``), ``session.phases`` (EEG phases, the answer window), ``session.reporting`` (rows, events,
progress). The engine imports no adapter: ``session.wiring`` builds them and hands them in.
"""
from __future__ import annotations

import sys
import time
from typing import Any, Callable, TextIO

import numpy as np
from transitions import Machine

from nao_trainer.core import mdp, task
from nao_trainer.errors import Interrupted, RobotUnavailable
from nao_trainer.ports import (AnswerSource, CommandQueue, EngagementMonitor, NullMonitor, NullObserver, Policy, Robot,
                               RobotCallFailed, RobotConnectionLost, SessionObserver, Transition, TurnContext)
from nao_trainer.session.behaviors import Behaviors
from nao_trainer.session.checkpoint import Checkpoints
from nao_trainer.session.config import StudyConfig
from nao_trainer.session.dialogue import Dialogue
from nao_trainer.session.machine import FINAL_STATES, INTRO_STATES, STATES, TRANSITIONS, TURN_STATES
from nao_trainer.session.operator import OperatorCommands
from nao_trainer.session.phases import EEGPhases
from nao_trainer.session.record import SessionRecorder, now_iso
from nao_trainer.session.reporting import Reporting
from nao_trainer.session.stage import Clock, Stage
from nao_trainer.session.turn import Turn, progress_line

EXIT_OK, EXIT_ROBOT_LOST, EXIT_INTERRUPTED = 0, RobotUnavailable.exit_code, Interrupted.exit_code
#: The operator stopped the session (a key or the console): goodbye and safe posture, then this code.
EXIT_OPERATOR_STOP = 5


class Session(OperatorCommands, Checkpoints, EEGPhases, Reporting):
    """One training session: owns the machine and talks to the world only through the ports.

    Build it connected (``wiring.run_session`` does that); ``run()`` plays it to the end and
    returns the exit code. Everything random comes from ``rng`` (sequences, dialogue variants) and
    the policy's own generator, so a seed replays a session exactly.
    """

    def __init__(self, config: StudyConfig, robot: Robot, answers: AnswerSource, policy: Policy,
                 recorder: SessionRecorder, dialogue: Dialogue, behaviors: Behaviors, rng: np.random.Generator,
                 policy_rng: np.random.Generator, monitor: EngagementMonitor | None = None,
                 progress: TextIO | None = sys.stderr, sleep: Callable[[float], None] = time.sleep,
                 commands: CommandQueue | None = None, observer: SessionObserver | None = None,
                 rngs: dict[str, np.random.Generator] | None = None, resume: dict[str, Any] | None = None,
                 policy_state: dict[str, Any] | None = None) -> None:
        self.cfg = config
        self.robot = robot
        self.answers = answers
        self.policy = policy
        self.rec = recorder
        self.behaviors = behaviors
        self.rng = rng
        self.policy_rng = policy_rng
        self.monitor = monitor or NullMonitor()
        self.progress = progress
        self.clock = Clock(config.timing.speed, sleep)
        self.stage = Stage(robot, dialogue, behaviors, rng, recorder, self.clock, config.timing,
                           config.robot.posture_speed)
        self.n_turns = config.session.turns
        self.mdp_state = mdp.START
        self.last_success: bool | None = None
        self.turn: Turn | None = None
        self.replay: Turn | None = None
        self.rows: list[dict[str, Any]] = []
        self.total = 0
        self.completed = 0
        self.lost_in: str | None = None
        self.status = "running"
        self.error = ""
        self._beep_onset = 0.0
        self.observer: SessionObserver = observer or NullObserver()
        self._init_commands(commands)
        # Generators a checkpoint must carry besides the session's and the policy's (the simulated participant's).
        self._init_checkpoints({"session": rng, "policy": policy_rng, **(rngs or {})}, resume)
        self._policy_state = policy_state  # which learning state the policy started from (events.jsonl)
        self._t0 = self.clock.now()
        self.max_duration_s = config.session.max_duration_s
        self.machine = Machine(model=self, states=STATES, transitions=TRANSITIONS, initial="greet",
                               auto_transitions=False, send_event=True, after_state_change="_log_transition")
        self.answers.watch(self._on_press)

    # -- driver ----------------------------------------------------------------------------------

    def run(self) -> int:
        """Play the session to ``done`` or ``aborted``; returns the exit code."""
        self._t0 = self.clock.now()
        self.rec.event("session_start", turns=self.n_turns, policy=self.policy.name, max_duration_s=self.max_duration_s,
                       eeg=self.monitor.describe())
        if self._policy_state:
            self.rec.event("policy_state", **self._policy_state)
        self.monitor.mark("session_start")
        self.observer.notify("session", {"turns": self.n_turns, "policy": self.policy.name, "speed": self.clock.speed,
                                         "max_duration_s": self.max_duration_s, "eeg": self.monitor.records_eeg,
                                         "robot": "connected", "completed": self.completed, "state": self.state})
        while self.state not in FINAL_STATES:
            try:
                if self._resume is not None:
                    trigger = self._resume_from_checkpoint()
                else:
                    trigger = self._between_states() or getattr(self, f"_do_{self.state}")()
            except RobotConnectionLost as exc:
                self.lost_in = self.state
                self.rec.event("robot_lost", state=self.state, error=str(exc),
                               turn=self.turn.number if self.turn else None)
                self.observer.notify("robot", {"robot": "lost", "error": str(exc)})
                self.trigger("robot_lost")
                continue
            except (KeyboardInterrupt, Interrupted) as exc:
                self.interrupted_by_operator(who_stopped(exc))
                break
            except RobotCallFailed as exc:  # the robot refused a call the task needs (speech, beep)
                self._robot_failed(exc)
                break
            self.trigger(trigger)
        return self._exit_code()

    def _exit_code(self) -> int:
        if self.state == "done":
            if self.status == "stopped":
                return EXIT_OPERATOR_STOP
            if self.status != "time limit":
                self.status = "completed"
            return EXIT_OK
        return EXIT_INTERRUPTED if self.status == "interrupted" else EXIT_ROBOT_LOST

    def interrupted_by_operator(self, by: str = "operator (Ctrl-C)") -> None:
        """Ctrl-C/SIGTERM: silence the robot, record the turn in flight, go to ``aborted``."""
        self.status = "interrupted"
        self.rec.event("interrupted", state=self.state, by=by)
        self.stage.silence()  # the robot may be mid-sentence: before the safe posture
        if self.turn is not None and not self.turn.recorded:
            self._abandon_turn(f"interrupted: {by}")
        if self.state not in FINAL_STATES:
            self.trigger("abort")

    def _robot_failed(self, exc: RobotCallFailed) -> None:
        self.status = "robot error"
        self.error = str(exc)
        self.rec.event("robot_call_failed", state=self.state, error=str(exc), fatal=True)
        if self.turn is not None and not self.turn.recorded:
            self._abandon_turn(f"interrupted: robot error ({exc})")
        if self.state not in FINAL_STATES:
            self.trigger("abort")

    def elapsed_s(self) -> float:
        """Session seconds since the session started (across a resumption; pauses count)."""
        return self._elapsed_before + self.clock.session(self.clock.now() - self._t0)

    # -- intro -----------------------------------------------------------------------------------

    def _do_greet(self) -> str:
        self._begin_phase("baseline", None)
        self.stage.posture(self.behaviors.start_posture)
        self.stage.say("greeting", pseudonym=self.cfg.participant.pseudonym)
        return "explain"

    def _do_instructions(self) -> str:
        if self._phase is None:
            self._begin_phase("baseline", None)
        self.stage.say("instructions", turns=self.n_turns)
        self._end_phase()
        return "practise" if self.cfg.session.practice else "begin_turns"

    def _do_practice(self) -> str:
        self.stage.say("practice_intro", behavior="practice")
        length = task.LENGTHS[0]
        context = TurnContext(0, mdp.encode(length, 0, 0), length, task.generate_sequence(self.rng, length))
        self.answers.prepare(context)
        self.stage.announce(1, length, look=False, turn=0)
        self.stage.letters(context.sequence, turn=0)
        answer = self._collect(0, length, self._beep(0))
        ok = not answer.timed_out and task.is_correct(context.sequence, answer.response)
        self.rec.event("practice", sequence="".join(context.sequence), response="".join(answer.response), success=ok)
        self.stage.say("practice_success" if ok else "practice_failure", behavior="practice")
        return "begin_turns"

    # -- a turn ----------------------------------------------------------------------------------

    def _next_turn(self) -> Turn:
        """The replayed turn after a loss, else the policy's choice in the current MDP state."""
        if self.replay is not None:
            turn, self.replay = self.replay, None
            return Turn(turn.number, turn.previous_state, turn.action, turn.state, notes=["replay of interrupted turn"],
                        replay=True, phase=turn.phase)
        notes: list[str] = []
        action = self._take_override()
        if action is not None:
            notes.append(f"operator chose {mdp.ACTION_NAMES[action]}")
            self.policy.guide(self.mdp_state, action)
        else:
            action = int(self.policy.act(self.mdp_state, self.policy_rng))
        phase = "override" if notes else str(self.policy.status().get("phase", ""))
        if not (0 <= action < mdp.N_ACTIONS and mdp.ACTION_MASK[self.mdp_state, action]):
            raise ValueError(f"policy {self.policy.name} chose action {action!r}, "
                             f"not allowed in state {mdp.state_label(self.mdp_state)}")
        if self.mdp_state == mdp.START:
            state = int(mdp.NEXT_STATE[mdp.START, action, 0])
        else:
            state = mdp.next_state(self.mdp_state, action, bool(self.last_success))
        return Turn(self.completed + 1, self.mdp_state, action, state, notes=notes, phase=phase)

    def _do_select_action(self) -> str:
        self.turn = turn = self._next_turn()
        st = turn.turn_state
        turn.sequence = task.generate_sequence(self.rng, st.length)
        turn.start_time = now_iso()
        self.answers.prepare(TurnContext(turn.number, turn.state, st.length, turn.sequence))
        plan = self.answers.intended()  # a simulated participant says what it intends
        if plan is not None:
            self.rec.event("simulated_plan", turn=turn.number, success=plan.success,
                           response="".join(plan.response), mistake=plan.mistake)
        self.rec.event("turn_start", turn=turn.number, state=turn.state, label=mdp.state_label(turn.state),
                       action=mdp.ACTION_NAMES[turn.action], sequence="".join(turn.sequence))
        self.monitor.mark("turn_start", turn.number)
        probs = self.policy.probabilities(turn.previous_state)
        self.observer.notify("turn_start", {
            "turn": turn.number, "level": st.level, "feedback": st.feedback, "length": st.length,
            "action": mdp.ACTION_NAMES[turn.action], "sequence": "".join(turn.sequence), "state": mdp.state_label(turn.state),
            "chosen_in": mdp.state_label(turn.previous_state), "notes": "; ".join(turn.notes),
            "probabilities": None if probs is None else dict(zip(mdp.ACTION_NAMES, (round(float(p), 4) for p in probs)))})
        self._begin_phase("listening", turn.number)
        return "give_feedback" if turn.action in (mdp.ENCOURAGE, mdp.CHALLENGE) else "announce_level"

    def _do_feedback(self) -> str:
        assert self.turn is not None
        st = self.turn.turn_state
        self.stage.feedback(st.feedback, bool(self.last_success), st.level, self.turn.number)
        return "announce_level"

    def _do_announce(self) -> str:
        assert self.turn is not None
        st = self.turn.turn_state
        self.stage.announce(st.level, st.length, turn=self.turn.number)
        return "speak"

    def _do_speak_sequence(self) -> str:
        assert self.turn is not None
        self.stage.letters(self.turn.sequence, turn=self.turn.number)
        return "sound_beep"

    def _do_beep(self) -> str:
        assert self.turn is not None
        self._beep_onset = self._beep(self.turn.number)
        return "wait_answer"

    def _do_await_answer(self) -> str:
        assert self.turn is not None
        self.turn.answer = self._collect(self.turn.number, len(self.turn.sequence), self._beep_onset)
        return "score_answer"

    def _do_score(self) -> str:
        turn = self.turn
        assert turn is not None and turn.answer is not None
        turn.answering = self._end_phase()
        turn.judge()
        return "record_turn"

    def _do_record(self) -> str:
        turn = self.turn
        assert turn is not None and turn.success is not None
        st = turn.turn_state
        score = task.score(st.level, turn.success)
        row = turn.row(score, task.signed_score(st.level, turn.success), self.clock.speed, self.monitor.records_eeg)
        self.completed += 1
        self.total += score
        done = self.completed >= self.n_turns
        engagement = turn.listening.engagement if turn.listening else None
        if turn.invalid:  # the operator marked it invalid: the learner does not see it
            self.rec.event("not_learned", turn=turn.number, reason="marked invalid")
        else:
            self.policy.observe(Transition(turn.previous_state, turn.action, score, engagement, turn.state, done))
        self.mdp_state, self.last_success = turn.state, turn.success
        # The checkpoint (with this row) first, then the row: a kill between the two loses nothing,
        # as a resumption appends the checkpoint's row when turns.csv lacks it.
        self._checkpoint(row)
        self._write_row(turn, row)
        self.rec.event("turn_end", turn=turn.number, success=turn.success, score=score, total=self.total)
        self.monitor.mark("turn_end", turn.number)
        self.observer.notify("row", {**row, "total": self.total, "elapsed_s": round(self.elapsed_s(), 2)})
        self._say_progress(progress_line(row, self.n_turns, self.total))
        status = self.policy.status()  # e.g. the posterior over user models after this turn
        if status:
            shown = {k: v for k, v in status.items() if k not in ("progress", "summary", "phase")}
            self.rec.event("policy_status", turn=turn.number, **shown)
            self.observer.notify("policy", {"turn": turn.number, **shown})
            if status.get("progress"):
                self._say_progress(status["progress"])
        return "finish_turns" if done else "next_turn"

    # -- goodbye ---------------------------------------------------------------------------------

    def _do_goodbye(self) -> str:
        self.stage.goodbye(self.total, self.completed)
        self.monitor.mark("session_end")
        return "end"

    # -- robot lost --------------------------------------------------------------------------------

    def _do_paused(self) -> str:
        lost_in = self.lost_in or "select_action"
        self._end_phase()
        if self.turn is not None and not self.turn.recorded and lost_in in TURN_STATES:
            self._abandon_turn(f"interrupted: robot lost during {lost_in}")
            self.replay = self.turn
        self._say_progress(f"robot lost during {lost_in}: paused, reconnecting...")
        if not self._reconnect():
            self.status = "robot lost"
            self.rec.event("give_up", after_s=self.cfg.robot.max_reconnect_s)
            self._say_progress(f"robot not back within {self.cfg.robot.max_reconnect_s:g} s: ending the session")
            return "give_up"
        if lost_in in INTRO_STATES:
            return "resume_intro"
        if lost_in == "goodbye":
            return "resume_goodbye"
        return "resume_turn"

    def _reconnect(self) -> bool:
        """Reconnect with exponential backoff (wall seconds) until ``robot.max_reconnect_s``."""
        r = self.cfg.robot
        deadline = self.clock.now() + r.max_reconnect_s
        backoff, attempt = r.backoff_initial_s, 0
        while (remaining := deadline - self.clock.now()) > 0:
            self.clock.sleep(min(backoff, remaining))
            attempt += 1
            try:
                self.robot.reconnect(max(0.5, min(r.connect_deadline_s, deadline - self.clock.now())))
                self.rec.event("reconnected", attempt=attempt)
                self._say_progress(f"robot back after {attempt} attempt(s): resuming")
                self.stage.say("resumed", behavior="greeting")
                return True
            except (RobotUnavailable, RobotConnectionLost, RobotCallFailed) as exc:
                self.rec.event("reconnect_failed", attempt=attempt, error=str(exc), next_wait_s=min(backoff * 2, r.backoff_max_s))
                backoff = min(backoff * 2, r.backoff_max_s)
        return False

    # -- shutdown --------------------------------------------------------------------------------

    def leave_safe(self) -> None:
        """Safe posture and LEDs reset, whatever happened; failures are logged, never raised."""
        self.stage.leave_safe()


def who_stopped(exc: BaseException) -> str:
    """Who stopped the session, for the record."""
    return f"{exc} received" if isinstance(exc, Interrupted) and str(exc) else "operator (Ctrl-C)"
