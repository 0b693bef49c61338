"""Console commands checked on arrival (issue 18 items 1 and 4): nothing malformed reaches the session's queue."""
from __future__ import annotations

import json

import pytest

from nao_trainer.console.command_schema import (MAX_BODY, MAX_DEPTH, NOTE_MAX, SCHEMA, CommandRejected, check_command,
                                          nesting_depth, parse_body)
from nao_trainer.ports import COMMAND_KINDS


class View:
    """The session as the console sees it: turn 3 of 25 in flight."""

    def __init__(self, current=3, planned=25):
        self.current, self.planned = current, planned

    def turn_in_flight(self):
        return self.current

    def turns_planned(self):
        return self.planned


def check(text: str, view=None):
    return check_command(parse_body(text.encode()), view or View())


def test_every_kind_has_a_schema():
    assert set(SCHEMA) == set(COMMAND_KINDS)


@pytest.mark.parametrize("body, kind, args", [
    ('{"kind":"pause"}', "pause", {}),
    ('{"kind":"stop","args":{}}', "stop", {}),
    ('{"kind":"resume","args":null}', "resume", {}),
    ('{"kind":"override","args":{"action":"RF2"}}', "override", {"action": "RF2"}),
    ('{"kind":"invalid","args":{"turn":3,"note":" phone rang "}}', "invalid", {"turn": 3, "note": "phone rang"}),
    ('{"kind":"invalid","args":{"turn":2.0}}', "invalid", {"turn": 2}),
    ('{"kind":"invalid","args":{"turn":null,"note":""}}', "invalid", {"note": ""}),
    ('{"kind":"note","args":{"text":"water"}}', "note", {"text": "water"}),
])
def test_valid_commands_pass_normalised(body, kind, args):
    assert check(body) == (kind, args)


@pytest.mark.parametrize("body, status, words", [
    ('{"kind":"invalid","args":{"turn":"abc"}}', 400, "whole number"),  # the attack of the issue
    ('{"kind":"invalid","args":{"turn":[1]}}', 400, "whole number"),
    ('{"kind":"invalid","args":{"turn":1e400}}', 400, "whole number"),  # overflows to inf
    ('{"kind":"invalid","args":{"turn":true}}', 400, "whole number"),
    ('{"kind":"invalid","args":{"turn":2.5}}', 400, "whole number"),
    ('{"kind":"invalid","args":{"turn":0}}', 400, "does not exist"),
    ('{"kind":"invalid","args":{"turn":26}}', 400, "does not exist"),
    ('{"kind":"invalid","args":{"turn":4}}', 400, "has not started"),
    ('{"kind":"invalid","args":{"turn":' + "9" * 5000 + '}}', 400, "JSON"),  # more digits than int() takes
    ('{"kind":"note","args":{"text":NaN}}', 400, "NaN"),
    ('{"kind":"note","args":{"text":-Infinity}}', 400, "-Infinity"),
    ('{"kind":"note","args":{"text":"   "}}', 400, "empty"),
    ('{"kind":"note","args":{"text":5}}', 400, "text"),
    ('{"kind":"note"}', 400, "required"),
    ('{"kind":"override","args":{"action":"L9"}}', 400, "L1"),
    ('{"kind":"override","args":{"action":null}}', 400, "required"),
    ('{"kind":"pause","args":{"x":1}}', 400, "unknown argument"),
    ('{"kind":"pause","args":[1]}', 400, "object"),
    ('{"kind":"pause","extra":1}', 400, "unknown field"),
    ('{"kind":"dance"}', 400, "unknown command"),
    ('{"kind":["pause"]}', 400, "unknown command"),
    ('[1]', 400, "object"),
    ('{"kind":', 400, "not valid JSON"),
    ("[" * 100_000, 413, "at most"),  # was a RecursionError and a 500
    ("[" * 1000, 400, "nested deeper"),
])
def test_malformed_commands_are_rejected_in_one_line(body, status, words):
    with pytest.raises(CommandRejected, match=words) as err:
        check(body)
    assert err.value.status == status and "\n" not in str(err.value) and len(str(err.value)) < 300


def test_a_note_has_a_length_limit_and_text_bytes_must_be_utf8():
    assert check(json.dumps({"kind": "note", "args": {"text": "x" * NOTE_MAX}}))[1]["text"] == "x" * NOTE_MAX
    with pytest.raises(CommandRejected, match=f"at most {NOTE_MAX}"):
        check(json.dumps({"kind": "note", "args": {"text": "x" * (NOTE_MAX + 1)}}))
    with pytest.raises(CommandRejected, match="UTF-8"):
        parse_body(b'{"kind":"\xff"}')
    with pytest.raises(CommandRejected) as err:
        parse_body(b" " * (MAX_BODY + 1))
    assert err.value.status == 413


def test_no_turn_in_flight_means_no_turn_can_be_named():
    with pytest.raises(CommandRejected, match="has not started"):
        check('{"kind":"invalid","args":{"turn":1}}', View(current=None))


def test_nesting_depth_ignores_brackets_in_strings():
    assert nesting_depth('{"a":[1,{"b":"[[[[{{"}]}') == 3
    assert nesting_depth('"\\"[[["') == 0
    assert nesting_depth("[" * (MAX_DEPTH + 1)) == MAX_DEPTH + 1
