"""Operator commands: where a key press or the console acts on a running session.

Commands (``ports.CommandQueue``: terminal keys, the console) are drained between states and each
fires a trigger of ``session.machine.COMMAND_TRIGGERS``; a command whose trigger the current state
does not have is refused, with the reason, in ``events.jsonl``. Pause takes effect after the current
state (the robot finishes its utterance), says the pause line and waits, the EEG still recording;
resume replays the interrupted turn; stop says goodbye. ``session.max_duration_s`` is looked at at
the same points (between turns, and while paused).

``OperatorDesk`` is a part of ``session.engine.Session``: it keeps the queue, the held commands, a
pending override and where a pause came from, and *decides* what a command means in a state
(``Decision``); the session carries the decision out (it owns the machine and the turn in flight).
"""
from __future__ import annotations

from dataclasses import dataclass

from nao_trainer.core import mdp
from nao_trainer.errors import Interrupted
from nao_trainer.ports import Command, CommandQueue, EngagementMonitor, SessionObserver
from nao_trainer.session.machine import COMMAND_TRIGGERS, IN_TURN, INTRO_STATES
from nao_trainer.session.record import SessionRecorder
from nao_trainer.session.reporting import SessionLog
from nao_trainer.session.turn import Turn

#: How often (wall seconds) a paused session looks at the command queue and the clock.
PAUSE_POLL_S = 0.2
#: States where pause, stop and repeat wait for the turn to be recorded.
HOLD_STATES = ("judge", "record")
#: The commands held while a turn is scored and recorded.
HELD_KINDS = ("pause", "stop", "repeat")


@dataclass(frozen=True)
class Decision:
    """What one command means in the current state. ``trigger`` None: refused (``detail`` says why)."""

    trigger: str | None
    detail: str
    by: str = ""  # the transition's reason
    internal: bool = False  # a trigger that keeps the state (override, invalid, note): fired, then logged
    abandon: bool = False  # record the turn in flight as interrupted first
    silence: bool = False  # silence the robot before that (stop)
    replay: bool = False  # play the abandoned turn again after the pause or repeat
    status: str | None = None  # the session's new status (stop)


