"""Errors a user can fix. The CLI prints them as one line (no traceback) and exits non-zero."""
from __future__ import annotations

import threading


class UserError(Exception):
    """A problem in the user's input or environment: message says what, where and how to fix it."""

    exit_code = 2


class ConfigError(UserError):
    """A study configuration, dialogue or behavior file is invalid."""


class DataError(UserError):
    """A recording, dataset or artifact file cannot be read as expected."""


class RobotUnavailable(UserError):
    """The robot (or its stand-in) cannot be reached or was lost for good."""

    exit_code = 3


class EEGUnavailable(UserError):
    """A required EEG stream is not available."""

    exit_code = 4


class Interrupted(Exception):
    """The operator interrupted a session (Ctrl-C); exit code 130 like a shell."""

    exit_code = 130


_INTERRUPT = threading.Event()


def note_interrupt(came: bool = True) -> None:
    """A Ctrl-C came (the command line's SIGINT handler says so before it raises KeyboardInterrupt); ``False``:
    forget it (a command starts)."""
    if came:
        _INTERRUPT.set()
    else:
        _INTERRUPT.clear()


def raise_if_interrupted() -> None:
    """KeyboardInterrupt again if a Ctrl-C came: long loops call it between steps.

    The KeyboardInterrupt of a Ctrl-C is raised wherever Python happens to be, and third-party C code that
    calls back into Python can swallow it there: seen in numpy's ``np.char.mod`` and in the import of
    ``numpy.random`` (`nao-trainer train` then went on with 600 M turns instead of stopping).
    """
    if _INTERRUPT.is_set():
        raise KeyboardInterrupt
