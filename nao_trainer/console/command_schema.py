"""What a console command may carry, checked when the request arrives (nothing malformed reaches the queue).

``SCHEMA`` declares, per command kind (``ports.COMMAND_KINDS``), the arguments it takes: their type,
whether they are required, and their range. ``parse_body`` reads a request body strictly (size,
nesting depth, no ``NaN``/``Infinity``, which Python's ``json`` accepts by default and ``JSON.parse``
does not); ``check_command`` checks one command against the schema and the session's read-only
``SessionView`` (a turn named must exist). Both raise ``CommandRejected`` with a one-line message
that the server answers with 400 (413 for a body too large).
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any, Protocol

from nao_trainer.core import mdp
from nao_trainer.ports import COMMAND_KINDS

#: Largest command body (bytes). A note of NOTE_MAX characters fits many times over.
MAX_BODY = 16 * 1024
#: Deepest nesting of arrays/objects in a body (a command needs 2: the body and its args).
MAX_DEPTH = 8
#: Longest note / invalid-turn note (characters).
NOTE_MAX = 2000


class CommandRejected(ValueError):
    """A command the console refuses at the door; ``status`` is the HTTP status to answer."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


class SessionView(Protocol):
    """What the console knows of the session, read-only (``server.ConsoleHub`` provides it)."""

    def turn_in_flight(self) -> int | None: ...

    def turns_planned(self) -> int | None: ...


@dataclass(frozen=True)
class Arg:
    """One argument: ``kind`` "text", "action" or "turn"; ``required``; ``nullable`` (null = not given)."""

    kind: str
    required: bool = False
    nullable: bool = True


#: command kind -> {argument name: what it may be}. Kinds not listed take no arguments.
SCHEMA: dict[str, dict[str, Arg]] = {
    "pause": {}, "resume": {}, "stop": {}, "repeat": {},
    "override": {"action": Arg("action", required=True, nullable=False)},
    "invalid": {"turn": Arg("turn"), "note": Arg("text")},
    "note": {"text": Arg("text", required=True, nullable=False)},
}
assert set(SCHEMA) == set(COMMAND_KINDS), "every command kind needs its schema"

_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)


def _reject_constant(name: str) -> None:
    raise CommandRejected(f"{name} is not a number JSON allows; send a finite number")


def nesting_depth(text: str) -> int:
    """The deepest nesting of ``[``/``{`` in JSON text (brackets inside strings do not count)."""
    depth = deepest = 0
    for ch in _STRING.sub('""', text):
        if ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


def parse_body(raw: bytes) -> dict[str, Any]:
    """The request body as a JSON object, read strictly; ``CommandRejected`` otherwise."""
    if len(raw) > MAX_BODY:
        raise CommandRejected(f"body of {len(raw)} bytes; a command is at most {MAX_BODY} bytes", 413)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise CommandRejected("the body is not UTF-8 text; send JSON") from None
    if nesting_depth(text) > MAX_DEPTH:
        raise CommandRejected(f"JSON nested deeper than {MAX_DEPTH} levels; send {{\"kind\": ..., \"args\": {{...}}}}")
    try:
        body = json.loads(text, parse_constant=_reject_constant)
    except CommandRejected:
        raise
    except json.JSONDecodeError as exc:
        raise CommandRejected(f"not valid JSON ({exc.msg} at character {exc.pos})") from None
    except ValueError as exc:  # e.g. an integer of more digits than Python converts
        raise CommandRejected(f"not a JSON command Python can read ({str(exc)[:80]})") from None
    if not isinstance(body, dict):
        raise CommandRejected("the body must be a JSON object {\"kind\": ..., \"args\": {...}}")
    return body


def check_command(body: dict[str, Any], view: SessionView) -> tuple[str, dict[str, Any]]:
    """(kind, args) of a valid command body, the args normalised (ints for turns, stripped text)."""
    unknown = set(body) - {"kind", "args"}
    if unknown:
        raise CommandRejected(f"unknown field(s) {', '.join(sorted(map(str, unknown)))[:80]}; send only kind and args")
    kind = body.get("kind")
    if not isinstance(kind, str) or kind not in SCHEMA:
        raise CommandRejected(f"unknown command {str(kind)[:40]!r}; use one of {', '.join(COMMAND_KINDS)}")
    args = body.get("args")
    args = {} if args is None else args
    if not isinstance(args, dict):
        raise CommandRejected(f"{kind}: args must be a JSON object")
    schema = SCHEMA[kind]
    extra = set(args) - set(schema)
    if extra:
        allowed = ", ".join(schema) or "none"
        raise CommandRejected(f"{kind}: unknown argument(s) {', '.join(sorted(map(str, extra)))[:80]} (allowed: {allowed})")
    out: dict[str, Any] = {}
    for name, arg in schema.items():
        value = args.get(name)
        if value is None:
            if arg.required or (name in args and not arg.nullable):
                raise CommandRejected(f"{kind}: argument {name} is required")
            continue
        out[name] = _check_value(kind, name, arg, value, view)
    return kind, out


def _check_value(kind: str, name: str, arg: Arg, value: Any, view: SessionView) -> Any:
    where = f"{kind}: {name}"
    if arg.kind == "text":
        if not isinstance(value, str):
            raise CommandRejected(f"{where} must be text")
        if len(value) > NOTE_MAX:
            raise CommandRejected(f"{where} has {len(value)} characters; at most {NOTE_MAX}")
        text = value.strip()
        if arg.required and not text:
            raise CommandRejected(f"{where} is empty")
        return text
    if arg.kind == "action":
        if not isinstance(value, str) or value not in mdp.ACTION_NAMES:
            raise CommandRejected(f"{where} must be one of {', '.join(mdp.ACTION_NAMES)}")
        return value
    assert arg.kind == "turn"
    # bool is an int in Python and 1.0 a float in JSON: only a whole, finite number is a turn
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (isinstance(value, float) and not (math.isfinite(value) and value.is_integer())):
        raise CommandRejected(f"{where} must be a whole number (the turn shown on the page)")
    turn = int(value)
    planned, current = view.turns_planned(), view.turn_in_flight()
    if turn < 1 or (planned is not None and turn > planned):
        raise CommandRejected(f"{where} {turn} does not exist (turns 1-{planned if planned is not None else '?'})")
    if current is None or turn > current:
        raise CommandRejected(f"{where} {turn} has not started (turn in flight: {current if current else 'none'})")
    return turn
