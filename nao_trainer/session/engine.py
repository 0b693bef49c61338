"""The session engine: one training session as a ``transitions`` state machine.

The states and transitions are data (``session.machine``); each state has a handler ``_do_<state>``
that works through the ports (robot via ``session.stage.Stage``, answers, EEG monitor, policy) and
returns the next trigger. Interruptions are uniform:

* a lost robot (``RobotConnectionLost``) -> ``paused``: the turn in flight is recorded as
  interrupted, the robot reconnected with exponential backoff and the turn replayed; after
  ``robot.max_reconnect_s`` the session ends (``aborted``, exit code 3);
* a refused call the task needs (``RobotCallFailed``: speech, beep) ends it as a robot error (exit 3);
* Ctrl-C or SIGTERM -> ``aborted``: the robot is silenced, exit code 130.

Operator commands (``ports.CommandQueue``: terminal keys, the console) are drained between states
and each fires a trigger of ``session.machine.COMMAND_TRIGGERS``; a command whose trigger the
current state does not have is refused, with the reason, in ``events.jsonl``. Pause takes effect
after the current state (the robot finishes its utterance), says the pause line and waits, the EEG
still recording; resume replays the interrupted turn; stop says goodbye (exit code 5).
``session.max_duration_s`` ends the session between turns (status "time limit", exit 0).

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
from nao_trainer.ports import (Answer, AnswerSource, Command, CommandQueue, EngagementMonitor, NullMonitor,
                               NullObserver, PhaseEngagement, Policy, Press, Robot, RobotCallFailed,
                               RobotConnectionLost, SessionObserver, Transition, TurnContext)
from nao_trainer.session.behaviors import Behaviors
from nao_trainer.session.config import StudyConfig
from nao_trainer.session.dialogue import Dialogue
from nao_trainer.session.machine import (COMMAND_TRIGGERS, FINAL_STATES, IN_TURN, INTRO_STATES, STATES, TRANSITIONS,
                                         TURN_STATES)
from nao_trainer.session.record import SessionRecorder, now_iso
from nao_trainer.session.stage import Clock, Stage
from nao_trainer.session.turn import Turn, progress_line

EXIT_OK, EXIT_ROBOT_LOST, EXIT_INTERRUPTED = 0, RobotUnavailable.exit_code, Interrupted.exit_code
#: The operator stopped the session (a key or the console): goodbye and safe posture, then this code.
EXIT_OPERATOR_STOP = 5
#: How often (wall seconds) a paused session looks at the command queue and the clock.
PAUSE_POLL_S = 0.2
#: States where pause, stop and repeat wait for the turn to be recorded.
HOLD_STATES = ("score", "record")


class Session:
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
        self._phase: str | None = None
        self._beep_onset = 0.0
        self.commands = commands if commands is not None else CommandQueue()
        self.observer: SessionObserver = observer or NullObserver()
        # Generators a checkpoint must carry besides the session's and the policy's (the simulated participant's).
        self._rngs = {"session": rng, "policy": policy_rng, **(rngs or {})}
        self._resume = resume
        self._policy_state = policy_state  # which learning state the policy started from (events.jsonl)
        self._override: int | None = None  # the operator's choice for the next turn
        self._held: list[Command] = []  # pause/stop/repeat that came while a turn was being scored/recorded
        self._paused_in: str | None = None
        self._reason: str | None = None  # why the next transition happens (an operator command, the clock)
        self._elapsed_before = 0.0  # session seconds played before a resumption
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

    def _log_transition(self, event: Any) -> None:
        reason, self._reason = self._reason, None
        turn = self.turn.number if self.turn else None
        extra: dict[str, Any] = {"reason": reason} if reason else {}
        dest = event.transition.dest
        if dest is None:  # an internal transition (an operator command that does not change the state)
            dest, extra["internal"] = self.state, True
        self.rec.event("transition", trigger=event.event.name, source=event.transition.source,
                       dest=dest, turn=turn, **extra)
        self.observer.notify("state", {"state": dest, "trigger": event.event.name, "turn": turn,
                                       "elapsed_s": round(self.elapsed_s(), 2), **extra})

    def elapsed_s(self) -> float:
        """Session seconds since the session started (across a resumption; pauses count)."""
        return self._elapsed_before + self.clock.session(self.clock.now() - self._t0)

    def _time_up(self) -> bool:
        return self.max_duration_s is not None and self.elapsed_s() >= self.max_duration_s

    def _on_press(self, press: Press) -> None:
        """An answer source saw a press (called from its thread): tell the observer."""
        self.observer.notify("press", {"turn": self.turn.number if self.turn else 0, "key": press.key,
                                       "letter": press.letter, "t": round(self.clock.session(press.t), 3)})

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
        self.rec.event("answer", turn=turn, timed_out=answer.timed_out,  # each press, seconds from the beep
                       presses=[{"key": p.key, "letter": p.letter, "t": round(self.clock.session(p.t), 3)}
                                for p in answer.presses])
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

    def _take_override(self) -> int | None:
        """The operator's action for this turn, if one is pending and allowed here (else refused, logged)."""
        action, self._override = self._override, None
        if action is None:
            return None
        if not mdp.ACTION_MASK[self.mdp_state, action]:
            self.rec.event("command_refused", kind="override", action=mdp.ACTION_NAMES[action],
                           reason=f"not allowed in state {mdp.state_label(self.mdp_state)}")
            self.observer.notify("command", {"kind": "override", "accepted": False,
                                             "reason": f"{mdp.ACTION_NAMES[action]} not allowed before the first turn"})
            return None
        return action

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

    def _record_row(self, turn: Turn, score: int | None, signed: int | None) -> dict[str, Any]:
        return self._write_row(turn, turn.row(score, signed, self.clock.speed, self.monitor.records_eeg))

    def _write_row(self, turn: Turn, row: dict[str, Any]) -> dict[str, Any]:
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
        self.observer.notify("row", {**self.rows[-1], "total": self.total, "elapsed_s": round(self.elapsed_s(), 2)})
        self._say_progress(f"turn {turn.number:3d}/{self.n_turns}  {why}")

    # -- operator commands -----------------------------------------------------------------------

    def _between_states(self) -> str | None:
        """The defined point where commands act: drain the queue, then look at the clock.

        Returns the trigger of a command that changes the state (stop wins over pause), else None.
        """
        if self.state == "operator_pause":
            return None  # its handler says the pause line first, then takes the commands
        trigger = self._apply_pending(hold=self.state in HOLD_STATES)
        if trigger is None and self.state == "select_action" and self._time_up():
            return self._end_for_time()
        return trigger

    def _apply_pending(self, hold: bool = False) -> str | None:
        """Apply the queued commands in order until one changes the state; the rest wait for the next point.

        ``hold``: pause, stop and repeat wait too (the turn's answer is in: it is recorded first).
        """
        pending, self._held = self._held + self.commands.drain(), []
        for i, cmd in enumerate(pending):
            if hold and cmd.kind in ("pause", "stop", "repeat"):
                self._held.append(cmd)
                continue
            trigger = self._apply(cmd)
            if trigger is not None:
                self._held += pending[i + 1:]
                return trigger
        return None

    def _end_for_time(self) -> str:
        self.status = "time limit"
        self._reason = f"session.max_duration_s = {self.max_duration_s:g} s reached"
        self.rec.event("max_duration", elapsed_s=round(self.elapsed_s(), 2), max_duration_s=self.max_duration_s)
        self._say_progress(f"maximum session duration ({self.max_duration_s:g} s) reached: ending the session")
        return "time_up"

    def _allowed(self, kind: str) -> str | None:
        """The trigger of command ``kind`` the current state has, or None."""
        triggers = set(self.machine.get_triggers(self.state))
        for t in COMMAND_TRIGGERS[kind]:
            if t in triggers:
                if t == "repeat_last" and self.turn is None:
                    continue
                if t == "resume_intro" and self._paused_in not in INTRO_STATES:
                    continue
                if t == "resume_turn" and self._paused_in in INTRO_STATES:
                    continue
                return t
        return None

    def _log_command(self, cmd: Command, accepted: bool, detail: str) -> None:
        self.rec.event("command", kind=cmd.kind, args=cmd.args, source=cmd.source, at=cmd.at, id=cmd.id,
                       state=self.state, accepted=accepted, detail=detail,
                       turn=self.turn.number if self.turn else None)
        if accepted:
            self.monitor.mark(f"command_{cmd.kind}", self.turn.number if self.turn else None)
        self.observer.notify("command", {"id": cmd.id, "kind": cmd.kind, "args": cmd.args, "source": cmd.source,
                                         "at": cmd.at, "state": self.state, "accepted": accepted, "detail": detail})
        if not accepted:
            self._say_progress(f"command {cmd.kind} from {cmd.source} refused: {detail}")

    def _apply(self, cmd: Command) -> str | None:
        """Act on one command at a defined point; returns a trigger that changes the state, or None."""
        trigger = self._allowed(cmd.kind)
        if trigger is None:
            self._log_command(cmd, False, f"not possible in state {self.state}")
            return None
        by = f"{cmd.kind} by operator ({cmd.source})"
        if cmd.kind == "override" or trigger == "repeat_last":
            name = cmd.args.get("action") if cmd.kind == "override" else mdp.ACTION_NAMES[self.turn.action]
            if name not in mdp.ACTION_NAMES:
                self._log_command(cmd, False, f"unknown action {name!r}; use {', '.join(mdp.ACTION_NAMES)}")
                return None
            self._override = mdp.ACTION_NAMES.index(name)
            self._reason = by
            self.trigger(trigger)
            self._log_command(cmd, True, f"next turn plays {name}")
            return None
        if cmd.kind == "invalid":
            assert self.turn is not None
            wanted = cmd.args.get("turn")
            if wanted is not None and int(wanted) != self.turn.number:
                self._log_command(cmd, False, f"turn {wanted} is not the turn in flight ({self.turn.number}); "
                                              "a recorded turn cannot be changed")
                return None
            note = str(cmd.args.get("note") or "").strip()
            self.turn.invalid = True
            self.turn.notes.append(f"invalid ({cmd.source})" + (f": {note}" if note else ""))
            self._reason = by
            self.trigger(trigger)
            self._log_command(cmd, True, f"turn {self.turn.number} marked invalid")
            return None
        if cmd.kind == "note":
            self._reason = by
            self.trigger(trigger)
            self._log_command(cmd, True, str(cmd.args.get("text", ""))[:500])
            return None
        # state changes: pause, resume, stop, repeat of the turn in flight
        if cmd.kind in ("pause", "stop", "repeat") and self.turn is not None and not self.turn.recorded \
                and self.state in IN_TURN:
            if cmd.kind == "stop":
                self.stage.silence()
            self._abandon_turn(f"interrupted: {by}")
            if cmd.kind != "stop":
                self.replay = self.turn
        if cmd.kind == "pause":
            self._paused_in = self.state
        if cmd.kind == "stop":
            self.status = "stopped"
        self._reason = by
        self._log_command(cmd, True, f"{trigger} from {self.state}")
        return trigger

    def _do_operator_pause(self) -> str:
        """Paused by the operator: say so, keep the EEG recording, wait for resume or stop."""
        self._end_phase()
        self.monitor.mark("pause_start", self.turn.number if self.turn else None)
        self.observer.notify("pause", {"paused": True, "in": self._paused_in})
        self._say_progress("paused by the operator: resume with r (or the console), stop with s")
        self.stage.say("paused")
        while True:
            trigger = self._apply_pending()
            if trigger is not None:
                if trigger != "operator_stop":
                    self.monitor.mark("pause_end", self.turn.number if self.turn else None)
                    self.observer.notify("pause", {"paused": False})
                    self._say_progress("resumed by the operator")
                    self.stage.say("resumed", behavior="greeting")
                return trigger
            if self._time_up():
                return self._end_for_time()
            self.commands.wait(PAUSE_POLL_S)

    # -- checkpoint and resumption ----------------------------------------------------------------

    def _checkpoint(self, row: dict[str, Any]) -> None:
        """After each recorded turn: everything a resumed session needs to continue exactly here."""
        self.rec.checkpoint({
            "completed": self.completed, "total": self.total, "mdp_state": self.mdp_state,
            "last_success": self.last_success, "elapsed_s": round(self.elapsed_s(), 3), "row": row,
            "rng": {name: g.bit_generator.state for name, g in self._rngs.items()},
            "policy": self.policy.snapshot(), "override": self._override,
        })

    def _resume_from_checkpoint(self) -> str:
        """A resumed session: restore the state of the last completed turn and go to the next turn."""
        cp, self._resume = self._resume, None
        assert cp is not None
        for name, state in cp["rng"].items():
            if name in self._rngs:
                self._rngs[name].bit_generator.state = state
        self.policy.restore(cp.get("policy"))
        self.completed, self.total = int(cp["completed"]), int(cp["total"])
        self.mdp_state, self.last_success = int(cp["mdp_state"]), cp["last_success"]
        self._override = cp.get("override")
        self._elapsed_before = float(cp.get("elapsed_s", 0.0))
        self._t0 = self.clock.now()
        self.rows = list(cp.get("rows_before", []))
        self.rec.event("resumed", after_turn=self.completed, total=self.total, elapsed_s=self._elapsed_before)
        self.monitor.mark("session_resumed")
        self.stage.posture(self.behaviors.start_posture)
        # An utterance the uninterrupted session did not have: its own generator, not the session's.
        self.stage.say("resumed", behavior="greeting", rng=np.random.default_rng(self.completed))
        self._reason = f"resumed after turn {self.completed}"
        return "resume_session"

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
