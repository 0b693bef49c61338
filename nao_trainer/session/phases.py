"""EEG phases and the answer window of the session.

The monitor records engagement per phase: ``baseline`` (greeting and instructions), ``listening``
(from the turn's start to beep + ``timing.listening_tail_s``) and ``answer`` (to the score). A phase
starts and ends with a marker in the EEG recording. ``PhaseClock`` is a part of
``session.engine.Session``, built with only the ports it touches.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable

from nao_trainer.ports import (Answer, AnswerSource, CommandQueue, EngagementMonitor, PhaseEngagement, Robot, RobotConnectionLost,
                               watch_link)
from nao_trainer.session.config import TimingSection
from nao_trainer.session.record import SessionRecorder
from nao_trainer.session.reporting import SessionLog
from nao_trainer.session.stage import Clock, Stage

#: While a turn waits for a lost EEG stream: how often (wall seconds) it looks at the operator's commands, and the
#: commands that end the wait (they then act as soon as the turn is recorded).
WAIT_POLL_S = 0.2
ENDS_A_WAIT = ("pause", "stop")


class PhaseClock:
    """Begin and end EEG phases; open the answer window and collect the answer."""

    def __init__(self, monitor: EngagementMonitor, stage: Stage, answers: AnswerSource, robot: Robot, clock: Clock,
                 timing: TimingSection, recorder: SessionRecorder, log: SessionLog, missing_alert_turns: int = 3,
                 eeg: Any = None) -> None:
        self.monitor = monitor
        self.stage = stage
        self.answers = answers
        self.robot = robot
        self.clock = clock
        self.timing = timing
        self.rec = recorder
        self.log = log
        self.missing_alert_turns = missing_alert_turns  # 0: never tell
        self.phase: str | None = None  # the EEG phase in progress
        self.onset_shift = 0.0  # beep onset minus the answer window's opening (wall seconds)
        self.missing = 0  # turns in a row without an engagement value while EEG is on
        self.eeg = eeg  # the study's EEGSettings (turn_requires_eeg, reconnect_wait_s), None in some tests
        self.waited_in_vain = False  # a lost stream did not return within reconnect_wait_s: no more waits until it does
        self.commands: CommandQueue | None = None  # the operator's commands, looked at while waiting for a lost stream
        self.cut_short = ""  # the command that ended the last wait for the stream

    def begin(self, phase: str, turn: int | None) -> None:
        """Start ``phase`` (ending the one in progress) with a marker in the recording."""
        if self.phase is not None:
            self.end(turn)
        self.monitor.begin_phase(phase, turn)
        self.monitor.mark(f"{phase}_start", turn)
        self.phase = phase

    def end(self, turn: int | None) -> PhaseEngagement | None:
        """End the phase in progress (None when there is none); ``turn`` numbers its end marker."""
        if self.phase is None:
            return None
        self.monitor.mark(f"{self.phase}_end", turn)
        self.phase = None
        return self.monitor.end_phase()

    def beep(self, turn: int) -> float:
        """Open the answer window and beep; returns the beep onset (time 0 of the answer).

        Answer sources time presses from ``open_window``, made just before the beep call; the
        press times are later shifted by ``onset_shift``, so reaction times count from the onset.
        """
        self.stage.look("answer")
        opened = self.clock.now()
        self.answers.open_window()
        onset = self.stage.beep(turn)
        self.onset_shift = max(0.0, onset - opened)
        return onset

    def collect(self, turn: int, presses: int, timeout_s: float, onset: float) -> tuple[Answer, PhaseEngagement | None]:
        """Close the listening phase at beep + tail (EEG), then wait for the answer.

        ``presses`` end the window early; ``timeout_s`` (session seconds) is the task's answer window.
        Returns the answer and the listening phase's engagement (None when no listening phase ran).
        """
        listening = None
        if self.phase == "listening":
            self.clock.wait_until(onset + self.clock.wall(self.timing.listening_tail_s))
            listening = self.end(turn)
            self.begin("answer", turn)
        # The window opened at the beep; the timeout counts from there (sources measure from open_window).
        # Nothing else talks to the robot meanwhile: a watchdog does (a frozen link goes unnoticed ~60 s).
        with watch_link(self.robot) as link:
            answer = self.answers.collect(presses, self.clock.wall(timeout_s))
        if self.onset_shift:
            answer = Answer(tuple(replace(p, t=p.t - self.onset_shift) for p in answer.presses), answer.timed_out)
        self.rec.event("answer", turn=turn, timed_out=answer.timed_out,  # each press, seconds from the beep
                       presses=[{"key": p.key, "letter": p.letter, "t": round(self.clock.session(p.t), 3)}
                                for p in answer.presses])
        if link.lost is not None:
            self.rec.event("link_frozen", turn=turn, error=link.lost)
            raise RobotConnectionLost(f"the link to the robot froze during the answer window ({link.lost})")
        if not self.robot.is_connected():  # an answer window does not talk to the robot: ask
            raise RobotConnectionLost("the robot dropped during the answer window")
        return answer, listening

    def note_signal(self, turn: int, listening: PhaseEngagement | None) -> None:
        """After a recorded turn: count the turns in a row without EEG; at ``eeg.missing_alert_turns`` tell
        the operator once (terminal line, console event, events.jsonl) so a lost headband is not found at the end."""
        if not self.monitor.records_eeg:
            return
        if listening is not None and listening.engagement is not None:
            if self.missing >= self.missing_alert_turns > 0:
                self.rec.event("eeg_back", turn=turn, after_turns=self.missing)
                self.log.observer.notify("eeg", {"missing_turns": 0, "turn": turn})
            self.missing = 0
            return
        self.missing += 1
        if self.missing == self.missing_alert_turns:
            reason = (listening.reason if listening is not None else "") or "no value"
            self.rec.event("eeg_missing", turn=turn, turns=self.missing, reason=reason)
            self.log.observer.notify("eeg", {"missing_turns": self.missing, "turn": turn, "reason": reason})
            self.log.say(f"warning: no EEG for the last {self.missing} turns ({reason}): check the headband and its stream")

    def lost_eeg(self, turn: int, listening: PhaseEngagement | None, answering: PhaseEngagement | None,
                 replayed: bool, notes: list[str]) -> str:
        """After the answer: did the turn lose EEG (the headband's stream stopped) in its listening or its answer
        phase, and is the turn to be played again? Returns the phase to name when it is ("listening" or
        "answer"), else "".

        A loss is flagged in the turn's notes and in events.jsonl, per phase. With ``eeg.turn_requires_eeg``
        the turn is played again once (not a replay), as after a lost robot link, when the stream is back: this
        waits up to ``eeg.reconnect_wait_s`` for it (the monitor reconnects in the background). A stream that
        does not return is not waited for again until it does; the turn is then recorded, flagged."""
        tolerance = 0.1 if self.eeg is None else self.eeg.processing.gap_tolerance_s
        if not self.monitor.records_eeg:
            return ""
        hit = ""
        for name, phase in (("listening", listening), ("answer", answering)):
            lost = 0.0 if phase is None else phase.lost_s
            if lost <= tolerance:  # a stamp jump this small is no gap in the data
                continue
            hit = hit or name
            notes.append(f"EEG lost {lost:.1f} s in the {name} phase")
            self.rec.event("eeg_lost_in_turn", turn=turn, lost_s=round(lost, 3), phase=name, replay=replayed)
        if not hit or self.eeg is None or not self.eeg.turn_requires_eeg or replayed:
            return ""
        wait = getattr(self.monitor, "wait_available", None)
        if wait is None:
            return ""
        back = getattr(self.monitor, "available", True)
        if not back and not self.waited_in_vain:
            self.log.say(f"turn {turn}: EEG lost; waiting up to {self.eeg.reconnect_wait_s:g} s for the headband's stream")
            back = self._wait_for_stream(wait, turn)
            self.waited_in_vain = not back and not self.cut_short
            if self.cut_short:
                self.rec.event("eeg_wait_cut_short", turn=turn, by=self.cut_short)
                notes.append(f"not replayed: the operator's {self.cut_short} ended the wait for the EEG stream")
                self.cut_short = ""
                return ""
            if not back:
                self.rec.event("eeg_not_back", turn=turn, waited_s=self.eeg.reconnect_wait_s)
                self.log.say(f"warning: the EEG stream is not back after {self.eeg.reconnect_wait_s:g} s; going on "
                             "without it (turns flagged; check the headband)")
        elif back:
            self.waited_in_vain = False
        if not back:
            notes.append(f"not replayed: the EEG stream was not back within {self.eeg.reconnect_wait_s:g} s")
            return ""
        self.monitor.mark("eeg_turn_replay", turn)
        return hit

    def _wait_for_stream(self, wait: Callable[[float], bool], turn: int) -> bool:
        """Wait up to ``eeg.reconnect_wait_s`` for the lost stream, looking at the operator's commands every
        ``WAIT_POLL_S``: a pause or stop ends the wait at once (``cut_short`` names it; the turn is then recorded,
        flagged, and the command acts as soon as it is)."""
        assert self.eeg is not None
        self.log.observer.notify("eeg_wait", {"waiting_s": self.eeg.reconnect_wait_s, "turn": turn})
        deadline = self.clock.now() + self.eeg.reconnect_wait_s
        while (remaining := deadline - self.clock.now()) > 0:
            if wait(min(WAIT_POLL_S, remaining)):
                return True
            asked = [k for k in (self.commands.kinds() if self.commands is not None else []) if k in ENDS_A_WAIT]
            if asked:
                self.cut_short = asked[0]
                return False
        return False
