"""Head buttons from the stand-in's terminal: ``nao-trainer mock-robot`` reads a, b, c as touches of the front,
middle and rear head buttons, so ``hardware-check``, ``run --input tactile`` and the before-first-participant
checklist can be rehearsed with no robot.

A daemon thread reads single keys (character mode, no Enter) when stdin is a terminal; each key is one
press through the stand-in's own control service (``StandIn.press``, what a finger on a NAO does: touch,
hold 0.1 s, release). The terminal's settings are restored by ``close`` and at exit.
"""
from __future__ import annotations

import atexit
import os
import select
import threading
from typing import Callable, TextIO

#: key -> (button letter, what the terminal says)
KEYS: dict[str, tuple[str, str]] = {"a": ("A", "front"), "b": ("B", "middle"), "c": ("C", "rear")}
HELP = ("head buttons from this terminal: " + "  ".join(f"{k} {name}" for k, (_, name) in KEYS.items())
        + "  (or `nao-trainer mock-robot press A|B|C --robot URL` from another shell; Ctrl-C stops the stand-in)")


class ButtonKeys:
    """Reads a/b/c from ``fd`` in a daemon thread and calls ``press(letter)`` for each until ``close``."""

    def __init__(self, press: Callable[[str], object], fd: int, out: TextIO | None) -> None:
        import termios
        import tty

        self.press, self.fd, self.out = press, fd, out
        self._saved = termios.tcgetattr(fd)
        tty.setcbreak(fd)  # keys without Enter; Ctrl-C still interrupts (ISIG stays on)
        atexit.register(self._restore)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="stand-in-keys", daemon=True)
        self._thread.start()
        self._say(HELP)

    @classmethod
    def start_if_terminal(cls, press: Callable[[str], object], out: TextIO | None, fd: int) -> "ButtonKeys | None":
        """A reader on ``fd`` when it is a terminal, else None (a pipe, a test's child process, CI)."""
        try:
            if not os.isatty(fd):
                return None
        except (OSError, ValueError):
            return None
        return cls(press, fd, out)

    def _say(self, line: str) -> None:
        if self.out is not None:
            print(line, file=self.out, flush=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.fd], [], [], 0.1)
                if not ready:
                    continue
                data = os.read(self.fd, 32)
            except (OSError, ValueError):
                return
            if not data:
                return
            for ch in data.decode("utf-8", errors="replace").lower():
                if ch in KEYS:
                    letter, name = KEYS[ch]
                    try:
                        self.press(letter)
                    except Exception as exc:  # noqa: BLE001 - the stand-in going away must not kill the reader
                        self._say(f"[{ch}] {name} head button: not pressed ({exc})")
                    else:
                        self._say(f"[{ch}] {name} head button ({letter}) pressed")

    def _restore(self) -> None:
        import termios

        if self._saved is not None:
            try:
                termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            except (OSError, termios.error):
                pass
            self._saved = None

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._restore()
