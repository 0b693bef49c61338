"""The session engine: one training session as a ``transitions`` state machine.

States and transitions are data (``STATES``, ``TRANSITIONS``); each state has a small handler
``_do_<state>`` that does its work through the ports (robot, answers, EEG monitor, policy) and
returns the trigger to fire next. A driver loop runs handler -> trigger until ``done`` or
``aborted``. This keeps the flow visible in one table (exported to ``docs/session-states.md``)
and makes the two kinds of interruption uniform:

* a lost robot (``ports.RobotConnectionLost`` from any robot call) fires ``robot_lost`` ->
  ``paused``: the turn in flight is recorded as interrupted, the robot is reconnected with
  exponential backoff, the buttons re-subscribed, and the turn is replayed; after
  ``robot.max_reconnect_s`` the session ends cleanly (``aborted``, exit code 3);
* Ctrl-C (or SIGTERM) fires ``abort`` -> ``aborted``: the robot goes to a safe posture with its
  LEDs reset, files are closed, exit code 130.

Per turn (MDP of ``core.mdp``): ``select_action`` asks the policy for an action in the state of the
turn just played, derives the new turn state (L, RF, PR) and its sequence; ``feedback`` (RF
actions only) says encouraging/challenging feedback on the *last* outcome; ``announce`` says
"Level N"; ``speak_sequence`` speaks each letter as its own utterance; ``beep`` opens the answer
window; ``await_answer`` collects the presses; ``score`` applies equation (1); ``record`` appends
the row to turns.csv (fsynced) and lets the policy observe the transition.
"""
from __future__ import annotations

import secrets
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, TextIO

import numpy as np
from transitions import Machine

from nao_trainer import __version__
from nao_trainer.session.behaviors import Behaviors, load_behaviors
from nao_trainer.session.config import DESKTOP, PROJECT_ROOT, StudyConfig
from nao_trainer.core import mdp, task
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.session.dialogue import Dialogue, load_dialogue
from nao_trainer.errors import ConfigError, Interrupted, RobotUnavailable, UserError
from nao_trainer.files import write_text_atomic
from nao_trainer.ports import (Answer, AnswerSource, EngagementMonitor, NullMonitor, PhaseEngagement, Policy, Robot,
                    RobotConnectionLost, Transition, TurnContext)
from nao_trainer.session.record import SessionRecorder, ensure_output_dir, now_iso, versions

# ----------------------------------------------------------------------------------------------
# The state machine, as data
# ----------------------------------------------------------------------------------------------

TURN_STATES = ("select_action", "feedback", "announce", "speak_sequence", "beep", "await_answer", "score", "record")
INTRO_STATES = ("greet", "instructions", "practice")
ACTIVE_STATES = INTRO_STATES + TURN_STATES + ("goodbye",)
STATES: list[str] = [*ACTIVE_STATES, "paused", "aborted", "done"]
TRANSITIONS: list[dict[str, Any]] = [
    {"trigger": "explain", "source": "greet", "dest": "instructions"},
    {"trigger": "practise", "source": "instructions", "dest": "practice"},
    {"trigger": "begin_turns", "source": ["instructions", "practice"], "dest": "select_action"},
    {"trigger": "give_feedback", "source": "select_action", "dest": "feedback"},
    {"trigger": "announce_level", "source": ["select_action", "feedback"], "dest": "announce"},
    {"trigger": "speak", "source": "announce", "dest": "speak_sequence"},
    {"trigger": "sound_beep", "source": "speak_sequence", "dest": "beep"},
    {"trigger": "wait_answer", "source": "beep", "dest": "await_answer"},
    {"trigger": "score_answer", "source": "await_answer", "dest": "score"},
    {"trigger": "record_turn", "source": "score", "dest": "record"},
    {"trigger": "next_turn", "source": "record", "dest": "select_action"},
    {"trigger": "finish_turns", "source": "record", "dest": "goodbye"},
    {"trigger": "end", "source": "goodbye", "dest": "done"},
    {"trigger": "robot_lost", "source": list(ACTIVE_STATES), "dest": "paused"},
    {"trigger": "resume_intro", "source": "paused", "dest": "instructions"},
    {"trigger": "resume_turn", "source": "paused", "dest": "select_action"},
    {"trigger": "resume_goodbye", "source": "paused", "dest": "goodbye"},
    {"trigger": "give_up", "source": "paused", "dest": "aborted"},
    {"trigger": "abort", "source": [*ACTIVE_STATES, "paused"], "dest": "aborted"},
]
FINAL_STATES = ("done", "aborted")
DIAGRAM_PATH = PROJECT_ROOT / "docs" / "session-states.md"

