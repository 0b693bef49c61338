"""What the session writes down and shows: turns.csv rows, transitions in ``events.jsonl``,
observer messages (the console) and progress lines.

``SessionLog`` is a part of ``session.engine.Session``: it owns the rows written so far and the
reason of the next transition (an operator command, the clock), which the transition's event carries.
"""
from __future__ import annotations

from typing import Any, TextIO

from nao_trainer.ports import Press, SessionObserver
from nao_trainer.session.record import SessionRecorder
from nao_trainer.session.stage import Clock
from nao_trainer.session.turn import Turn


class SessionLog:
    """Rows, transition events, press notices and progress lines."""

    def __init__(self, recorder: SessionRecorder, observer: SessionObserver, progress: TextIO | None,
                 clock: Clock) -> None:
        self.rec = recorder
        self.observer = observer
        self.progress = progress
        self.clock = clock
        self.rows: list[dict[str, Any]] = []
        self._reason: str | None = None

    def because(self, reason: str) -> None:
        """Why the next transition happens (its event carries it)."""
        self._reason = reason

    def transition(self, trigger: str, source: str, dest: str | None, state: str, turn: int | None,
                   elapsed_s: float) -> None:
        """A state change (``dest`` None: an internal transition, an operator command that keeps the state)."""
        reason, self._reason = self._reason, None
        extra: dict[str, Any] = {"reason": reason} if reason else {}
        if dest is None:
            dest, extra["internal"] = state, True
        self.rec.event("transition", trigger=trigger, source=source, dest=dest, turn=turn, **extra)
        self.observer.notify("state", {"state": dest, "trigger": trigger, "turn": turn,
                                       "elapsed_s": round(elapsed_s, 2), **extra})

    def press(self, press: Press, turn: int) -> None:
        """An answer source saw a press (called from its thread): tell the observer."""
        self.observer.notify("press", {"turn": turn, "key": press.key, "letter": press.letter,
                                       "t": round(self.clock.session(press.t), 3)})

    def say(self, line: str) -> None:
        """One progress line on the terminal (none when quiet)."""
        if self.progress is not None:
            print(line, file=self.progress, flush=True)

    def row(self, turn: Turn, row: dict[str, Any]) -> dict[str, Any]:
        """Append ``turn``'s row to turns.csv (fsynced) and to the rows of this run."""
        self.rec.turn(row)
        turn.recorded = True
        self.rows.append(row)
        return row

    def policy_status(self, status: dict[str, Any], turn: int) -> None:
        """What the policy says after a turn (e.g. its posterior over user models): events, console, progress."""
        if status:
            shown = {k: v for k, v in status.items() if k not in ("progress", "summary", "phase", "posterior_text")}
            self.rec.event("policy_status", turn=turn, **shown)
            # the console also gets the posterior as the terminal words it (posterior_text: "user model 3 0.86 | ...")
            words = {"posterior_text": status["posterior_text"]} if status.get("posterior_text") else {}
            self.observer.notify("policy", {"turn": turn, **shown, **words})
            if status.get("progress"):
                self.say(status["progress"])

    def time_limit(self, max_duration_s: float, elapsed_s: float) -> None:
        """``session.max_duration_s`` reached: why, the event, the operator's line."""
        self.because(f"session.max_duration_s = {max_duration_s:g} s reached")
        self.rec.event("max_duration", elapsed_s=round(elapsed_s, 2), max_duration_s=max_duration_s)
        self.say(f"maximum session duration ({max_duration_s:g} s) reached: ending the session")

    def paused(self, paused_in: str | None) -> None:
        """The operator paused the session (in state ``paused_in``): the console and the terminal."""
        self.observer.notify("pause", {"paused": True, "in": paused_in})
        self.say("paused by the operator: resume with r (or the console), stop with s")

    def resumed(self) -> None:
        """The operator resumed the session."""
        self.observer.notify("pause", {"paused": False})
        self.say("resumed by the operator")
