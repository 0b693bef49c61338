"""What the session writes down and shows: turns.csv rows (an interrupted turn too), transitions
in ``events.jsonl``, observer messages (the console) and progress lines.

``Reporting`` is a part of ``session.engine.Session``.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from nao_trainer.ports import Press

if TYPE_CHECKING:
    from nao_trainer.session.turn import Turn


class Reporting:
    """Rows, transition events, press notices and progress lines."""

    # the session's, used here
    state: str
    turn: Turn | None
    rows: list[dict[str, Any]]
    total: int
    n_turns: int
    _reason: str | None
    progress: Any
    rec: Any
    observer: Any
    monitor: Any
    answers: Any
    clock: Any

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

    def _on_press(self, press: Press) -> None:
        """An answer source saw a press (called from its thread): tell the observer."""
        self.observer.notify("press", {"turn": self.turn.number if self.turn else 0, "key": press.key,
                                       "letter": press.letter, "t": round(self.clock.session(press.t), 3)})

    def _say_progress(self, line: str) -> None:
        if self.progress is not None:
            print(line, file=self.progress, flush=True)

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