EXIT_OK, EXIT_ROBOT_LOST, EXIT_INTERRUPTED = 0, RobotUnavailable.exit_code, Interrupted.exit_code


def diagram_markdown() -> str:
    """The state diagram as a Markdown page with a Mermaid block (no graphviz needed)."""
    from transitions.extensions import GraphMachine

    class _Model:
        pass

    model = _Model()
    GraphMachine(model=model, states=STATES, transitions=TRANSITIONS, initial="greet", auto_transitions=False,
                 graph_engine="mermaid", title="nao-trainer session")
    # Keep the plain diagram: drop transitions' title front matter and colour classes (the
    # "active state" colouring means nothing in a document).
    lines = model.get_graph().source.strip().splitlines()
    body = lines[lines.index("stateDiagram-v2"):]
    source = "\n".join(ln for ln in body if ln.strip() and not ln.strip().startswith(("classDef", "Class ")))
    return (
        "# Session states\n\n"
        "Generated from `nao_trainer.session.engine.STATES` / `TRANSITIONS` by `nao_trainer.session.engine.export_diagram()`;\n"
        "a test fails when this file is out of date. See docs/session.md for what each state does.\n\n"
        f"```mermaid\n{source}\n```\n"
    )


def export_diagram(path: Path = DIAGRAM_PATH) -> Path:
    """Write the state diagram (``docs/session-states.md``)."""
    path.write_text(diagram_markdown(), encoding="utf-8")
    return path


# ----------------------------------------------------------------------------------------------
# Turn bookkeeping
# ----------------------------------------------------------------------------------------------


@dataclass
class Turn:
    """A turn in flight (or just played)."""

    number: int
    previous_state: int  # the MDP state the action was chosen in (START for the first turn)
    action: int
    state: int  # this turn's state (L, RF, PR)
    sequence: tuple[str, ...] = ()
    start_time: str = ""
    answer: Answer | None = None
    listening: PhaseEngagement | None = None
    answering: PhaseEngagement | None = None
    success: bool | None = None
    notes: list[str] = field(default_factory=list)
    recorded: bool = False

    @property
    def turn_state(self) -> mdp.State:
        return mdp.decode(self.state)


@dataclass
class SessionResult:
    """What a finished (or ended) session returns to the caller."""

    path: Path | None
    status: str  # completed | robot lost | interrupted | error
    exit_code: int
    rows: list[dict[str, Any]]
    seed: int
    error: str = ""

    @property
    def completed_rows(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["success"] in (True, False)]

    @property
    def total_score(self) -> int:
        return int(sum(r["score"] for r in self.completed_rows))

    def level_table(self) -> list[tuple[int, int, float | None]]:
        """(level, turns played, success rate) per level."""
        out = []
        for level in task.LEVELS:
            rows = [r for r in self.completed_rows if r["level"] == level]
            rate = sum(bool(r["success"]) for r in rows) / len(rows) if rows else None
            out.append((level, len(rows), rate))
        return out

    @property
    def mean_engagement(self) -> float | None:
        values = [r["engagement"] for r in self.completed_rows if r["engagement"] is not None]
        return float(np.mean(values)) if values else None

    def summary(self) -> str:
        """A plain-text summary table for the terminal."""
        lines = ["", "level  played  success rate"]
        for level, n, rate in self.level_table():
            lines.append(f"  {level}    {n:5d}    {'-' if rate is None else f'{rate:6.0%}'}")
        eng = self.mean_engagement
        lines += [
            f"turns completed: {len(self.completed_rows)}   total score: {self.total_score}   "
            f"mean engagement: {'n/a (EEG off)' if eng is None else f'{eng:.2f}'}",
            f"status: {self.status} (exit {self.exit_code})" + (f": {self.error}" if self.error else ""),
            f"session folder: {self.path if self.path else '(none written)'}",
        ]
        return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# The session
