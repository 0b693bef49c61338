"""In-memory stand-ins for the ports, so the session engine's handlers run in milliseconds.

``FakeRobot`` implements ``ports.Robot``: it records every call and can be told to lose the
connection, refuse a call or raise Ctrl-C at the n-th call of a method. ``ScriptedAnswers``
implements ``ports.AnswerSource`` and answers at once (right or wrong, as scripted). The qi
stand-in tests still cover the real adapter and the whole path.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from nao_trainer.ports import Answer, Intention, Press, RobotCallFailed, RobotConnectionLost, TurnContext


@dataclass
class Fault:
    """Raise ``error`` at the ``at``-th call (1-based) of ``method``; ``drops`` also takes the link down."""

    method: str
    at: int
    error: BaseException
    drops: bool = False


@dataclass
class FakeRobot:
    """A robot in memory: ``calls`` holds (method, args) in order."""

    reconnect_after: int = 1  # reconnect() succeeds at this attempt (0 = never)
    calls: list[tuple[str, tuple[Any, ...]]] = field(default_factory=list)
    connected: bool = True
    faults: list[Fault] = field(default_factory=list)
    reconnect_attempts: int = 0
    button_callback: Callable[[str, float], None] | None = None

    # -- scripting -------------------------------------------------------------------------------

    def lose_at(self, method: str, at: int = 1) -> None:
        self.faults.append(Fault(method, at, RobotConnectionLost(f"{method}: lost the robot (fake)"), drops=True))

    def refuse_at(self, method: str, at: int = 1, message: str = "refused (fake)") -> None:
        self.faults.append(Fault(method, at, RobotCallFailed(f"{method} failed on the robot: {message}")))

    def interrupt_at(self, method: str, at: int = 1) -> None:
        self.faults.append(Fault(method, at, KeyboardInterrupt()))

    def said(self) -> list[str]:
        return [args[0] for name, args in self.calls if name == "say"]

    def count(self, method: str) -> int:
        return sum(name == method for name, _ in self.calls)

    def _call(self, method: str, *args: Any) -> None:
        if not self.connected:
            raise RobotConnectionLost(f"{method}: not connected (fake)")
        self.calls.append((method, args))
        n = self.count(method)
        for fault in self.faults:
            if fault.method == method and fault.at == n:
                if fault.drops:
                    self.connected = False
                raise fault.error

    # -- ports.Robot -----------------------------------------------------------------------------

    def say(self, text: str, animated: bool = False, mode: str = "contextual") -> None:
        self._call("say", text, animated, mode)

    def beep(self, frequency_hz: int, duration_s: float, gain: float = 0.5) -> None:
        self._call("beep", frequency_hz, duration_s, gain)

    def set_eye_leds(self, rgb: int, duration_s: float) -> None:
        self._call("set_eye_leds", rgb, duration_s)

    def go_to_posture(self, name: str, speed: float) -> None:
        self._call("go_to_posture", name, speed)

    def stop_all(self) -> None:
        self._call("stop_all")

    def subscribe_buttons(self, callback: Callable[[str, float], None]) -> None:
        self.button_callback = callback

    def unsubscribe_buttons(self) -> None:
        self.button_callback = None

    def reconnect(self, deadline_s: float) -> None:
        self.reconnect_attempts += 1
        self.calls.append(("reconnect", (deadline_s,)))
        if self.reconnect_after and self.reconnect_attempts >= self.reconnect_after:
            self.connected = True
            return
        raise RobotConnectionLost("still gone (fake)")

    def is_connected(self) -> bool:
        return self.connected

    def close(self) -> None:
        self.connected = False


class ScriptedAnswers:
    """Answers at once: the sequence itself, or a wrong first letter for turns listed in ``wrong``.

    Press times are ``times`` (wall seconds after the window opened), so reaction times can be checked.
    """

    def __init__(self, wrong: set[int] = frozenset(), times: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9),
                 simulated: bool = False) -> None:
        self.wrong = set(wrong)
        self.times = times
        self.simulated = simulated
        self.context: TurnContext | None = None
        self.windows = 0
        self.timeouts: list[float] = []
        self.abandoned = 0
        self.closed = False
        self.watcher = None
        self.on_collect: Callable[[TurnContext], None] | None = None  # e.g. send a command mid-answer

    def watch(self, callback) -> None:
        self.watcher = callback

    def _response(self) -> tuple[str, ...]:
        assert self.context is not None
        seq = self.context.sequence
        if self.context.turn in self.wrong:
            return ({"A": "B", "B": "C", "C": "A"}[seq[0]],) + seq[1:]
        return seq

    def prepare(self, context: TurnContext) -> None:
        self.context = context

    def intended(self) -> Intention | None:
        if not self.simulated or self.context is None:
            return None
        return Intention(self.context.turn not in self.wrong, self._response(), "" if self.context.turn not in self.wrong else "swap")

    def open_window(self) -> None:
        self.windows += 1

    def collect(self, n_expected: int, timeout_s: float) -> Answer:
        if self.context is None:
            raise ValueError("collect() before prepare()")
        self.timeouts.append(timeout_s)
        if self.on_collect is not None:
            self.on_collect(self.context)
        presses = tuple(Press(key=l, letter=l, t=t) for l, t in zip(self._response(), self.times))
        for p in presses:
            if self.watcher is not None:
                self.watcher(p)
        return Answer(presses=presses, timed_out=len(presses) < n_expected)

    def abandon(self) -> None:
        self.abandoned += 1

    def close(self) -> None:
        self.closed = True
