"""The study configuration's schema: every key's type, range or rule, and the check of one value.

``SCHEMA`` maps section -> key -> ``Field``; ``check_value`` returns the problem with a value (the
text after ``key '...'`` in an error message) or None. ``session.config`` merges and loads the files
against it and names file and line.
"""
from __future__ import annotations

import math
import re
import string
from dataclasses import dataclass
from typing import Any, Callable

from nao_trainer.robot.address import parse_url, redact_url

INPUTS = ("simulated", "tactile", "keyboard")
#: ``robot.url`` values that are not addresses: the in-process stand-in, the laptop itself.
MOCK, DESKTOP = "mock", "desktop"
#: No setting needs an integer this large; beyond it a number is a typo (and may not fit a float).
MAX_INT = 10**12


@dataclass(frozen=True)
class Field:
    """One configuration key: its type, allowed values and a fix hint for error messages."""

    kind: type | tuple[type, ...]
    nullable: bool = False
    min: float | None = None
    max: float | None = None
    choices: tuple[Any, ...] | None = None
    item: type | tuple[type, ...] | None = None  # element type of a list
    length: int | None = None  # exact list length
    check: Callable[[Any], str | None] | None = None  # extra rule: returns a problem or None
    free: bool = False  # a free-form mapping (keys not checked)


def _robot_url(value: str) -> str | None:
    if value in (MOCK, DESKTOP):
        return None
    problem = parse_url(value)[1]  # the robot client's own rule: the two never disagree
    return f"{problem} (got {redact_url(value)!r})" if problem else None  # never echo a password


def is_robot_address(url: str) -> bool:
    """True for a NAOqi address (a robot, or a stand-in started elsewhere), False for mock/desktop."""
    return url not in (MOCK, DESKTOP)


def _policy_spec(value: str) -> str | None:
    if value in ("schedule", "random", "personalised", "bayes") or re.fullmatch(r"usp:[^:\s]+(:[A-Za-z0-9_-]+)?", value):
        return None
    return "must be 'schedule', 'random', 'personalised', 'bayes' or 'usp:CLUSTER[:METHOD]'"


def _objective(value: str) -> str | None:
    if value == "score" or re.fullmatch(r"target(:(0?\.\d+))?", value):
        return None
    return "must be 'score' or 'target:R' with 0 < R < 1, e.g. target:0.75"


def _schedule(value: list) -> str | None:
    from nao_trainer.core import mdp  # lazily: `nao-trainer --help` parses without numpy

    bad = [a for a in value if a not in mdp.ACTION_NAMES]
    if bad:
        return f"unknown action {bad[0]!r}; use {', '.join(mdp.ACTION_NAMES)}"
    if not value:
        return "needs at least one action"
    if value[0] not in mdp.ACTION_NAMES[:4]:
        return f"must start with a level action (L1..L4), got {value[0]!r}: there is no outcome to give feedback on yet"
    return None


STATE_PATH_FIELDS = ("pseudonym", "output")


def _state_path(value: str) -> str | None:
    if value == "{session}":
        return None
    try:
        names = {n for _, n, _, _ in string.Formatter().parse(value) if n is not None}
    except ValueError as exc:
        return f"has a broken placeholder ({exc})"
    unknown = names - set(STATE_PATH_FIELDS)
    if unknown:
        return (f"unknown placeholder {{{sorted(unknown)[0]}}}; use {{pseudonym}} and {{output}}, "
                "or exactly {session} for the session folder")
    return None


