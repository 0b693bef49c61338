"""Errors a user can fix. The CLI prints them as one line (no traceback) and exits non-zero."""
from __future__ import annotations


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
