"""Sessions of another task read back (issue 26): an n-back session's turns.csv (no length, no sequence) is read by
the columns its task declares; `import` refuses it in one line, because the turn table and the user models fitted
on it are the published data's (the sequence task); its study row has no span in letters."""
from __future__ import annotations

import json

import pytest

from nao_trainer.cli import main
from nao_trainer.data import own
from nao_trainer.data.study import study_session
from nao_trainer.errors import DataError
from nao_trainer.learn.psychometric_prior import load_prior

TURNS = """\
turn,start_time,state,level,feedback,previous_score,action,n,stimuli,targets,hits,misses,false_alarms,correct_rejections,d_prime,response,success,score,signed_score,reaction_time,completion_time,engagement,engagement_index,eeg_quality,answer_engagement,engagement_note,notes,invalid,replay,phase
1,2026-12-03T08:37:30.482+00:00,31,2,0,0,L2,2,GGTGWCWCCP,0001001100,2,1,1,6,1.206,AAA,True,2,2,3.272,17.292,,,,,EEG off,,,,
2,2026-12-03T08:37:31.017+00:00,33,2,0,2,L2,2,HKPKPCHHTH,0001100001,1,2,1,6,0.3,AA,False,-1,-2,9.23,21.222,,,,,EEG off,3 errors,,,
"""


def _session(tmp_path, task: str | None):
    folder = tmp_path / "sessions" / "N002_20261203-083729"
    folder.mkdir(parents=True)
    values = {"participant": {"pseudonym": "N002"}, "study": {"name": "nback"}}
    if task:
        values["task"] = {"name": task, "settings": {}}
    (folder / "session.json").write_text(json.dumps({
        "format": "nao-trainer/session", "format_version": 1, "status": "completed", "input": "simulated",
        "started": "2026-12-03T08:37:29.975+00:00", "ended": "2026-12-03T08:37:31.751+00:00", "policy": "schedule",
        "config": {"values": values}}))
    (folder / "turns.csv").write_text(TURNS)
    return folder


def test_an_nback_session_is_read_by_its_tasks_columns(tmp_path):
    folder = _session(tmp_path, "nback")
    sess = own.read_session(folder)
    assert sess.task == "nback" and [r["hits"] for r in sess.rows] == ["2", "1"]
    rows, excluded = own.table_rows(sess)
    assert not excluded and [(r["level"], r["success"], r["score"]) for r in rows] == [(2, 1, 2), (2, 0, -1)]
    row = study_session(folder, load_prior()).row
    assert row["score"] == 1 and row["success_L2"] == 0.5 and row["span"] is None  # no span in letters


def test_a_session_without_a_task_is_the_sequence_tasks_and_needs_its_columns(tmp_path):
    folder = _session(tmp_path, None)  # an older folder: no task recorded
    with pytest.raises(DataError, match="missing columns length, sequence"):
        own.read_session(folder)


def test_a_session_of_a_task_not_installed_is_one_line(tmp_path):
    with pytest.raises(DataError, match="session's task cannot be read: unknown task 'stroop'"):
        own.read_session(_session(tmp_path, "stroop"))


def test_import_refuses_nback_sessions_saying_what_does_not_carry_over(tmp_path, capsys):
    _session(tmp_path, "nback")
    assert main(["import", str(tmp_path / "sessions"), "--out", str(tmp_path / "turns.csv")]) == 2
    err = capsys.readouterr().err
    assert "task 'nback': not imported" in err and "published data" in err and "Traceback" not in err
    assert len([line for line in err.splitlines() if "error" in line]) == 1 and not (tmp_path / "turns.csv").exists()
    assert main(["fit", str(tmp_path / "sessions"), "--out", str(tmp_path / "models")]) == 2  # fit reads through import
    err = capsys.readouterr().err
    assert "task 'nback': not imported" in err and "Traceback" not in err and not (tmp_path / "models").exists()
