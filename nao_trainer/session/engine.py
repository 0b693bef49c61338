"""The session engine: one training session as a ``transitions`` state machine.

The states and transitions are data (``session.machine``); each state has a handler ``_do_<state>``
that works through the ports (robot via ``session.stage.Stage``, answers, EEG monitor, policy) and
returns the next trigger. Interruptions are uniform:

* a lost robot (``RobotConnectionLost``) -> ``paused``: the turn in flight is recorded as
  interrupted, the robot reconnected with exponential backoff and the turn replayed; after
  ``robot.max_reconnect_s`` the session ends (``aborted``, exit code 3);
* a refused call the task needs (``RobotCallFailed``: speech, beep) ends it as a robot error (exit 3);
* Ctrl-C or SIGTERM -> ``aborted``: the robot is silenced, exit code 130.

A turn (``core.mdp``): ``select_action`` (policy, new turn state and sequence), ``feedback`` (RF
actions), ``announce``, ``speak_sequence``, ``beep`` (the answer window opens), ``await_answer``,
``score`` (equation (1)), ``record`` (turns.csv, fsynced; the policy observes the transition).
The engine imports no adapter: ``session.wiring`` builds them and hands them in.
"""
from __future__ import annotations

import sys
import time
from typing import Any, Callable, TextIO

import numpy as np
from transitions import Machine

from nao_trainer.core import mdp, task
from nao_trainer.errors import Interrupted, RobotUnavailable
from nao_trainer.ports import (Answer, AnswerSource, EngagementMonitor, NullMonitor, PhaseEngagement, Policy, Robot,
                               RobotCallFailed, RobotConnectionLost, Transition, TurnContext)
from nao_trainer.session.behaviors import Behaviors
from nao_trainer.session.config import StudyConfig
from nao_trainer.session.dialogue import Dialogue
from nao_trainer.session.machine import FINAL_STATES, INTRO_STATES, STATES, TRANSITIONS, TURN_STATES
from nao_trainer.session.record import SessionRecorder, now_iso
from nao_trainer.session.stage import Clock, Stage
from nao_trainer.session.turn import Turn, progress_line

EXIT_OK, EXIT_ROBOT_LOST, EXIT_INTERRUPTED = 0, RobotUnavailable.exit_code, Interrupted.exit_code


