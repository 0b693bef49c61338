"""EEG phases and the answer window of the session.

The monitor records engagement per phase: ``baseline`` (greeting and instructions), ``listening``
(from the turn's start to beep + ``timing.listening_tail_s``) and ``answer`` (to the score). A phase
starts and ends with a marker in the EEG recording. ``EEGPhases`` is a part of
``session.engine.Session``.
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

from nao_trainer.ports import Answer, PhaseEngagement, RobotConnectionLost, watch_link

if TYPE_CHECKING:
    from nao_trainer.session.turn import Turn


class EEGPhases:
    """Begin and end EEG phases; open the answer window and collect the answer."""

    _phase: str | None = None  # the EEG phase in progress
    _onset_shift: float = 0.0  # beep onset minus the answer window's opening (wall seconds)
    # the session's, used here
    turn: Turn | None
    cfg: Any
    robot: Any
    answers: Any
    monitor: Any
    stage: Any
    clock: Any
    rec: Any

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
        """Open the answer window and beep; returns the beep onset (time 0 of the answer).

        Answer sources time presses from ``open_window``, made just before the beep call; the
        press times are later shifted by ``_onset_shift``, so reaction times count from the onset.
        """
        self.stage.look("answer")
        opened = self.clock.now()
        self.answers.open_window()
        onset = self.stage.beep(turn)
        self._onset_shift = max(0.0, onset - opened)
        return onset

    def _collect(self, turn: int, length: int, onset: float) -> Answer:
        """Close the listening phase at beep + tail (EEG), then wait for the answer."""
        if self._phase == "listening":
            self.clock.wait_until(onset + self.clock.wall(self.cfg.timing.listening_tail_s))
            assert self.turn is not None
            self.turn.listening = self._end_phase()
            self._begin_phase("answer", turn)
        # The window opened at the beep; the timeout counts from there (sources measure from open_window).
        # Nothing else talks to the robot meanwhile: a watchdog does (a frozen link goes unnoticed ~60 s).
        with watch_link(self.robot) as link:
            answer = self.answers.collect(length, self.clock.wall(self.cfg.timing.response_timeout_s(length)))
        if self._onset_shift:
            answer = Answer(tuple(replace(p, t=p.t - self._onset_shift) for p in answer.presses), answer.timed_out)
        self.rec.event("answer", turn=turn, timed_out=answer.timed_out,  # each press, seconds from the beep
                       presses=[{"key": p.key, "letter": p.letter, "t": round(self.clock.session(p.t), 3)}
                                for p in answer.presses])
        if link.lost is not None:
            self.rec.event("link_frozen", turn=turn, error=link.lost)
            raise RobotConnectionLost(f"the link to the robot froze during the answer window ({link.lost})")
        if not self.robot.is_connected():  # an answer window does not talk to the robot: ask
            raise RobotConnectionLost("the robot dropped during the answer window")
        return answer
