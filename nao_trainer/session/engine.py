"""The session engine: one training session as a ``transitions`` state machine.

The states and transitions are data (``session.machine``); each state has a handler ``_do_<state>``
that works through the ports (robot via ``session.stage.Stage``, answers, EEG monitor, policy) and
returns the next trigger. Interruptions are uniform:

* a lost robot (``RobotConnectionLost``) -> ``paused``: the turn in flight is recorded as
  interrupted, the robot reconnected with exponential backoff and the turn replayed; after
  ``robot.max_reconnect_s`` the session ends (``aborted``, exit code 3);
* a refused call the task needs (``RobotCallFailed``: speech, beep) ends it as a robot error (exit 3),
  unless the robot was put to sleep or its Autonomous Life changed: then that is set back
  (``ports.RobotUpkeep``), and the turn in flight replayed or the intro or goodbye played again, once each;
* Ctrl-C or SIGTERM -> ``aborted``: the robot is silenced, exit code 130;
* operator commands (``session.operator``) act between states: pause, resume, stop (exit code 5);
  ``session.max_duration_s`` ends the session between turns (status "time limit", exit 0).

A turn (``core.mdp``): ``select_action`` (policy, new turn state and the task's trial), ``feedback`` (RF
actions), ``announce``, ``present`` (the task presents its trial), ``open_window`` (the beep), ``collect``,
``judge`` (the task judges and scores: equation (1) for the sequence task), ``record`` (turns.csv, fsynced; the
policy observes the transition). The session is generic over ``tasks.base.Task`` (``SessionPorts.task``).
The parts ``Session`` composes, each in its own module and built with only what it touches:
``session.operator.OperatorDesk`` (commands), ``session.checkpoint.Checkpointer`` (``--resume``),
``session.phases.PhaseClock`` (EEG phases, the answer window), ``session.reporting.SessionLog`` (rows,
events, progress). The ports come in as one ``SessionPorts``; the handlers of a turn's states get the
turn in flight. The engine imports no adapter: ``session.wiring`` builds them and hands them in.
"""
from __future__ import annotations

import sys
import time
from typing import Any, Callable, TextIO

import numpy as np
from transitions import Machine

from nao_trainer.core import mdp
from nao_trainer.errors import Interrupted, RobotUnavailable
from nao_trainer.ports import (Command, Press, RobotCallFailed, RobotConnectionLost, SessionObserver, Transition,
                               TurnContext)
from nao_trainer.session.checkpoint import Checkpointer, Standing
from nao_trainer.session.config import StudyConfig
from nao_trainer.session.machine import (AGAIN_STATES, FINAL_STATES, IN_TURN, INTRO_STATES, REPLAYABLE, STATES,
                                        TRANSITIONS, TURN_STATES)
from nao_trainer.session.health import HealthDesk
from nao_trainer.session.operator import HOLD_STATES, OperatorDesk, who_stopped
from nao_trainer.session.parts import Randomness, Script, SessionPorts
from nao_trainer.session.phases import PhaseClock
from nao_trainer.session.reconnect import Reconnector
from nao_trainer.session.record import SessionRecorder, now_iso
from nao_trainer.session.reporting import SessionLog
from nao_trainer.session.stage import Clock, Stage
from nao_trainer.session.turn import Turn, progress_line
from nao_trainer.tasks.base import table_fields

EXIT_OK, EXIT_ROBOT_LOST, EXIT_INTERRUPTED = 0, RobotUnavailable.exit_code, Interrupted.exit_code
#: The operator stopped the session (a key or the console): goodbye and safe posture, then this code.
EXIT_OPERATOR_STOP = 5
#: Every turn was played and recorded, but events.jsonl or session.xdf could not be written to the end (a full disk).
EXIT_RECORD_INCOMPLETE = 6


