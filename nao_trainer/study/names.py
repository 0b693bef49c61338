"""One validator for every name the study layer turns into a folder, a label or a line of output.

Pseudonyms, pseudonym prefixes and arm names become folder names and BIDS labels: letters and digits,
starting with a letter. Study and site names may also hold ``-``, ``_`` and ``.`` (never first, never
``..``). Checked with ``fullmatch``: ``^...$`` lets a trailing newline through (``"P\\n"`` matched), which
then broke every later command.
"""
from __future__ import annotations

import re

from nao_trainer.errors import ConfigError

_PATTERNS = {
    "label": (re.compile(r"[A-Za-z][A-Za-z0-9]*"), "letters and digits, starting with a letter"),
    "name": (re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}"),
             "letters, digits, '-', '_' or '.', starting with a letter or digit, at most 64 characters"),
}


def name_problem(value: object, kind: str = "label") -> str:
    """'' when ``value`` is a valid name of ``kind`` (label|name), else what it must be."""
    pattern, rule = _PATTERNS[kind]
    if not isinstance(value, str) or not pattern.fullmatch(value) or ".." in value:
        return rule
    return ""


def check_name(value: object, what: str, kind: str = "label") -> str:
    """``value`` when valid; ``ConfigError`` naming ``what`` (shown with ``repr``: a newline stays visible)."""
    problem = name_problem(value, kind)
    if problem:
        raise ConfigError(f"{what} {value!r}: must be {problem}")
    return value  # type: ignore[return-value]