# ----------------------------------------------------------------------------------------------


class Session:
    """One training session: owns the machine and talks to the world only through the ports.

    Build it connected (``run_session`` does the wiring); ``run()`` plays it to the end and
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
        self.dialogue = dialogue
        self.behaviors = behaviors
        self.rng = rng
        self.policy_rng = policy_rng
        self.monitor = monitor or NullMonitor()
        self.progress = progress
        self._sleep = sleep
        t = config["timing"]
        self.speed = float(t["speed"])
        self.n_turns = int(config.get("session.turns"))
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
        self.rec.event("session_start", turns=self.n_turns, policy=getattr(self.policy, "name", "?"))
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
                self._interrupted_by_operator(_who(exc))
                break
            except RuntimeError as exc:  # the robot refused a call the task needs (speech, beep)
                self._robot_failed(exc)
                break
            self.trigger(trigger)
        return self._exit_code()

    def _exit_code(self) -> int:
        if self.state == "done":
            self.status = "completed"
            return EXIT_OK
        return EXIT_INTERRUPTED if self.status == "interrupted" else EXIT_ROBOT_LOST

    def _interrupted_by_operator(self, by: str = "operator (Ctrl-C)") -> None:
        self.status = "interrupted"
        self.rec.event("interrupted", state=self.state, by=by)
        try:  # the robot may be mid-sentence: silence it before the goodbye and the safe posture
            self.robot.stop_all()
        except (RuntimeError, RobotConnectionLost) as exc:
            self.rec.event("robot_call_failed", what="stop speech", error=str(exc))
        if self.turn is not None and not self.turn.recorded:
            self._abandon_turn(f"interrupted: {by}")
        if self.state not in FINAL_STATES:
            self.trigger("abort")

    def _robot_failed(self, exc: RuntimeError) -> None:
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

    # -- helpers ---------------------------------------------------------------------------------

    def _wait(self, session_seconds: float) -> None:
        if session_seconds > 0:
            self._sleep(session_seconds / self.speed)

    def _optional(self, what: str, call: Callable[[], Any]) -> None:
        """Eye colours and postures dress the session up: a robot that refuses one is logged, not fatal.

        A lost connection still propagates (``RobotConnectionLost`` is no ``RuntimeError``).
        """
        try:
            call()
        except RuntimeError as exc:
            self.rec.event("robot_call_failed", what=what, error=str(exc))

    def _leds(self, rgb: int) -> None:
        self._optional("leds", lambda: self.robot.set_eye_leds(rgb, self.behaviors.led_fade_s / self.speed))

    def _posture(self, name: str) -> None:
        self._optional(f"posture {name}", lambda: self.robot.go_to_posture(name, self.cfg.get("robot.posture_speed")))

    def _look(self, event: str) -> bool:
        """Set the eye colour of ``event``; returns whether speech should be animated."""
        b = self.behaviors[event]
        self._leds(b.leds)
        return b.animated

    def _say(self, event: str, behavior: str | None = None, **fields: Any) -> str:
        b = self.behaviors[behavior or event]
        self._leds(b.leds)
        text = self.dialogue.say(event, self.rng, **fields)
        self.robot.say(text, b.animated, b.mode)
        self.rec.event("say", what=event, text=text)
        return text

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

    def _speak_letters(self, sequence: tuple[str, ...]) -> None:
        """Each letter as its own utterance, separated by the configured gap."""
        self._look("sequence")
        for i, letter in enumerate(sequence):
            if i:
                self._wait(self.cfg.get("timing.letter_gap_s"))
            self.robot.say(letter, False, "disabled")

    def _beep(self, turn: int) -> float:
        """Open the answer window and beep; returns the beep onset (time 0 of the answer)."""
        t = self.cfg["timing"]
        self._look("answer")
        self.answers.open_window()
        onset = time.monotonic()
        self.robot.beep(t["beep_hz"], t["beep_s"] / self.speed, t["beep_gain"])
        self.rec.event("beep", turn=turn)
        return onset

    def _collect(self, turn: int, length: int, onset: float) -> Answer:
        """Close the listening phase at beep + tail (EEG), then wait for the answer."""
        if self._phase == "listening":
            remaining = onset + self.cfg.get("timing.listening_tail_s") / self.speed - time.monotonic()
            if remaining > 0:
                self._sleep(remaining)
            assert self.turn is not None
            self.turn.listening = self._end_phase()
            self._begin_phase("answer", turn)
        # The window opened at the beep; the timeout counts from there (sources measure from open_window).
        answer = self.answers.collect(length, self.cfg.response_timeout_s(length) / self.speed)
        self._check_robot()
        return answer

    def _check_robot(self) -> None:
        """An answer window does not talk to the robot: ask whether it is still there."""
        if not self.robot.is_connected():
            raise RobotConnectionLost("the robot dropped during the answer window")

    # -- intro -----------------------------------------------------------------------------------

    def _do_greet(self) -> str:
        self._begin_phase("baseline", None)
        self._posture(self.behaviors.start_posture)
        self._say("greeting", pseudonym=self.cfg.get("participant.pseudonym"))
        return "explain"

    def _do_instructions(self) -> str:
        if self._phase is None:
            self._begin_phase("baseline", None)
        self._say("instructions", turns=self.n_turns)
        self._end_phase()
        return "practise" if self.cfg.get("session.practice") else "begin_turns"

    def _do_practice(self) -> str:
        self._say("practice_intro", behavior="practice")
        length = task.LENGTHS[0]
        state = mdp.encode(length, 0, 0)
        context = TurnContext(0, state, length, task.generate_sequence(self.rng, length))
        self.answers.prepare(context)
        self._wait(self.cfg.get("timing.pause_before_level_s"))
        self.robot.say(self.dialogue.say("level", self.rng, level=1, length=length), False, "disabled")
        self._speak_letters(context.sequence)
        answer = self._collect(0, length, self._beep(0))
        ok = not answer.timed_out and task.is_correct(context.sequence, answer.response)
        self.rec.event("practice", sequence="".join(context.sequence), response="".join(answer.response), success=ok)
        self._say("practice_success" if ok else "practice_failure", behavior="practice")
        return "begin_turns"

    # -- a turn ----------------------------------------------------------------------------------

    def _do_select_action(self) -> str:
        if self.replay is not None:
            turn, self.replay = self.replay, None
            turn = Turn(turn.number, turn.previous_state, turn.action, turn.state, notes=["replay of interrupted turn"])
        else:
            action = int(self.policy.act(self.mdp_state, self.policy_rng))
            if not (0 <= action < mdp.N_ACTIONS and mdp.ACTION_MASK[self.mdp_state, action]):
                raise ValueError(f"policy {getattr(self.policy, 'name', '?')} chose action {action!r}, "
                                 f"not allowed in state {mdp.state_label(self.mdp_state)}")
            if self.mdp_state == mdp.START:
                state = int(mdp.NEXT_STATE[mdp.START, action, 0])
            else:
                state = mdp.next_state(self.mdp_state, action, bool(self.last_success))
            turn = Turn(self.completed + 1, self.mdp_state, action, state)
        st = turn.turn_state
        turn.sequence = task.generate_sequence(self.rng, st.length)
        turn.start_time = now_iso()
        self.turn = turn
        self.answers.prepare(TurnContext(turn.number, turn.state, st.length, turn.sequence))
        plan = getattr(self.answers, "plan", None)  # a simulated participant says what it intends
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
        kind = self.turn.turn_state.feedback
        style = "encouraging" if kind == 1 else "challenging"
        b = self.behaviors[style]
        self._leds(b.leds)
        text = self.dialogue.feedback(kind, bool(self.last_success), self.rng, level=self.turn.turn_state.level)
        self.robot.say(text, b.animated, b.mode)
        self.rec.event("say", what=f"{style}_{'success' if self.last_success else 'failure'}", text=text,
                       turn=self.turn.number)
        return "announce_level"

    def _do_announce(self) -> str:
        assert self.turn is not None
        st = self.turn.turn_state
        self._wait(self.cfg.get("timing.pause_before_level_s"))
        self._look("level")
        self.robot.say(self.dialogue.say("level", self.rng, level=st.level, length=st.length), False, "disabled")
        return "speak"

    def _do_speak_sequence(self) -> str:
        assert self.turn is not None
        self._speak_letters(self.turn.sequence)
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
        answer, n = turn.answer, len(turn.sequence)
        invalid = [p.key for p in answer.presses if p.letter is None]
        if not answer.presses:
            turn.notes.append("timeout: no answer")
        elif answer.timed_out:
            turn.notes.append(f"timeout: {len(answer.presses)} of {n} presses")
        elif len(answer.presses) > n:
            turn.notes.append(f"too many presses: {len(answer.presses)} of {n}")
        turn.notes += [f"invalid key {k!r}" for k in invalid]
        turn.success = (not answer.timed_out and len(answer.presses) == n and not invalid
                        and task.is_correct(turn.sequence, answer.response))
        return "record_turn"

    def _do_record(self) -> str:
        turn = self.turn
        assert turn is not None and turn.success is not None
        st = turn.turn_state
        score = task.score(st.level, turn.success)
        row = self._row(turn, score=score, signed=task.signed_score(st.level, turn.success))
        self.rec.turn(row)
        turn.recorded = True
        self.rows.append(row)
        self.completed += 1
        self.total += score
        done = self.completed >= self.n_turns
        engagement = turn.listening.engagement if turn.listening else None
        self.policy.observe(Transition(turn.previous_state, turn.action, score, engagement, turn.state, done))
        self.mdp_state, self.last_success = turn.state, turn.success
        self.rec.event("turn_end", turn=turn.number, success=turn.success, score=score, total=self.total)
        self.monitor.mark("turn_end", turn.number)
        self._progress(row)
        return "finish_turns" if done else "next_turn"

    def _row(self, turn: Turn, score: int | None, signed: int | None) -> dict[str, Any]:
        st = turn.turn_state
        a, sp = turn.answer, self.speed
        lis, ans = turn.listening, turn.answering
        return {
            "turn": turn.number, "start_time": turn.start_time, "state": turn.state, "length": st.length,
            "level": st.level, "feedback": st.feedback, "previous_score": st.previous,
            "action": mdp.ACTION_NAMES[turn.action], "sequence": "".join(turn.sequence),
            "response": "".join(a.response) if a else "", "success": turn.success, "score": score,
            "signed_score": signed,
            "reaction_time": round(a.reaction_time * sp, 3) if a and a.reaction_time is not None else None,
            "completion_time": round(a.completion_time * sp, 3) if a and a.completion_time is not None else None,
            "engagement": _round(lis.engagement if lis else None),
            "engagement_index": _round(lis.index if lis else None),
            "eeg_quality": None if isinstance(self.monitor, NullMonitor) else _round(lis.quality if lis else None),
            "answer_engagement": _round(ans.engagement if ans else None),
            "engagement_note": (lis.reason if lis.engagement is None else "") if lis
            else ("" if turn.success is None else "no listening phase"),
            "notes": "; ".join(turn.notes),
        }

    def _progress(self, row: dict[str, Any]) -> None:
        if self.progress is None:
            return
        fb = {0: "   ", 1: "enc", 2: "chl"}[row["feedback"]]
        eng = "-" if row["engagement"] is None else f"{row['engagement']:.2f}"
        mark = "ok " if row["success"] else "err"
        print(f"turn {row['turn']:3d}/{self.n_turns}  L{row['level']} {fb}  {row['sequence']:>9} vs "
              f"{row['response']:<9} {mark} {row['score']:+d}  total {self.total:4d}  E {eng}"
              + (f"  ({row['notes']})" if row["notes"] else ""), file=self.progress, flush=True)

    def _abandon_turn(self, why: str) -> None:
        """Record the turn in flight as interrupted (never silently lost)."""
        turn = self.turn
        assert turn is not None
        self._end_phase()
        self.answers.abandon()
        turn.notes.append(why)
        turn.success = None
        row = self._row(turn, score=None, signed=None)
        self.rec.turn(row)
        turn.recorded = True
        self.rows.append(row)
        self.rec.event("turn_interrupted", turn=turn.number, reason=why)
        if self.progress is not None:
            print(f"turn {turn.number:3d}/{self.n_turns}  {why}", file=self.progress, flush=True)

    # -- goodbye ---------------------------------------------------------------------------------

    def _do_goodbye(self) -> str:
        self._say(self.dialogue.goodbye_event(self.total), behavior="goodbye", total=self.total, turns=self.completed)
        self._posture(self.behaviors.end_posture)
        self._leds(self.behaviors.leds_reset)
        self.monitor.mark("session_end")
        return "end"

    # -- robot lost --------------------------------------------------------------------------------

    def _do_paused(self) -> str:
        lost_in = self.lost_in or "select_action"
        self._end_phase()
        if self.turn is not None and not self.turn.recorded and lost_in in TURN_STATES:
            self._abandon_turn(f"interrupted: robot lost during {lost_in}")
            self.replay = self.turn
        if self.progress is not None:
            print(f"robot lost during {lost_in}: paused, reconnecting...", file=self.progress, flush=True)
        if not self._reconnect():
            self.status = "robot lost"
            self.rec.event("give_up", after_s=self.cfg.get("robot.max_reconnect_s"))
            if self.progress is not None:
                print(f"robot not back within {self.cfg.get('robot.max_reconnect_s'):g} s: ending the session",
                      file=self.progress, flush=True)
            return "give_up"
        if lost_in in INTRO_STATES:
            return "resume_intro"
        if lost_in == "goodbye":
            return "resume_goodbye"
        return "resume_turn"

    def _reconnect(self) -> bool:
        """Reconnect with exponential backoff until ``robot.max_reconnect_s`` (the robot re-subscribes the buttons)."""
        r = self.cfg["robot"]
        deadline = time.monotonic() + r["max_reconnect_s"]
        backoff, attempt = r["backoff_initial_s"], 0
        while (remaining := deadline - time.monotonic()) > 0:
            self._sleep(min(backoff, remaining))
            attempt += 1
            try:
                self.robot.reconnect(max(0.5, min(r["connect_deadline_s"], deadline - time.monotonic())))
                self.rec.event("reconnected", attempt=attempt)
                if self.progress is not None:
                    print(f"robot back after {attempt} attempt(s): resuming", file=self.progress, flush=True)
                self._say("resumed", behavior="greeting")
                return True
            except (RobotUnavailable, RobotConnectionLost, RuntimeError) as exc:
                self.rec.event("reconnect_failed", attempt=attempt, error=str(exc), next_wait_s=min(backoff * 2, r["backoff_max_s"]))
                backoff = min(backoff * 2, r["backoff_max_s"])
        return False

    # -- shutdown --------------------------------------------------------------------------------

    def leave_safe(self) -> None:
        """Safe posture and LEDs reset, whatever happened; failures are logged, never raised."""
        leave_robot_safe(self.robot, self.behaviors, self.cfg.get("robot.posture_speed"), self.rec)


def leave_robot_safe(robot: Robot, behaviors: Behaviors, posture_speed: float,
                     recorder: SessionRecorder | None = None) -> None:
    """Safe posture and LEDs reset, whatever happened; failures are logged to ``recorder``, never raised."""
    def log(name: str, **data: Any) -> None:
        if recorder is not None:
            recorder.event(name, **data)

    if not robot.is_connected():
        log("safe_state_skipped", why="robot not connected")
        return
    for what, call in (
        ("posture", lambda: robot.go_to_posture(behaviors.safe_posture, posture_speed)),
        ("leds", lambda: robot.set_eye_leds(behaviors.leds_reset, 0.0)),
    ):
        try:
            call()
            log("safe_state", what=what)
        except Exception as exc:  # noqa: BLE001 - shutdown must go on (robot may be gone)
            log("safe_state_failed", what=what, error=str(exc))


def _who(exc: BaseException) -> str:
    """Who stopped the session, for the record."""
    return f"{exc} received" if isinstance(exc, Interrupted) and str(exc) else "operator (Ctrl-C)"


def _round(x: float | None, nd: int = 4) -> float | None:
    return None if x is None else round(float(x), nd)


# ----------------------------------------------------------------------------------------------
# Wiring: run_session
# ----------------------------------------------------------------------------------------------


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
    spec = config.get("participant_model.user_model")
    if spec:
        try:
            from nao_trainer.learn.artifacts import load_simulator
        except ImportError as exc:
            raise ConfigError(f"user model {spec!r}: data-driven simulators are not available in this install ({exc})") from None
        return load_simulator(spec)
    pm = config["participant_model"]
    return UserSimulator.from_level_rates("config-levels", pm["success_by_level"], pm["engagement_by_level"])


def open_engagement_monitor(config: StudyConfig, session_dir: Path, rng: np.random.Generator) -> EngagementMonitor:
    """The EEG monitor of the study's ``eeg.mode`` ("off" -> ports.NullMonitor)."""
    eeg = dict(config["eeg"])
    if eeg["mode"] == "off":
        return NullMonitor()  # without importing pylsl
    from nao_trainer.eeg.monitor import open_monitor  # sets LSL's scope before its first stream object

    return open_monitor(eeg["mode"], eeg, session_dir, rng, config.get("participant.pseudonym"))