class OperatorDesk:
    """Drain, hold, judge and record operator commands; the pending override."""

    def __init__(self, commands: CommandQueue, log: SessionLog, recorder: SessionRecorder,
                 monitor: EngagementMonitor, observer: SessionObserver) -> None:
        self.commands = commands
        self.log = log
        self.rec = recorder
        self.monitor = monitor
        self.observer = observer
        self.override: int | None = None  # the operator's choice for the next turn
        self.paused_in: str | None = None  # the state a pause interrupted
        self._held: list[Command] = []  # pause/stop/repeat that came while a turn was being scored/recorded

    def due(self, hold: bool) -> list[Command]:
        """The commands to apply now, oldest first; with ``hold`` pause, stop and repeat wait for the next point."""
        pending, self._held = self._held + self.commands.drain(), []
        if hold:
            self._held = [c for c in pending if c.kind in HELD_KINDS]
            pending = [c for c in pending if c.kind not in HELD_KINDS]
        return pending

    def take(self, kinds: tuple[str, ...]) -> list[Command]:
        """The held and queued commands of ``kinds``, oldest first, taken (the others stay)."""
        held = [c for c in self._held if c.kind in kinds]
        self._held = [c for c in self._held if c.kind not in kinds]
        return held + self.commands.take(kinds)

    def stop_waiting(self) -> bool:
        """Whether a stop is held or queued (nothing is taken)."""
        return any(c.kind == "stop" for c in self._held) or "stop" in self.commands.kinds()

    def hold(self, rest: list[Command]) -> None:
        """Commands that came after one that changed the state: they act at the next point."""
        self._held += rest

    def wait(self) -> None:
        """While paused: block until a command comes or a poll interval passed."""
        self.commands.wait(PAUSE_POLL_S)

    def decide(self, cmd: Command, state: str, triggers: set[str], turn: Turn | None) -> Decision:
        """What ``cmd`` does in ``state`` (``triggers``: the state's triggers); ``turn``: the turn in flight
        or the last one. Marks ``turn`` invalid and records the override when accepted."""
        trigger = self._allowed(cmd.kind, triggers, turn)
        if trigger is None:
            return Decision(None, f"not possible in state {state}")
        by = f"{cmd.kind} by operator ({cmd.source})"
        if cmd.kind == "override" or trigger == "repeat_last":
            name = cmd.args.get("action") if cmd.kind == "override" else mdp.ACTION_NAMES[turn.action]  # type: ignore[union-attr]
            if name not in mdp.ACTION_NAMES:
                return Decision(None, f"unknown action {name!r}; use {', '.join(mdp.ACTION_NAMES)}")
            self.override = mdp.ACTION_NAMES.index(name)
            return Decision(trigger, f"next turn plays {name}", by, internal=True)
        if cmd.kind == "invalid":
            return self._invalid(cmd, trigger, by, turn)
        if cmd.kind == "note":
            return Decision(trigger, str(cmd.args.get("text", ""))[:500], by, internal=True)
        # state changes: pause, resume, stop, repeat of the turn in flight
        in_flight = cmd.kind in HELD_KINDS and turn is not None and not turn.recorded and state in IN_TURN
        if cmd.kind == "pause":
            self.paused_in = state
        return Decision(trigger, f"{trigger} from {state}", by, abandon=in_flight,
                        silence=in_flight and cmd.kind == "stop", replay=in_flight and cmd.kind != "stop",
                        status="stopped" if cmd.kind == "stop" else None)

    def _invalid(self, cmd: Command, trigger: str, by: str, turn: Turn | None) -> Decision:
        assert turn is not None  # mark_invalid exists only while a turn is in flight (IN_TURN)
        wanted = cmd.args.get("turn")
        if wanted is not None and int(wanted) != turn.number:
            return Decision(None, f"turn {wanted} is not the turn in flight ({turn.number}); "
                                  "a recorded turn cannot be changed")
        note = str(cmd.args.get("note") or "").strip()
        turn.invalid = True
        turn.notes.append(f"invalid ({cmd.source})" + (f": {note}" if note else ""))
        return Decision(trigger, f"turn {turn.number} marked invalid", by, internal=True)

    def _allowed(self, kind: str, triggers: set[str], turn: Turn | None) -> str | None:
        """The trigger of command ``kind`` the current state has, or None."""
        for t in COMMAND_TRIGGERS[kind]:
            if t in triggers:
                if t == "repeat_last" and turn is None:
                    continue
                if t == "resume_intro" and self.paused_in not in INTRO_STATES:
                    continue
                if t == "resume_turn" and self.paused_in in INTRO_STATES:
                    continue
                return t
        return None

    def record(self, cmd: Command, accepted: bool, detail: str, state: str, turn: int | None) -> None:
        """The command in events.jsonl, a marker in the EEG recording, the console told; refusals on the terminal."""
        self.rec.event("command", kind=cmd.kind, args=cmd.args, source=cmd.source, at=cmd.at, id=cmd.id,
                       state=state, accepted=accepted, detail=detail, turn=turn)
        if accepted:
            self.monitor.mark(f"command_{cmd.kind}", turn)
        self.observer.notify("command", {"id": cmd.id, "kind": cmd.kind, "args": cmd.args, "source": cmd.source,
                                         "at": cmd.at, "state": state, "accepted": accepted, "detail": detail})
        if not accepted:
            self.log.say(f"command {cmd.kind} from {cmd.source} refused: {detail}")

    def take_override(self, mdp_state: int) -> int | None:
        """The operator's action for this turn, if one is pending and allowed here (else refused, logged)."""
        action, self.override = self.override, None
        if action is None:
            return None
        if not mdp.ACTION_MASK[mdp_state, action]:
            self.rec.event("command_refused", kind="override", action=mdp.ACTION_NAMES[action],
                           reason=f"not allowed in state {mdp.state_label(mdp_state)}")
            self.observer.notify("command", {"kind": "override", "accepted": False,
                                             "reason": f"{mdp.ACTION_NAMES[action]} not allowed before the first turn"})
            return None
        return action


def who_stopped(exc: BaseException) -> str:
    """Who stopped the session, for the record."""
    return f"{exc} received" if isinstance(exc, Interrupted) and str(exc) else "operator (Ctrl-C)"
