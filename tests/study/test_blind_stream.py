"""Blinding on the terminal: every arm shows its turn lines (their absence would name the arm)."""
from __future__ import annotations

import io

from nao_trainer.study.runner import BLIND_LABEL, BlindStream

NAMES = ["personalised", "level2", "random", "schedule"]


def _shown(text: str) -> list[str]:
    out = io.StringIO()
    stream = BlindStream(out, NAMES)
    stream.write(text)
    return out.getvalue().splitlines()


def test_a_turn_line_tagged_with_the_policy_phase_is_shown_without_its_tag():
    lines = _shown("turn   1/25  L2          CABBC vs CABBC     ok  +2  total    2  E -  [assessment]\n"
                   "turn   7/25  L2          CBCBB vs CBCBB     ok  +2  total    7  E 0.00  [personalised]\n")
    assert lines == ["turn   1/25  L2          CABBC vs CABBC     ok  +2  total    2  E -",
                     "turn   7/25  L2          CBCBB vs CBCBB     ok  +2  total    7  E 0.00"]


def test_an_untagged_turn_line_looks_the_same_as_a_tagged_one():
    tagged = _shown("turn   3/25  L3        BACCCBA vs BACCCBB   err -1  total    3  E -  [assessment]\n")
    plain = _shown("turn   3/25  L3        BACCCBA vs BACCCBB   err -1  total    3  E -\n")
    assert tagged == plain and len(plain) == 1


def test_lines_about_the_policy_are_dropped_and_arm_names_hidden():
    lines = _shown("           posterior: user model 3 0.37 | user model 1 0.33 | user model 2 0.30 (assessment)\n"
                   "matched user model 3 (posterior 0.81)\n"
                   "arm level2 ready\n")
    assert lines == [f"arm {BLIND_LABEL} ready"]
