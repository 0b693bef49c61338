"""Operator commands: where a key press or the console acts on a running session.

Commands (``ports.CommandQueue``: terminal keys, the console) are drained between states and each
fires a trigger of ``session.machine.COMMAND_TRIGGERS``; a command whose trigger the current state
does not have is refused, with the reason, in ``events.jsonl``. Pause takes effect after the current
state (the robot finishes its utterance), says the pause line and waits, the EEG still recording;
resume replays the interrupted turn; stop says goodbye. ``session.max_duration_s`` is looked at at
the same points (between turns, and while paused).

``OperatorCommands`` is a part of ``session.engine.Session``: it acts on the session's state.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from nao_trainer.core import mdp
from nao_trainer.ports import Command, CommandQueue
from nao_trainer.session.machine import COMMAND_TRIGGERS, IN_TURN, INTRO_STATES

if TYPE_CHECKING:
    from nao_trainer.session.turn import Turn

#: How often (wall seconds) a paused session looks at the command queue and the clock.
PAUSE_POLL_S = 0.2
#: States where pause, stop and repeat wait for the turn to be recorded.
HOLD_STATES = ("score", "record")


class OperatorCommands:
    """Drain, check, apply and record operator commands; the ``operator_pause`` state's handler."""

    commands: CommandQueue
    _override: int | None  # the operator's choice for the next turn
    _held: list[Command]  # pause/stop/repeat that came while a turn was being scored/recorded
    _paused_in: str | None  # the state a pause interrupted
    _reason: str | None  # why the next transition happens (an operator command, the clock)
    # the session's, used here
    state: str
    turn: Turn | None
    replay: Turn | None
    status: str
    mdp_state: int
    max_duration_s: float | None
    rec: Any
    monitor: Any
    observer: Any
    stage: Any
    machine: Any

    def _init_commands(self, commands: CommandQueue | None) -> None:
        self.commands = commands if commands is not None else CommandQueue()
        self._override = None
        self._held = []
        self._paused_in = None
        self._reason = None

    def _time_up(self) -> bool:
        return self.max_duration_s is not None and self.elapsed_s() >= self.max_duration_s

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
            try:
                trigger = self._apply(cmd)
            except (ValueError, TypeError, KeyError, AttributeError, OverflowError) as exc:
                # issue 18: a malformed command (a program's, or one the console let through) is refused
                # and logged; it never ends the session. The console checks arguments on arrival too.
                self._log_command(cmd, False, f"malformed arguments ignored ({type(exc).__name__}: {str(exc)[:200]})")
                continue
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