class Session:
    """One training session: owns the machine and talks to the world only through the ports.

    Build it connected (``wiring.run_session`` does that); ``run()`` plays it to the end and
    returns the exit code. Everything random comes from ``rng`` (sequences, dialogue variants) and
    the policy's own generator, so a seed replays a session exactly.
    """

    def __init__(self, config: StudyConfig, robot: Robot, answers: AnswerSource, policy: Policy,
                 recorder: SessionRecorder, dialogue: Dialogue, behaviors: Behaviors, rng: np.random.Generator,
                 policy_rng: np.random.Generator, monitor: EngagementMonitor | None = None,
                 progress: TextIO | None = sys.stderr, sleep: Callable[[float], None] = time.sleep) -> None:
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
        self._phase: str | None = None
        self._beep_onset = 0.0
        self.machine = Machine(model=self, states=STATES, transitions=TRANSITIONS, initial="greet",
                               auto_transitions=False, send_event=True, after_state_change="_log_transition")

    # -- driver ----------------------------------------------------------------------------------

    def run(self) -> int:
        """Play the session to ``done`` or ``aborted``; returns the exit code."""
        self.rec.event("session_start", turns=self.n_turns, policy=self.policy.name)
        self.monitor.mark("session_start")
        while self.state not in FINAL_STATES:
            try:
                trigger = getattr(self, f"_do_{self.state}")()
            except RobotConnectionLost as exc:
                self.lost_in = self.state
                self.rec.event("robot_lost", state=self.state, error=str(exc),
                               turn=self.turn.number if self.turn else None)
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

    def _log_transition(self, event: Any) -> None:
        self.rec.event("transition", trigger=event.event.name, source=event.transition.source,
                       dest=event.transition.dest, turn=self.turn.number if self.turn else None)

    def _say_progress(self, line: str) -> None:
        if self.progress is not None:
            print(line, file=self.progress, flush=True)

    # -- EEG phases and the answer window ----------------------------------------------------------

    def _begin_phase(self, phase: str, turn: int | None) -> None:
        if self._phase is not None:
            self._end_phase()
        self.monitor.begin_phase(phase, turn)
        self.monitor.mark(f"{phase}_start", turn)
        self._phase = phase

    def _end_phase(self) -> PhaseEngagement | None:
        if self._phase is None:
            return None
        self.monitor.mark(f"{self._phase}_end", self.turn.number if self.turn else None)
        self._phase = None
        return self.monitor.end_phase()

    def _beep(self, turn: int) -> float:
        """Open the answer window and beep; returns the beep onset (time 0 of the answer)."""
        self.stage.look("answer")
        self.answers.open_window()
        return self.stage.beep(turn)

    def _collect(self, turn: int, length: int, onset: float) -> Answer:
        """Close the listening phase at beep + tail (EEG), then wait for the answer."""
        if self._phase == "listening":
            self.clock.wait_until(onset + self.clock.wall(self.cfg.timing.listening_tail_s))
            assert self.turn is not None
            self.turn.listening = self._end_phase()
            self._begin_phase("answer", turn)
        # The window opened at the beep; the timeout counts from there (sources measure from open_window).
        answer = self.answers.collect(length, self.clock.wall(self.cfg.timing.response_timeout_s(length)))
        if not self.robot.is_connected():  # an answer window does not talk to the robot: ask
            raise RobotConnectionLost("the robot dropped during the answer window")
        return answer

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
        self.stage.announce(1, length, look=False)
        self.stage.letters(context.sequence)
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
                        phase=turn.phase)
        action = int(self.policy.act(self.mdp_state, self.policy_rng))
        phase = str(self.policy.status().get("phase", ""))
        if not (0 <= action < mdp.N_ACTIONS and mdp.ACTION_MASK[self.mdp_state, action]):
            raise ValueError(f"policy {self.policy.name} chose action {action!r}, "
                             f"not allowed in state {mdp.state_label(self.mdp_state)}")
        if self.mdp_state == mdp.START:
            state = int(mdp.NEXT_STATE[mdp.START, action, 0])
        else:
            state = mdp.next_state(self.mdp_state, action, bool(self.last_success))
        return Turn(self.completed + 1, self.mdp_state, action, state, phase=phase)

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
        self.stage.announce(st.level, st.length)
        return "speak"

    def _do_speak_sequence(self) -> str:
        assert self.turn is not None
        self.stage.letters(self.turn.sequence)
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
        row = self._record_row(turn, score, task.signed_score(st.level, turn.success))
        self.completed += 1
        self.total += score
        done = self.completed >= self.n_turns
        engagement = turn.listening.engagement if turn.listening else None
        self.policy.observe(Transition(turn.previous_state, turn.action, score, engagement, turn.state, done))
        self.mdp_state, self.last_success = turn.state, turn.success
        self.rec.event("turn_end", turn=turn.number, success=turn.success, score=score, total=self.total)
        self.monitor.mark("turn_end", turn.number)
        self._say_progress(progress_line(row, self.n_turns, self.total))
        status = self.policy.status()  # e.g. the posterior over user models after this turn
        if status:
            self.rec.event("policy_status", turn=turn.number,
                           **{k: v for k, v in status.items() if k not in ("progress", "summary", "phase")})
            if status.get("progress"):
                self._say_progress(status["progress"])
        return "finish_turns" if done else "next_turn"

    def _record_row(self, turn: Turn, score: int | None, signed: int | None) -> dict[str, Any]:
        row = turn.row(score, signed, self.clock.speed, self.monitor.records_eeg)
        self.rec.turn(row)
        turn.recorded = True
        self.rows.append(row)
        return row

    def _abandon_turn(self, why: str) -> None:
        """Record the turn in flight as interrupted (never silently lost)."""
        turn = self.turn
        assert turn is not None
        self._end_phase()
        self.answers.abandon()
        turn.notes.append(why)
        turn.success = None
        self._record_row(turn, None, None)
        self.rec.event("turn_interrupted", turn=turn.number, reason=why)
        self._say_progress(f"turn {turn.number:3d}/{self.n_turns}  {why}")

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