def _configured_state_path(config: StudyConfig) -> Path | None:
    """The study's ``policy.state_path`` (a learning policy's state across sessions), or None."""
    state_path = config.get("policy.state_path")
    return Path(state_path).expanduser().resolve() if state_path else None


def run_session(config: StudyConfig, options: RunOptions = RunOptions(), progress: TextIO | None = None) -> SessionResult:
    """Connect, play and record one session as the study says; returns its result.

    Raises ``UserError`` subclasses before anything is written (invalid files, robot unreachable:
    ``RobotUnavailable``, exit code 3). Ctrl-C ends with status "interrupted" and exit code 130
    after leaving the robot safe and closing the files.
    """
    progress = None if options.quiet else (progress or sys.stderr)
    dialogue = load_dialogue(config.path("session.dialogue"))
    if dialogue.language != config.get("session.language"):
        raise ConfigError(f"{dialogue.source}: dialogue language {dialogue.language!r} differs from session.language "
                          f"{config.get('session.language')!r}; point session.dialogue at a {config.get('session.language')} file")
    behaviors = load_behaviors(config.path("session.behaviors"))
    seed = config.get("session.seed")
    seed = int(seed) if seed is not None else secrets.randbelow(2**31)
    simulator = build_simulator(config) if config.get("answers.input") == "simulated" else None
    from nao_trainer.session.policies import make_policy

    # Loaded once, before the robot moves: a missing or stale policy, or a torn/foreign learning-state
    # file, is found here. Without policy.state_path a learning policy saves into the session folder,
    # which gets its path once the folder exists (_run_wired).
    policy = make_policy(config.get("policy.kind"), config.get("policy.schedule"), bool(config.get("policy.learning")),
                         _configured_state_path(config))
    # Not closed on failure here: closing a learning policy saves it, and nothing is written before the robot answers.
    ensure_output_dir(config.output_dir())  # an unusable output folder is found before the robot moves

    with _signals_as_interrupt():
        return _run_wired(config, progress, dialogue, behaviors, seed, simulator, policy)