class Session:
    """One training session: owns the machine and talks to the world only through the ports.

    Build it connected (``wiring.run_session`` does that); ``run()`` plays it to the end and
    returns the exit code. Everything random comes from ``random`` (sequences, dialogue variants) and
    the policy's own generator, so a seed replays a session exactly. Its parts: ``log``
    (``SessionLog``), ``phases`` (``PhaseClock``), ``desk`` (``OperatorDesk``), ``checkpoints``
    (``Checkpointer``) and ``stage`` (``Stage``), each built with what it touches.
    """

    def __init__(self, config: StudyConfig, ports: SessionPorts, recorder: SessionRecorder, script: Script,
                 random: Randomness, *, progress: TextIO | None = sys.stderr, sleep: Callable[[float], None] = time.sleep,
                 resume: dict[str, Any] | None = None, policy_state: dict[str, Any] | None = None) -> None:
        self.cfg = config
        self.ports = ports
        self.robot, self.answers, self.policy, self.monitor = ports.robot, ports.answers, ports.policy, ports.monitor
        self.observer: SessionObserver = ports.observer
        self.rec = recorder
        self.behaviors = script.behaviors
        self.rng = random.session
        self.policy_rng = random.policy
        self.clock = Clock(config.timing.speed, sleep)
        self.stage = Stage(ports.robot, script.dialogue, script.behaviors, random.session, recorder, self.clock,
                           config.timing, config.robot.posture_speed, config.robot.link_deadline_s)
        self.log = SessionLog(recorder, ports.observer, progress, self.clock)
        self.rows: list[dict[str, Any]] = self.log.rows  # the rows this run wrote (and those before a resumption)
        self.phases = PhaseClock(ports.monitor, self.stage, ports.answers, ports.robot, self.clock, config.timing,
                                 recorder, self.log, config.eeg.missing_alert_turns, config.eeg)
        self.desk = OperatorDesk(ports.commands, self.log, recorder, ports.monitor, ports.observer)
        self.phases.commands = ports.commands  # a wait for a lost EEG stream ends on a pause or stop
        model = config.robot.robot_model()
        self.health = HealthDesk(ports.health, ports.upkeep, ports.commands, self.log, recorder, ports.monitor,
                                 ports.observer, model.cool_posture(),
                                 bool(getattr(model.settings, "pause_on_safeguard", True)))
        self.checkpoints = Checkpointer(recorder, ports.policy, random.by_name())
        self.reconnector = Reconnector(ports.robot, config.robot, self.clock, recorder, self.log, self.stage)
        self.reconnector.commands = ports.commands  # a stop ends the reconnection attempts ...
        self.reconnector.between_attempts = self._while_away  # ... a pause and a resume act at once
        self.away_paused = False  # the operator paused while the robot was away: paused once it is back
        self.task = ports.task
        self.in_window = bool(getattr(ports.task, "presents_in_window", False))  # answers come during present
        self.stage.mark = ports.monitor.mark
        self.n_turns = config.session.turns
        self.mdp_state = mdp.START
        self.last_success: bool | None = None
        self.turn: Turn | None = None  # the turn in flight, or the last one played
        self.replay: Turn | None = None
        self._set_back_in: set[str] = set()  # turns and intro states played again after a refused call
        self.total = 0
        self.completed = 0
        self.lost_in: str | None = None
        self.status = "running"
        self.error = ""
        self._beep_onset = 0.0
        self._resume = resume  # the checkpoint to resume from, until it is used
        self._elapsed_before = 0.0  # session seconds played before a resumption
        self._policy_state = policy_state  # which learning state the policy started from (events.jsonl)
        self._t0 = self.clock.now()
        self.max_duration_s = config.session.max_duration_s
        self.machine = Machine(model=self, states=STATES, transitions=TRANSITIONS, initial="greet",
                               auto_transitions=False, send_event=True, after_state_change="_log_transition")
        self.answers.watch(self._on_press)

    def _turn_number(self) -> int | None:
        return self.turn.number if self.turn else None

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
                                         "robot": "connected", "completed": self.completed, "state": self.state,
                                         "task": self.task.name, "fields": [list(f) for f in table_fields(self.task)]})
        while self.state not in FINAL_STATES:
            try:
                if self._resume is not None:
                    trigger = self._resume_from_checkpoint()
                else:
                    trigger = self._between_states() or self._handle(self.state)
            except RobotConnectionLost as exc:
                self.lost_in = self.state
                self.rec.event("robot_lost", state=self.state, error=str(exc), turn=self._turn_number())
                self.observer.notify("robot", {"robot": "lost", "error": str(exc)})
                self.trigger("robot_lost")
                continue
            except (KeyboardInterrupt, Interrupted) as exc:
                self.interrupted_by_operator(who_stopped(exc))
                break
            except RobotCallFailed as exc:  # the robot refused a call the task needs (speech, beep)
                if self._set_back(exc):
                    continue
                self._robot_failed(exc)
                break
            self.trigger(trigger)
        return self._exit_code()

    def _handle(self, state: str) -> str:
        """Run the handler of ``state``; the handlers of a turn's states get the turn in flight."""
        handler = getattr(self, f"_do_{state}")
        if state in IN_TURN:
            assert self.turn is not None  # select_action made it
            return handler(self.turn)
        return handler()

    def _exit_code(self) -> int:
        if self.state == "done":
            if self.status == "stopped":
                return EXIT_OPERATOR_STOP
            if self.status not in ("time limit", "battery low"):
                self.status = "completed"
            return EXIT_OK
        if self.status == "stopped":  # stopped while the robot was away (session.reconnect)
            return EXIT_OPERATOR_STOP
        return EXIT_INTERRUPTED if self.status == "interrupted" else EXIT_ROBOT_LOST

    def interrupted_by_operator(self, by: str = "operator (Ctrl-C)") -> None:
        """Ctrl-C/SIGTERM: silence the robot, record the turn in flight, go to ``aborted``."""
        self.status = "interrupted"
        self.rec.event("interrupted", state=self.state, by=by)
        self.stage.silence()  # the robot may be mid-sentence: before the safe posture
        self._abort(f"interrupted: {by}")

    def _set_back(self, exc: RobotCallFailed) -> bool:
        """A call refused by a NAO put to sleep (a hand held 3 s on its head, life on) or changed: set back, the
        turn replayed or an intro state (not a resumed greeting) or the goodbye played again; once each."""
        turn = self.turn if self.state in REPLAYABLE and self.turn is not None and not self.turn.recorded else None
        where = f"turn {turn.number}" if turn is not None else self.state
        resumed_greeting = self.state == "greet" and self.completed > 0  # a resumption's "resumed" line
        if where in self._set_back_in or (turn is None and (self.state not in AGAIN_STATES or resumed_greeting)):
            return False
        fixed = self.ports.upkeep.between_turns()
        if not fixed:
            return False
        self._set_back_in.add(where)
        self.rec.event("robot_call_failed", state=self.state, error=str(exc), fatal=False, set_back=fixed)
        why = f"robot refused a call ({'; '.join(fixed)}: set back)"
        if turn is not None:
            self._abandon_turn(turn, f"interrupted: {why}")
            self.replay = turn
            self.trigger("robot_recovered")
        else:  # the loop plays the same state again
            self.answers.abandon()  # the practice's window, if its beep was refused
            self.log.say(f"{self.state}: {why}; again")
        return True

    def _robot_failed(self, exc: RobotCallFailed) -> None:
        self.status = "robot error"
        self.error = str(exc)
        self.rec.event("robot_call_failed", state=self.state, error=str(exc), fatal=True)
        self._abort(f"interrupted: robot error ({exc})")

    def _abort(self, why: str) -> None:
        """The turn in flight recorded as interrupted (``why``), then ``aborted``."""
        if self.turn is not None and not self.turn.recorded:
            self._abandon_turn(self.turn, why)
        if self.state not in FINAL_STATES:
            self.trigger("abort")

    def elapsed_s(self) -> float:
        """Session seconds since the session started (across a resumption; pauses count)."""
        return self._elapsed_before + self.clock.session(self.clock.now() - self._t0)

    def wall_elapsed_s(self) -> float:
        """Wall seconds since the session started (what the console's clock shows: a demo sped up x25 that took
        30 s shows 30 s, not 750)."""
        return self.clock.wall(self.elapsed_s())

    # -- what the session writes down (session.reporting) ----------------------------------------

    def _log_transition(self, event: Any) -> None:
        self.log.transition(event.event.name, event.transition.source, event.transition.dest, self.state,
                            self._turn_number(), self.elapsed_s())

    def _on_press(self, press: Press) -> None:
        self.log.press(press, self.turn.number if self.turn else 0)

    def _abandon_turn(self, turn: Turn, why: str) -> None:
        """Record the turn in flight as interrupted (never silently lost)."""
        self.phases.end(turn.number)
        self.answers.abandon()
        turn.notes.append(why)
        turn.success = None
        row = self.log.row(turn, turn.row(None, None, self.clock.speed, self.monitor.records_eeg, self.task.columns))
        self.rec.event("turn_interrupted", turn=turn.number, reason=why)
        self.observer.notify("row", {**row, "total": self.total, "elapsed_s": round(self.elapsed_s(), 2)})
        self.log.say(f"turn {turn.number:3d}/{self.n_turns}  {why}")

    # -- intro -----------------------------------------------------------------------------------

    def _do_greet(self) -> str:
        self.phases.begin("baseline", None)
        self.stage.posture(self.behaviors.start_posture)
        self.stage.say("greeting", pseudonym=self.cfg.participant.pseudonym)
        return "explain"

    def _do_instructions(self) -> str:
        if self.phases.phase is None:
            self.phases.begin("baseline", None)
        self.stage.say("instructions", turns=self.n_turns)
        self.phases.end(self._turn_number())
        return "practise" if self.cfg.session.practice else "begin_turns"

    def _do_practice(self) -> str:
        self.stage.say("practice_intro", behavior="practice")
        trial = self.task.practice_trial(self.rng)
        size = self.task.size(trial)
        context = TurnContext(0, mdp.encode(mdp.LENGTHS[trial.level - 1], 0, 0), size, trial.stimuli, trial)
        self.answers.prepare(context)
        self.stage.announce(trial.level, size, look=False, turn=0)
        if self.in_window:
            onset = self.phases.beep(0)
            self.task.present(self.stage, trial, 0, onset)
        else:
            self.task.present(self.stage, trial, 0)
            onset = self.phases.beep(0)
        answer, _ = self.phases.collect(0, self._presses(trial), self._timeout_s(trial), onset)
        ok = not answer.timed_out and self.task.judge(trial, answer).success
        self.rec.event("practice", sequence="".join(trial.stimuli), response="".join(answer.response), success=ok)
        self.stage.say("practice_success" if ok else "practice_failure", behavior="practice")
        return "begin_turns"

    def _presses(self, trial) -> int:
        """Presses that end the answer window early (a stream task waits for its timeout)."""
        return trial.presses if trial.presses is not None else 10**6

    def _timeout_s(self, trial) -> float:
        t = self.cfg.timing
        return self.task.response_timeout_s(trial, t.response_timeout_base_s, t.response_timeout_per_letter_s)

    # -- a turn ----------------------------------------------------------------------------------

    def _next_turn(self) -> Turn:
        """The replayed turn after a loss, else the policy's choice in the current MDP state."""
        if self.replay is not None:
            turn, self.replay = self.replay, None
            return turn.again()
        notes: list[str] = []
        action = self.desk.take_override(self.mdp_state)
        if action is not None:
            notes.append(f"operator chose {mdp.ACTION_NAMES[action]}")
            self.policy.guide(self.mdp_state, action)
        else:
            action = int(self.policy.act(self.mdp_state, self.policy_rng))
        phase = "override" if notes else str(self.policy.status().get("phase", ""))
        return Turn.chosen(self.completed + 1, self.mdp_state, action, self.last_success, self.policy.name, notes, phase)

    def _do_select_action(self) -> str:
        self.ports.upkeep.between_turns()  # Autonomous Life or the motors changed by someone: set back
        self.turn = turn = self._next_turn()
        st = turn.turn_state
        turn.trial = self.task.make_trial(st.level, self.rng)
        turn.sequence = turn.trial.stimuli
        turn.start_time = now_iso()
        self.answers.prepare(TurnContext(turn.number, turn.state, self.task.size(turn.trial), turn.sequence, turn.trial))
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
            "expected": "".join(turn.trial.expected),
            "chosen_in": mdp.state_label(turn.previous_state), "notes": "; ".join(turn.notes),
            "probabilities": None if probs is None else dict(zip(mdp.ACTION_NAMES, (round(float(p), 4) for p in probs)))})
        self.phases.begin("listening", turn.number)
        return "give_feedback" if turn.action in (mdp.ENCOURAGE, mdp.CHALLENGE) else "announce_level"

    def _do_feedback(self, turn: Turn) -> str:
        st = turn.turn_state
        self.stage.feedback(st.feedback, bool(self.last_success), st.level, turn.number)
        return "announce_level"

    def _do_announce(self, turn: Turn) -> str:
        st = turn.turn_state
        self.stage.announce(st.level, self.task.size(turn.trial), turn=turn.number)
        return "open_first" if self.in_window else "speak"

    def _do_present(self, turn: Turn) -> str:
        if self.in_window:
            self.task.present(self.stage, turn.trial, turn.number, self._beep_onset)
            return "collect_presented"
        self.task.present(self.stage, turn.trial, turn.number)
        return "sound_beep"

    def _do_open_window(self, turn: Turn) -> str:
        self._beep_onset = self.phases.beep(turn.number)
        return "present_in_window" if self.in_window else "wait_answer"

    def _do_collect(self, turn: Turn) -> str:
        answer, listening = self.phases.collect(turn.number, self._presses(turn.trial), self._timeout_s(turn.trial),
                                                self._beep_onset)
        turn.answer = answer
        if listening is not None:
            turn.listening = listening
        # The answer phase ends with the answer (judging it talks to nothing): a loss in it is known now.
        turn.answering = self.phases.end(turn.number)
        lost_in = self.phases.lost_eeg(turn.number, listening, turn.answering, turn.replay, turn.notes)
        if lost_in:  # eeg.turn_requires_eeg, and the stream is back
            self._abandon_turn(turn, f"interrupted: EEG lost during the {lost_in} phase")
            self.replay = turn
            return "repeat_turn"
        return "score_answer"

    def _do_judge(self, turn: Turn) -> str:
        if self.phases.phase is not None:  # a phase still open (collect ends the answer phase)
            turn.answering = self.phases.end(turn.number)
        turn.judge(self.task)
        return "record_turn"

    def _do_record(self, turn: Turn) -> str:
        assert turn.success is not None  # judged in judge
        st = turn.turn_state
        score = self.task.score(st.level, turn.success)
        row = turn.row(score, self.task.signed_score(st.level, turn.success), self.clock.speed, self.monitor.records_eeg,
                       self.task.columns)
        self.completed += 1
        if not turn.invalid:  # the total counts what the summary counts: turns not marked invalid
            self.total += score
        done = self.completed >= self.n_turns
        engagement = turn.listening.engagement if turn.listening else None
        learn = None
        if turn.invalid:  # the operator marked it invalid: the learner does not see it
            self.rec.event("not_learned", turn=turn.number, reason="marked invalid")
        else:
            learn = Transition(turn.previous_state, turn.action, score, engagement, turn.state, done)
        self.mdp_state, self.last_success = turn.state, turn.success
        # The answered turn is on disk before the participant's learning state is saved: the checkpoint
        # (with this row and the transition not yet learned), then the row, then the policy learns and
        # saves. A kill or a failed write in between loses nothing: a resumption appends the checkpoint's
        # row when turns.csv lacks it, and hands the policy the transition.
        try:
            self.checkpoints.write(self._standing(), row, self.elapsed_s(), self.desk.override, learn)
        except OSError:  # a full disk: the answered turn is still kept in turns.csv, then the failure ends the session
            self.log.row(turn, row)
            raise
        self.log.row(turn, row)
        if learn is not None:
            self.policy.observe(learn)
        self.rec.event("turn_end", turn=turn.number, success=turn.success, score=score, total=self.total)
        self.monitor.mark("turn_end", turn.number)
        self.observer.notify("row", {**row, "total": self.total, "elapsed_s": round(self.elapsed_s(), 2)})
        self.log.say(progress_line(row, self.n_turns, self.total, self.task))
        self.phases.note_signal(turn.number, turn.listening)
        self.log.policy_status(self.policy.status(), turn.number)
        return "finish_turns" if done else "next_turn"

    def _standing(self) -> Standing:
        return Standing(self.completed, self.total, self.mdp_state, self.last_success)

    # -- goodbye ---------------------------------------------------------------------------------

    def _do_goodbye(self) -> str:
        self.stage.goodbye(self.total, self.completed)
        self.monitor.mark("session_end")
        return "end"

    # -- resumed (run --resume) ------------------------------------------------------------------

    def _resume_from_checkpoint(self) -> str:
        """A resumed session: restore the state of the last completed turn and go to the next turn."""
        cp, self._resume = self._resume, None
        assert cp is not None
        restored = self.checkpoints.restore(cp)
        st = restored.standing
        self.completed, self.total, self.mdp_state, self.last_success = st.completed, st.total, st.mdp_state, st.last_success
        self.desk.override = restored.override
        self._elapsed_before = restored.elapsed_s
        self._t0 = self.clock.now()
        self.log.rows[:] = restored.rows
        self.rec.event("resumed", after_turn=self.completed, total=self.total, elapsed_s=self._elapsed_before)
        self.monitor.mark("session_resumed")
        self.stage.posture(self.behaviors.start_posture)
        # An utterance the uninterrupted session did not have: its own generator, not the session's.
        self.stage.say("resumed", behavior="greeting", rng=np.random.default_rng(self.completed))
        self.log.because(f"resumed after turn {self.completed}")
        return "resume_session"

    # -- operator commands (session.operator decides, the session acts) ---------------------------

    def _time_up(self) -> bool:
        return self.max_duration_s is not None and self.elapsed_s() >= self.max_duration_s

    def _between_states(self) -> str | None:
        """The defined point where commands act: drain the queue, then look at the clock.

        Returns the trigger of a command that changes the state (stop wins over pause), else None.
        """
        if self.state in ("operator_pause", "paused"):
            # operator_pause: its handler says the pause line first, then takes the commands; paused (the robot
            # is away): the reconnection looks for a stop meanwhile, the rest act once the robot is back
            return None
        self.health.take(self.state, self.turn)  # the robot's falls, heat, battery, chest button (session.health)
        trigger = self._apply_pending(hold=self.state in HOLD_STATES)
        if trigger is None and self.state == "select_action" and self._time_up():
            return self._end_for_time()
        if trigger is None and self.state == "select_action" and self.health.before_turn(self.stage):
            return self._end_for_battery()
        return trigger

    def _end_for_battery(self) -> str:
        """BatteryLow: the turn in flight was finished; end cleanly, saying what to do."""
        self.status = "battery low"
        self.rec.event("battery_low_end", completed=self.completed)
        self.log.say(f"robot battery low: the session ends after turn {self.completed} of {self.n_turns}; charge "
                     "the robot (plug it in, about an hour to full) before the next session")
        return "time_up"

    def _apply_pending(self, hold: bool = False) -> str | None:
        """Apply the due commands in order until one changes the state; the rest wait for the next point."""
        pending = self.desk.due(hold)
        for i, cmd in enumerate(pending):
            try:
                trigger = self._apply(cmd)
            except (ValueError, TypeError, KeyError, AttributeError, OverflowError) as exc:
                # A malformed command (a program's, or one the console let through) is refused and logged; it
                # never ends the session. The console checks arguments on arrival too (console.command_schema).
                self.desk.record(cmd, False, f"malformed arguments ignored ({type(exc).__name__}: {str(exc)[:200]})",
                                 self.state, self._turn_number())
                continue
            if trigger is not None:
                self.desk.hold(pending[i + 1:])
                return trigger
        return None

    def _apply(self, cmd: Command) -> str | None:
        """Carry out one command; returns a trigger that changes the state, or None."""
        turn = self.turn
        decision = self.desk.decide(cmd, self.state, set(self.machine.get_triggers(self.state)), turn)
        if decision.trigger is None:
            self.desk.record(cmd, False, decision.detail, self.state, self._turn_number())
            return None
        if decision.internal:
            self.log.because(decision.by)
            self.trigger(decision.trigger)
            self.desk.record(cmd, True, decision.detail, self.state, self._turn_number())
            return None
        if decision.abandon and turn is not None:
            if decision.silence:
                self.stage.silence()
            self._abandon_turn(turn, f"interrupted: {decision.by}")
            if decision.replay:
                self.replay = turn
        if decision.status:
            self.status = decision.status
        self.log.because(decision.by)
        self.desk.record(cmd, True, decision.detail, self.state, self._turn_number())
        return decision.trigger

    def _end_for_time(self) -> str:
        self.status = "time limit"
        self.log.time_limit(self.max_duration_s, self.elapsed_s())
        return "time_up"

    def _do_operator_pause(self) -> str:
        """Paused by the operator: say so, keep the EEG recording, wait for resume or stop."""
        self.phases.end(self._turn_number())
        self.monitor.mark("pause_start", self._turn_number())
        self.log.paused(self.desk.paused_in)
        self.stage.say("paused")
        while True:
            trigger = self._apply_pending()
            if trigger is not None:
                if trigger != "operator_stop":
                    self.health.resumed()  # the operator says the robot is up: its motors may wake again
                    self.monitor.mark("pause_end", self._turn_number())
                    self.log.resumed()
                    self.stage.say("resumed", behavior="greeting")
                return trigger
            if self._time_up():
                return self._end_for_time()
            self.desk.wait()

    # -- robot lost --------------------------------------------------------------------------------

    def _do_paused(self) -> str:
        lost_in = self.lost_in or "select_action"
        self.phases.end(self._turn_number())
        if self.turn is not None and not self.turn.recorded and lost_in in TURN_STATES:
            self._abandon_turn(self.turn, f"interrupted: robot lost during {lost_in}")
            self.replay = self.turn
        self.log.say(f"robot lost during {lost_in}: paused, reconnecting...")
        self.away_paused = False
        if not self.reconnector.reconnect():
            if self.reconnector.stopped:  # the operator stopped while the robot was away: no goodbye to say
                self.status = "stopped"
                for cmd in self.desk.due(False):
                    accepted = cmd.kind == "stop"
                    self.desk.record(cmd, accepted, "stop while the robot is away: the session ends without a "
                                     "goodbye" if accepted else "not possible while the robot is away", self.state,
                                     self._turn_number())
                self.log.say("stopped by the operator while the robot was away: the session ends")
                return "abort"
            self.status = "robot lost"
            self.rec.event("give_up", after_s=self.cfg.robot.max_reconnect_s)
            self.log.say(f"robot not back within {self.cfg.robot.max_reconnect_s:g} s: ending the session")
            return "give_up"
        if self.away_paused:  # the operator paused meanwhile: paused until they go on (operator_pause says so)
            self.away_paused = False
            self.log.say(f"robot back after {self.reconnector.attempts} attempt(s): the session stays paused (paused "
                         "by the operator while it was away)")
            return "pause"
        self.log.say(f"robot back after {self.reconnector.attempts} attempt(s): resuming")
        self.stage.say("resumed", behavior="greeting")
        if lost_in in INTRO_STATES:
            return "resume_intro"
        if lost_in == "goodbye":
            return "resume_goodbye"
        return "resume_turn"

    def _while_away(self) -> bool:
        """Between reconnection attempts: True once the operator asked to stop (the attempts end). A pause acts at
        once: recorded, and the session stays paused once the robot is back until the operator goes on; a resume
        after it cancels it (the session plays on once the robot is back). Other commands act once it is back."""
        if self.desk.stop_waiting():
            return True
        lost_in = self.lost_in or "select_action"
        for cmd in self.desk.take(("pause", "resume")):
            if cmd.kind == "pause":
                if lost_in == "goodbye":
                    accepted, detail = False, "the robot is away during the goodbye: it is said once the robot is back"
                elif self.away_paused:
                    accepted, detail = False, "already paused"
                else:
                    accepted, detail = True, ("paused while the robot is away: the session stays paused once it is "
                                              "back, until resumed")
                    self.away_paused = True
                    self.desk.paused_in = lost_in
            elif self.away_paused:
                accepted, detail = True, "resumed while the robot is away: the session plays on once it is back"
                self.away_paused = False
            else:
                accepted, detail = False, "not paused (the session plays on once the robot is back)"
            self.desk.record(cmd, accepted, detail, self.state, self._turn_number())
            if accepted and cmd.kind == "pause":
                self.log.paused(lost_in)
            elif accepted:
                self.log.resumed()
        return False

    # -- shutdown --------------------------------------------------------------------------------

    def leave_safe(self) -> None:
        """Safe posture and LEDs reset, whatever happened; failures are logged, never raised."""
        self.stage.leave_safe()
