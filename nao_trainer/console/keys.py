"""Operator keys on the terminal: p pause, r resume, s stop, i mark the turn in flight invalid.

A background thread reads single keys (character mode, no Enter) from the terminal and puts
commands on the session's queue. It runs only when stdin is a terminal (never on a pipe, and the
session does not start it when answers come from the keyboard); the terminal's settings are
restored by ``close`` (and at exit, should the process end another way).
"""
from __future__ import annotations

import atexit
import os
import select
import sys
import threading
from typing import TextIO

from nao_trainer.ports import CommandQueue

#: key -> (command kind, arguments, what the terminal says)
KEYS: dict[str, tuple[str, dict, str]] = {
    "p": ("pause", {}, "pause after the current utterance"),
    "r": ("resume", {}, "resume (replays the interrupted turn)"),
    "s": ("stop", {}, "stop: goodbye, safe posture, exit code 5"),
    "i": ("invalid", {"note": "marked with the i key"}, "mark the turn in flight invalid (not learned from)"),
}
HELP = "keys: " + "  ".join(f"{k} {kind}" for k, (kind, _, _) in KEYS.items()) + "  (Ctrl-C aborts)"


class KeyReader:
    """Reads operator keys from ``fd`` in a daemon thread until ``close``."""

    def __init__(self, commands: CommandQueue, fd: int, progress: TextIO | None = sys.stderr) -> None:
        import termios
        import tty

        self.commands = commands
        self.fd = fd
        self.progress = progress
        self._saved = termios.tcgetattr(fd)
        tty.setcbreak(fd)  # keys without Enter; Ctrl-C still interrupts (ISIG stays on)
        atexit.register(self._restore)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="operator-keys", daemon=True)
        self._thread.start()
        self._say(HELP)

    @classmethod
    def start_if_terminal(cls, commands: CommandQueue, progress: TextIO | None = sys.stderr,
                          fd: int | None = None) -> "KeyReader | None":
        """A reader on stdin when it is a terminal, else None (a pipe, CI)."""
        fd = sys.stdin.fileno() if fd is None else fd
        try:
            if not os.isatty(fd):
                return None
        except (OSError, ValueError):
            return None
        return cls(commands, fd, progress)

    def _say(self, line: str) -> None:
        if self.progress is not None:
            print(line, file=self.progress, flush=True)

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
                    kind, args, what = KEYS[ch]
                    self.commands.submit(kind, args, source="keys")
                    self._say(f"[{ch}] {what}: requested")

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