def _run_wired(config: StudyConfig, progress: TextIO | None, dialogue: Dialogue,
               behaviors: Behaviors, seed: int, simulator: UserSimulator | None, policy: Policy) -> SessionResult:
    """``run_session`` once the files and the policy are loaded: connect, wire the ports, play, clean up."""
    from nao_trainer.robot.naoqi import NaoqiRobot, redact_url

    session_ss, policy_ss, participant_ss, eeg_ss = np.random.SeedSequence(seed).spawn(4)
    input_kind = config.get("answers.input")
    speed = float(config.get("timing.speed"))
    url = config.get("robot.url")
    standin = robot = recorder = monitor = answers = buttons = None
    policy_to_close: Policy | None = None  # closed (and a learning policy saved) only once the folder exists
    session: Session | None = None
    status, code, error = "error", 1, ""
    try:
        if url == "mock":
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
            robot = NaoqiRobot.connect(connect_url, float(config.get("robot.connect_deadline_s")), None,
                                       debounce_s=float(config.get("answers.debounce_s")) / speed)
        # Only now that the robot answered does anything get written.
        recorder = SessionRecorder(config.output_dir(), config.get("participant.pseudonym"))
        path = recorder.open({
            "nao_trainer": __version__, "versions": versions(), "seed": seed,
            "robot": "stand-in (in-process)" if standin else repr(robot) if url == DESKTOP else redact_url(url),
            "input": input_kind, "policy": config.get("policy.kind"),
            "user_model": simulator.name if simulator else None,
            "config": config.snapshot(), "argv": sys.argv[1:],
        })
        if progress:
            print(f"session folder: {path}", file=progress, flush=True)
        if url == DESKTOP:
            robot.record_audio_to(path / "audio")
        monitor = open_engagement_monitor(config, path, np.random.default_rng(eeg_ss))
        answers, buttons = _make_answers(config, robot, standin, connect_url, simulator, monitor,
                                         np.random.default_rng(participant_ss), progress)
        policy_rng = np.random.default_rng(policy_ss)
        if getattr(policy, "learning", False) and getattr(policy, "state_path", "") is None:
            policy.state_path = path / "policy_state.json"
        policy_to_close = policy
        session = Session(config, robot, answers, policy, recorder, dialogue, behaviors, np.random.default_rng(session_ss),
                          policy_rng, monitor, progress)
        try:
            code = session.run()
        except (KeyboardInterrupt, Interrupted) as exc:
            session._interrupted_by_operator(_who(exc))
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
                leave_robot_safe(robot, behaviors, config.get("robot.posture_speed"), recorder)
            for closer in (answers, policy_to_close, monitor, buttons):
                _close_quietly(closer, recorder)
            if robot is not None:
                _close_quietly(robot, recorder)
            if recorder is not None and recorder.is_open:
                if standin is not None:
                    _write_transcript(recorder.path, standin.transcript())
                recorder.close(status, code, total_score=session.total if session else 0, error=error)
            if standin is not None:
                standin.stop()
    return SessionResult(recorder.path if recorder else None, status, code, session.rows if session else [], seed, error)


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

    speed = float(config.get("timing.speed"))
    debounce, grace = config.get("answers.debounce_s") / speed, config.get("timing.grace_s") / speed
    kind = config.get("answers.input")
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
                                min_gap_s=max(0.3, 4 * config.get("answers.debounce_s"))), buttons


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
    import json

    if path is None:
        return
    write_text_atomic(path / "robot_transcript.jsonl", "".join(json.dumps(entry, default=str) + "\n" for entry in transcript))
