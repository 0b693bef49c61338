"""Answer inputs: the NAO's head buttons and a keyboard (or a USB buzzer box that types a/b/c).

Both implement ``ports.AnswerSource`` on top of one thread-safe ``PressWindow``: presses that arrive
before ``open_window`` (i.e. before the beep) are discarded, repeated presses of the same button
closer than the debounce interval count once, and ``collect`` returns after the expected number
of presses plus a short grace period (so extra presses are seen and make the answer wrong) or at
the timeout. All times are wall-clock seconds from the beep; the session rescales them when a
session runs sped up.
"""
from __future__ import annotations

import os
import select
import sys
import threading
import time
from typing import Callable, TextIO

from nao_trainer.ports import Answer, Intention, Press, Robot, TurnContext

KEY_LETTERS: dict[str, str] = {"a": "A", "b": "B", "c": "C"}


class PressWindow:
    """Collects presses of one answer window; safe to feed from other threads (qi callbacks)."""

    def __init__(self, debounce_s: float = 0.08, grace_s: float = 0.4,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.debounce_s = float(debounce_s)
        self.grace_s = float(grace_s)
        self._clock = clock
        self._cond = threading.Condition()
        self._opened_at: float | None = None
        self._presses: list[Press] = []
        self._last: dict[str, float] = {}
        self.discarded = 0  # presses outside any window (before the beep, after collect)
        self.listener: Callable[[Press], None] | None = None  # told of every accepted press

    def open(self) -> float:
        """Open the window now; press times count from here."""
        with self._cond:
            self._opened_at = self._clock()
            self._presses = []
            self._last = {}
            return self._opened_at

    def add(self, key: str, letter: str | None, t: float | None = None) -> bool:
        """Register a press at monotonic time ``t`` (now when None); False when discarded."""
        t = self._clock() if t is None else t
        with self._cond:
            if self._opened_at is None or t < self._opened_at:
                self.discarded += 1
                return False
            last = self._last.get(key)
            if last is not None and t - last < self.debounce_s:
                return False  # a bounce of the same button
            self._last[key] = t
            press = Press(key=key, letter=letter, t=t - self._opened_at)
            self._presses.append(press)
            self._cond.notify_all()
        if self.listener is not None:
            self.listener(press)
        return True

    def wait_for_press(self, n: int, timeout_s: float) -> float | None:
        """Monotonic time of the window's ``n``-th press once it has arrived; None on timeout or closed window."""
        with self._cond:
            self._cond.wait_for(lambda: self._opened_at is None or len(self._presses) >= n, timeout_s)
            if self._opened_at is None or len(self._presses) < n:
                return None
            return self._opened_at + self._presses[n - 1].t

    def collect(self, n_expected: int, timeout_s: float) -> Answer:
        """Wait for ``n_expected`` presses (+ grace) or the timeout, then close the window."""
        with self._cond:
            if self._opened_at is None:
                raise ValueError("collect() before open_window()")
            deadline = self._opened_at + timeout_s
            while True:
                now = self._clock()
                if len(self._presses) >= n_expected:
                    end = min(deadline, self._opened_at + self._presses[n_expected - 1].t + self.grace_s) \
                        if n_expected else now
                    if now >= end:
                        break
                    self._cond.wait(end - now)
                    continue
                if now >= deadline:
                    break
                self._cond.wait(deadline - now)
            presses = tuple(self._presses)
            self._opened_at = None
            self._presses = []
            self._cond.notify_all()
        return Answer(presses=presses, timed_out=len(presses) < n_expected)

    def close(self) -> None:
        with self._cond:
            self._opened_at = None
            self._cond.notify_all()


class TactileAnswers:
    """Answers from the NAO's head buttons (front/middle/rear = A/B/C), counted on the press.

    Subscribes through ``robot.subscribe_buttons``; after a reconnection the robot re-subscribes
    the same callback itself (``NaoqiRobot.reconnect``), so presses keep arriving.
    """

    def __init__(self, robot: Robot, debounce_s: float = 0.08, grace_s: float = 0.4) -> None:
        self.robot = robot
        self.window = PressWindow(debounce_s, grace_s)
        self.robot.subscribe_buttons(self._on_press)

    def _on_press(self, letter: str, t: float) -> None:
        self.window.add(key=letter, letter=letter if letter in ("A", "B", "C") else None, t=t)

    def prepare(self, context: TurnContext) -> None:
        pass

    def open_window(self) -> None:
        self.window.open()

    def collect(self, n_expected: int, timeout_s: float) -> Answer:
        return self.window.collect(n_expected, timeout_s)

    def intended(self) -> Intention | None:
        return None  # a person's answer is not known in advance

    def abandon(self) -> None:
        """The turn was interrupted after its beep: close its window, so presses until the next beep are
        discarded (the replay's speech must not collect them)."""
        self.window.close()

    def watch(self, callback: Callable[[Press], None]) -> None:
        self.window.listener = callback

    def close(self) -> None:
        self.window.close()
        try:
            self.robot.unsubscribe_buttons()
        except Exception:  # noqa: BLE001 - the robot may already be gone; closing must not fail
            pass


class KeyboardAnswers:
    """Answers typed as a/b/c on a terminal, a pipe or a USB buzzer box (which types letters).

    On a terminal the input is switched to character mode (no Enter needed) and restored by
    ``close``; elsewhere (a pipe) it reads bytes as they come. Keys pressed before the window
    opens are read and discarded; newlines and spaces are ignored; any other key counts as an
    invalid press (the answer is then wrong, and the key is recorded).
    """

    def __init__(self, fd: int | None = None, debounce_s: float = 0.0, grace_s: float = 0.4,
                 echo: TextIO | None = None) -> None:
        self.fd = sys.stdin.fileno() if fd is None else fd
        self.window = PressWindow(debounce_s, grace_s)
        self.echo = echo  # the participant's terminal: a prompt at the beep, the keys, the practice result
        self._context: TurnContext | None = None
        self._saved = None
        self._eof = False
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None
        if os.isatty(self.fd):
            import termios
            import tty

            self._saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)

    def _read_available(self, timeout_s: float) -> str:
        if self._eof:  # input closed (end of a pipe): nothing more will come
            time.sleep(timeout_s)
            return ""
        ready, _, _ = select.select([self.fd], [], [], max(0.0, timeout_s))
        if not ready:
            return ""
        data = os.read(self.fd, 64)
        if not data:
            self._eof = True
        return data.decode("utf-8", errors="replace")

    def _drain(self) -> None:
        while self._read_available(0.0):
            pass

    def prepare(self, context: TurnContext) -> None:
        self._context = context

    def open_window(self) -> None:
        """Discard what was typed while the robot spoke, then read keys as they come."""
        self._drain()
        self.window.open()
        if self._context is not None:
            practice = " (practice)" if self._context.turn == 0 else ""
            self._show(f"your answer{practice}, {self._context.length} letters (a/b/c): ")
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._pump, args=(self._stop,), name="keyboard-answers", daemon=True)
        self._reader.start()

    def collect(self, n_expected: int, timeout_s: float) -> Answer:
        try:
            answer = self.window.collect(n_expected, timeout_s)
        finally:
            self._stop_reader()
        context, self._context = self._context, None
        self._show(self._verdict(answer, context) + "\n")
        return answer

    @staticmethod
    def _verdict(answer: Answer, context: TurnContext | None) -> str:
        """The end of the prompt line: the practice result, or just how the window ended."""
        end = " - time is up" if answer.timed_out else ""
        if context is None or context.turn != 0:
            return end
        if not answer.timed_out and tuple(answer.response) == tuple(context.sequence):
            return f"{end}  practice: correct"
        return f"{end}  practice: the sequence was {' '.join(context.sequence)}"

    def _show(self, text: str) -> None:
        if self.echo is not None:
            try:
                self.echo.write(text)
                self.echo.flush()
            except (OSError, ValueError):  # the terminal went away: answers still count
                self.echo = None

    def _stop_reader(self) -> None:
        if self._reader is not None:
            self._stop.set()
            self._reader.join()
            self._reader = None

    def _pump(self, stop: threading.Event) -> None:
        while not stop.is_set():
            text = self._read_available(0.02)
            now = time.monotonic()
            for ch in text:
                if ch in " \r\n\t":
                    continue
                if self.window.add(key=ch, letter=KEY_LETTERS.get(ch.lower()), t=now):
                    self._show(ch.upper() if ch.lower() in KEY_LETTERS else ch if ch.isprintable() else "?")

    def intended(self) -> Intention | None:
        return None  # a person's answer is not known in advance

    def abandon(self) -> None:
        """The turn was interrupted after its beep: stop reading and close its window (the next
        ``open_window`` starts a new reader; keys typed meanwhile are discarded then)."""
        self._stop_reader()
        self.window.close()

    def watch(self, callback: Callable[[Press], None]) -> None:
        self.window.listener = callback

    def close(self) -> None:
        self._stop_reader()
        self.window.close()
        if self._saved is not None:
            import termios

            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self._saved = None
