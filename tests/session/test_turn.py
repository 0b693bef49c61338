"""session.turn: the run summary counts what `nao-trainer study` counts (invalid turns left out) and says how
many turns had EEG."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from nao_trainer.data.study import study_session
from nao_trainer.errors import DataError
from nao_trainer.ports import CommandQueue
from nao_trainer.session.config import DEFAULT_CONFIG, load_config
from nao_trainer.session.turn import SessionResult, summary_data
from nao_trainer.session.wiring import RunOptions, run_session


def row(turn: int, level: int, success: bool | None, score: int | None, engagement: float | None,
        note: str = "", invalid: bool | None = None) -> dict:
    return {"turn": turn, "level": level, "success": success, "score": score, "engagement": engagement,
            "engagement_note": note, "invalid": invalid}


def test_the_summary_leaves_invalid_turns_out_and_says_how_many_turns_had_eeg():
    rows = [row(1, 2, True, 2, 0.8), row(2, 3, True, 3, None, "EEG stream lost", invalid=True),
            row(3, 3, False, -3, None, "EEG stream lost"), row(4, 1, None, None, None, "interrupted")]
    result = SessionResult(Path("x"), "completed", 0, rows, 1)
    assert len(result.completed_rows) == 2 and result.total_score == -1 and len(result.invalid_rows) == 1
    line = next(ln for ln in result.summary().splitlines() if ln.startswith("turns completed"))
    assert line.startswith("turns completed: 2 (+1 marked invalid, not counted)   total score: -1")
    assert line.endswith("mean engagement: 0.80 (EEG in 1 of 2 turns)")
    assert summary_data(result)["eeg_turns"] == 1 and summary_data(result)["invalid_turns"] == 1
    off = SessionResult(Path("x"), "completed", 0, [row(1, 1, True, 1, None, "EEG off")], 1)
    assert "EEG in" not in off.summary() and summary_data(off)["eeg_turns"] is None


class MarkInvalid:
    """An operator who marks turn ``n`` invalid while it is played."""

    def __init__(self, commands: CommandQueue, n: int) -> None:
        self.commands, self.n = commands, n

    def notify(self, kind: str, data: dict) -> None:
        if kind == "turn_start" and data["turn"] == self.n:
            self.commands.submit("invalid", {"turn": self.n}, "test")


def test_after_a_turn_marked_invalid_the_summary_and_the_study_table_agree(tmp_path):
    cfg = load_config(DEFAULT_CONFIG, {"session.turns": 4, "timing.speed": 50.0, "session.output": str(tmp_path),
                                       "eeg.mode": "off", "session.practice": False, "participant.pseudonym": "V",
                                       "session.seed": 2})
    commands = CommandQueue()
    result = run_session(cfg, RunOptions(quiet=True, commands=commands, observer=MarkInvalid(commands, 2)))
    assert result.exit_code == 0 and len(result.invalid_rows) == 1
    table = study_session(result.path).row
    assert (table["turns"], table["score"]) == (len(result.completed_rows), result.total_score)
    assert table["turns"] == 3  # 4 played, 1 marked invalid
    assert "(+1 marked invalid, not counted)" in result.summary()
    assert json.loads((result.path / "session.json").read_text())["eeg_turns"] is None  # EEG off


def test_the_summary_gives_the_span_from_the_counted_turns_and_nothing_without_turns(tmp_path):
    from nao_trainer.core.psychometric import level_counts, session_span
    from nao_trainer.learn.psychometric_prior import load_prior

    rows = [row(i + 1, 1 + i // 6, i % 6 < 5 - i // 6, 0, None, "EEG off") for i in range(24)]
    rows.append(row(25, 4, True, 4, None, "EEG off", invalid=True))  # not counted: not in the span either
    result = SessionResult(Path("x"), "completed", 0, rows, 1)
    want = session_span(load_prior(), level_counts([r["level"] for r in rows[:24]],
                                                   [r["success"] for r in rows[:24]]), 0.75)
    line = f"span at 75 %: {want.median:.1f} letters [{want.lo:.1f}, {want.hi:.1f}]"
    assert line + " (working-memory span: the sequence length recalled 75 % of the time; 90 % interval)" \
        in result.summary().splitlines()  # spelled out (issue 29)
    assert summary_data(result)["span"] == {"rate": 0.75, "median": round(want.median, 3), "lo": round(want.lo, 3),
                                            "hi": round(want.hi, 3), "interval": 0.9}
    stronger = SessionResult(Path("x"), "completed", 0, [{**r, "success": True} for r in rows], 1).span()
    assert stronger.median > want.median
    none = SessionResult(Path("x"), "interrupted", 3, [row(1, 1, None, None, None, "interrupted")], 1)
    assert "span" not in none.summary() and summary_data(none)["span"] is None
    bad = tmp_path / "pooled.json"
    bad.write_text("{")
    broken = SessionResult(Path("x"), "completed", 0, rows, 1, span_prior=bad)
    assert f"span at 75 %: n/a ({bad}:1: not valid JSON" in broken.summary()  # said, and the summary still prints


def test_a_run_writes_its_span_to_session_json_as_the_study_table_computes_it(tmp_path):
    from nao_trainer.learn.psychometric_prior import load_prior

    cfg = load_config(DEFAULT_CONFIG, {"session.turns": 8, "timing.speed": 50.0, "session.output": str(tmp_path),
                                       "eeg.mode": "off", "session.practice": False, "participant.pseudonym": "W",
                                       "session.seed": 3})
    result = run_session(cfg, RunOptions(quiet=True))
    assert result.exit_code == 0
    span = json.loads((result.path / "session.json").read_text())["span"]
    table = study_session(result.path, load_prior()).row
    assert [table["span"], table["span_lo"], table["span_hi"]] == pytest.approx([span["median"], span["lo"], span["hi"]],
                                                                                abs=0.006)
    assert span["lo"] < span["median"] < span["hi"]
    assert study_session(result.path).row["span"] is None  # no prior given: the columns stay empty


def test_a_target_study_gives_its_span_at_its_own_rate_in_the_summary_session_json_and_the_table(tmp_path):
    """A study that keeps participants near R (``policy.objective: target:R``) measures its span at R, the
    length this participant succeeds at R of the time; a score study at 75 %."""
    from nao_trainer.core.psychometric import level_counts, session_span
    from nao_trainer.learn.psychometric_prior import load_prior

    cfg = load_config(DEFAULT_CONFIG, {"session.turns": 8, "timing.speed": 50.0, "session.output": str(tmp_path),
                                       "eeg.mode": "off", "session.practice": False, "participant.pseudonym": "T",
                                       "session.seed": 3, "policy.objective": "target:0.6"})
    result = run_session(cfg, RunOptions(quiet=True))
    assert result.exit_code == 0
    span = json.loads((result.path / "session.json").read_text())["span"]
    counted = result.completed_rows
    want = session_span(load_prior(), level_counts([r["level"] for r in counted], [r["success"] for r in counted]), 0.6)
    assert span["rate"] == 0.6 and span["median"] == pytest.approx(want.median, abs=0.001)
    assert "span at 60 %:" in result.summary()
    at_75 = session_span(load_prior(), level_counts([r["level"] for r in counted], [r["success"] for r in counted]),
                         0.75)
    assert want.median > at_75.median  # a lower rate is reached at a longer length
    table = study_session(result.path, load_prior()).row
    assert table["span_rate"] == 0.6 and table["span"] == pytest.approx(span["median"], abs=0.006)
    info = json.loads((result.path / "session.json").read_text())
    for bad in ("0.6", 1.5, True):  # a crafted rate: one line naming the file
        info["span"]["rate"] = bad
        (result.path / "session.json").write_text(json.dumps(info))
        with pytest.raises(DataError, match=r"session.json: span.rate must be a number between 0 and 1"):
            study_session(result.path, load_prior())
