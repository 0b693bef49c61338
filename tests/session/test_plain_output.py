"""The session's output in plain words (issue 29): the console's clock in wall seconds, a turn marked invalid
said on its line, the personalised policy's choice and the span spelled out."""
from __future__ import annotations

from types import SimpleNamespace

from nao_trainer.policies.personalised import plain_name
from nao_trainer.session.engine import Session
from nao_trainer.session.stage import Clock
from nao_trainer.session.turn import progress_line
from nao_trainer.tasks.nback import NBackTask
from nao_trainer.tasks.sequence import SequenceTask


def test_the_consoles_clock_is_wall_time_not_sped_up_time():
    now = [100.0]
    session = SimpleNamespace(clock=Clock(speed=25, now=lambda: now[0]), _t0=70.0, _elapsed_before=0.0)
    session.elapsed_s = lambda: Session.elapsed_s(session)
    assert Session.elapsed_s(session) == 750.0  # session seconds (the record's)
    assert Session.wall_elapsed_s(session) == 30.0  # what a supervisor's watch says


def test_a_turn_marked_invalid_says_it_is_not_in_the_total():
    row = {"turn": 3, "level": 2, "feedback": 0, "sequence": "ABABC", "response": "ABABC", "success": True,
           "score": 2, "engagement": 0.5, "notes": "", "phase": "", "invalid": True}
    assert "not in the total" in progress_line(row, 25, 4)
    assert "not in the total" not in progress_line({**row, "invalid": False}, 25, 6)


def test_robot_feedback_is_spelled_out_on_the_turn_line():
    row = {"turn": 8, "level": 2, "feedback": 1, "sequence": "ABABC", "response": "ABABC", "success": True,
           "score": 2, "engagement": 0.5, "notes": "", "phase": "personalised"}
    assert progress_line(row, 25, 4, SequenceTask()).startswith("turn   8/25  L2      ABABC vs ABABC     ok  +2  total    4  E 0.50  "
                                                "(robot feedback: encouraging)  [personalised]")
    assert "(robot feedback: challenging)" in progress_line({**row, "feedback": 2}, 25, 4, SequenceTask())
    assert "feedback" not in progress_line({**row, "feedback": 0}, 25, 4, SequenceTask())


def test_the_progress_line_says_what_the_task_describes():
    row = {"turn": 3, "level": 2, "feedback": 0, "sequence": "ABABC", "response": "ABABA", "success": False,
           "score": -1, "engagement": None, "notes": "", "phase": ""}
    assert "ABABC vs ABABA" in progress_line(row, 25, 4, SequenceTask())
    nback = {**row, "hits": 5, "targets": "0010010101010000100000", "false_alarms": 1}
    assert "hits 5/6 false alarms 1" in progress_line(nback, 25, 4, NBackTask())
    assert "pressed ABABA" in progress_line(row, 25, 4, object())  # a task without describe: what was pressed


def test_candidate_policies_are_named_in_words():
    assert plain_name("usp:3") == "personalised (user model 3)"
    assert plain_name("usp:3", "by expected value") == "personalised (user model 3, by expected value)"
    assert plain_name("fixed:4") == "fixed level 4"
    assert plain_name("fixed:4", "by expected value") == "fixed level 4 (by expected value)"
