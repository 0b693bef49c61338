"""The session record: never overwritten, every completed turn durable, atomic session.json."""
from __future__ import annotations

import datetime as dt
import json
import os
import signal
import subprocess
import sys
import textwrap

from nao_trainer.session.record import TURN_COLUMNS, SessionRecorder, create_session_dir, read_events, read_turns


def test_session_folders_are_never_reused(tmp_path):
    when = dt.datetime(2026, 1, 2, 3, 4, 5)
    a = create_session_dir(tmp_path, "P01", when)
    b = create_session_dir(tmp_path, "P01", when)
    assert a.name == "P01_20260102-030405" and b.name == "P01_20260102-030405_2"


def test_events_before_open_are_kept_and_json_is_final(tmp_path):
    rec = SessionRecorder(tmp_path, "P02")
    rec.event("connecting", url="tcp://x")
    assert not any(tmp_path.iterdir())  # nothing written before open
    path = rec.open({"seed": 7})
    rec.turn({"turn": 1, "sequence": "ABC", "success": True, "score": 1})
    rec.event("turn_end", turn=1)
    assert json.loads((path / "session.json").read_text())["status"] == "running"
    rec.close("completed", 0, total_score=1)
    info = json.loads((path / "session.json").read_text())
    assert info["status"] == "completed" and info["exit_code"] == 0 and info["seed"] == 7 and info["turns_recorded"] == 1
    assert [e["event"] for e in read_events(path)] == ["connecting", "turn_end"]
    rows = read_turns(path)
    assert list(rows[0]) == list(TURN_COLUMNS) and rows[0]["sequence"] == "ABC" and rows[0]["notes"] == ""
    assert not (path / ".session.json.tmp").exists()


def test_a_killed_writer_leaves_every_completed_turn(tmp_path):
    script = textwrap.dedent(f"""
        import sys, time
        from nao_trainer.session.record import SessionRecorder
        rec = SessionRecorder({str(tmp_path)!r}, "K")
        path = rec.open({{}})
        for i in range(1, 4):
            rec.turn({{"turn": i, "sequence": "AB", "success": True}})
        print(path, flush=True)
        time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    path = proc.stdout.readline().strip()
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    rows = read_turns(path)
    assert [r["turn"] for r in rows] == ["1", "2", "3"]
    assert json.loads(open(os.path.join(path, "session.json")).read())["status"] == "running"


def test_session_plot(tmp_path):
    from nao_trainer.plots.session import plot_session

    rec = SessionRecorder(tmp_path, "PL")
    path = rec.open({})
    for i, (level, ok, fb, eng) in enumerate([(1, True, 0, 0.4), (2, False, 0, ""), (2, True, 1, 0.7)], start=1):
        rec.turn({"turn": i, "level": level, "success": ok, "feedback": fb, "score": level if ok else -1, "engagement": eng})
    rec.turn({"turn": 4, "level": 3, "success": None, "notes": "interrupted: robot lost during beep"})
    rec.close("robot lost", 3)
    out = plot_session(path)
    assert out == path / "session.png" and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000


def test_session_plot_names_the_robot_feedback_in_words(tmp_path):
    """Issue 29: the figure labelled the robot's feedback `enc` / `chl`; it says encouraging / challenging, as the
    turn line (`robot feedback: encouraging`) and the dialogue do."""
    from nao_trainer.plots import pyplot
    from nao_trainer.plots.session import session_figure

    rec = SessionRecorder(tmp_path, "PL")
    path = rec.open({})
    for i, (level, ok, fb) in enumerate([(2, True, 1), (2, False, 2), (3, True, 0), (3, True, 1)], start=1):
        rec.turn({"turn": i, "level": level, "success": ok, "feedback": fb, "score": level if ok else -1})
    rec.close("completed", 0)
    fig = session_figure(path)
    try:
        top = fig.axes[0]
        labels = [text.get_text() for text in top.get_legend().get_texts()]
        assert {"robot feedback: encouraging", "robot feedback: challenging"} <= set(labels), labels
        words = {text.get_text() for ax in fig.axes for text in ax.texts} | set(labels)
        assert not {"enc", "chl"} & words, words
        marks = {c.get_label(): len(c.get_offsets()) for c in top.collections}
        assert marks["robot feedback: encouraging"] == 2 and marks["robot feedback: challenging"] == 1, marks
    finally:
        pyplot().close(fig)


def test_a_session_folder_that_cannot_be_created_is_a_config_error(tmp_path):
    import pytest

    from nao_trainer.errors import ConfigError

    blocker = tmp_path / "f"
    blocker.write_text("")
    with pytest.raises(ConfigError, match=r"session.output: cannot create the folder .*f/out \(Not a directory\); point"):
        create_session_dir(blocker / "out", "P01")
    with pytest.raises(ConfigError, match="cannot create the folder"):
        SessionRecorder(blocker / "out", "P01").open({})