SCHEMA: dict[str, Any] = {
    "study": {"name": Field(str), "description": Field(str, nullable=True)},
    "participant": {"pseudonym": Field(str, check=lambda v: None if re.fullmatch(r"[A-Za-z0-9_-]{1,40}", v)
                                        else "must be 1-40 letters, digits, '_' or '-' (it names the session folder; never a real name)")},
    "robot": {
        "url": Field(str, check=_robot_url),
        "connect_deadline_s": Field((int, float), min=0.5, max=120),
        "max_reconnect_s": Field((int, float), min=0, max=3600),
        "backoff_initial_s": Field((int, float), min=0.05, max=60),
        "backoff_max_s": Field((int, float), min=0.1, max=300),
        "posture_speed": Field((int, float), min=0.05, max=1.0),
    },
    "session": {
        "turns": Field(int, min=1, max=500),
        "practice": Field(bool),
        "seed": Field(int, nullable=True, min=0),
        "language": Field(str, choices=("en",)),
        "dialogue": Field(str),
        "behaviors": Field(str),
        "output": Field(str),
        "max_duration_s": Field((int, float), nullable=True, min=1, max=86400),
    },
    "timing": {
        "speed": Field((int, float), min=0.1, max=200),
        "pause_before_level_s": Field((int, float), min=0, max=30),
        "letter_gap_s": Field((int, float), min=0, max=10),
        "beep_hz": Field(int, min=100, max=8000),
        "beep_s": Field((int, float), min=0.05, max=3),
        "beep_gain": Field((int, float), min=0.0, max=1.0),
        "response_timeout_base_s": Field((int, float), min=1, max=300),
        "response_timeout_per_letter_s": Field((int, float), min=0, max=60),
        "grace_s": Field((int, float), min=0, max=5),
        "listening_tail_s": Field((int, float), min=0, max=5),
    },
    "answers": {
        "input": Field(str, choices=INPUTS),
        "debounce_s": Field((int, float), min=0, max=1),
    },
    "participant_model": {
        "success_by_level": Field(list, item=(int, float), length=4, check=lambda v: None if all(0 <= x <= 1 for x in v) else "values must lie in [0, 1]"),
        "engagement_by_level": Field(list, item=(int, float), length=4, check=lambda v: None if all(0 <= x <= 1 for x in v) else "values must lie in [0, 1]"),
        "user_model": Field(str, nullable=True),
    },
    "policy": {
        "kind": Field(str, check=_policy_spec),
        "schedule": Field(list, item=str, check=_schedule),
        "learning": Field(bool),
        "state_path": Field(str, nullable=True, check=lambda v: _state_path(v)),
        "guidance": Field((int, float), min=0, max=10),
        # personalised (learn.personalised, docs/personalisation.md)
        "assessment": Field(list, item=int, check=lambda v: None if len(v) <= 12 and all(1 <= x <= 4 for x in v)
                            else "levels 1..4, at most 12 turns"),
        "kappa": Field((int, float), min=0.01),
        "margin": Field((int, float), min=0),
        "objective": Field(str, check=lambda v: _objective(v)),  # bayes (core/objective.py)
    },
    "console": {
        "enabled": Field(bool),
        "port": Field(int, min=0, max=65535),
        "bind": Field(str, check=lambda v: None if re.fullmatch(r"[0-9A-Za-z.:-]{1,253}", v)
                      else "must be an IP address or host name, e.g. 127.0.0.1"),
    },
    # Types only: the modes, scopes, stream properties and processing keys are judged by the one
    # validator of the section, eeg.settings.EEGSettings (called by load_config with file:line).
    "eeg": {
        "mode": Field(str),
        "required": Field(bool),
        "stream_type": Field(str),
        "stream_name": Field(str, nullable=True),
        "source_id": Field(str, nullable=True),
        "lsl_scope": Field(str),
        "processing": Field(dict, free=True),
        "xdf": Field(bool),
    },
}


def _type_name(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    names = {int: "an integer", float: "a number", str: "a text", bool: "true/false", list: "a list", dict: "a mapping"}
    return " or ".join(names.get(k, k.__name__) for k in kinds if not (k is int and float in kinds))


def _is_kind(value: Any, kind: type | tuple[type, ...]) -> bool:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool) and bool not in kinds:
        return False
    return isinstance(value, kinds)


def _number_problem(value: Any) -> str | None:
    """NaN and infinity pass every range check (all comparisons are False), huge integers overflow floats."""
    if isinstance(value, float) and not math.isfinite(value):
        return f"must be a finite number, got {value!r}"
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_INT:
        return f"must be a number of sensible size, got one with {len(str(abs(value)))} digits"
    return None


def _text_problem(value: str) -> str | None:
    """Control characters (NUL...) and lone surrogates cannot be file names or spoken text."""
    bad = next((c for c in value if ord(c) < 0x20 or ord(c) == 0x7F or 0xD800 <= ord(c) <= 0xDFFF), None)
    if bad is not None:
        return f"must not contain control characters or invalid Unicode (found U+{ord(bad):04X})"
    return None


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_value(value: Any, spec: Field) -> str | None:
    """The problem with ``value`` for ``spec`` (one line, without key or place), or None."""
    if value is None:
        return None if spec.nullable else f"needs a value ({_type_name(spec.kind)}), got nothing"
    if not _is_kind(value, spec.kind):
        return f"must be {_type_name(spec.kind)}, got {_short(value)}"
    problem = _number_problem(value) or (_text_problem(value) if isinstance(value, str) else None)
    if problem:
        return problem
    if spec.choices is not None and value not in spec.choices:
        return f"must be one of {', '.join(map(str, spec.choices))}, got {value!r}"
    if spec.min is not None and value < spec.min:
        return f"must be >= {spec.min:g}, got {value!r}"
    if spec.max is not None and value > spec.max:
        return f"must be <= {spec.max:g}, got {value!r}"
    if isinstance(value, list):
        if spec.length is not None and len(value) != spec.length:
            return f"must have {spec.length} values, got {len(value)}"
        for item in value:
            if spec.item is not None and not _is_kind(item, spec.item):
                return f"values must each be {_type_name(spec.item)}, got {_short(item)}"
            problem = _number_problem(item) or (_text_problem(item) if isinstance(item, str) else None)
            if problem:
                return f"values: {problem}"
    if spec.check is not None:
        problem = spec.check(value)
        if problem:
            return f"{problem} (got {_short(value)})" if "got" not in problem else problem
    return None
