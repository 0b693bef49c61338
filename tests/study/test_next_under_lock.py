"""`study next` plans the session under the participant's lock: one that ended meanwhile counts."""
from __future__ import annotations

import io

import pytest

from _study_data import study_with_one_participant
from nao_trainer.errors import DataError
from nao_trainer.session.wiring import RunOptions
from nao_trainer.study import runner
from nao_trainer.study.registry import record_session


def test_a_session_recorded_between_plan_and_lock_is_counted(tmp_path, capsys, monkeypatch):
    root = study_with_one_participant(tmp_path)
    capsys.readouterr()
    real_lock = runner.participant_lock

    def lock_after_two_sessions_ended(study, pseudonym, notice=None):
        for number in (1, 2):  # another operator's `study next` finished both sessions meanwhile
            record_session(root, pseudonym, {"number": number, "folder": f"{pseudonym}_x{number}",
                                             "status": "completed", "exit_code": 0, "started": None,
                                             "ended": "2026-11-02T10:00:00+00:00", "outside_interval": False,
                                             "protocol_sha256": study.protocol.sha256})
        return real_lock(study, pseudonym, notice)

    monkeypatch.setattr(runner, "participant_lock", lock_after_two_sessions_ended)
    played = []
    monkeypatch.setattr(runner, "play", lambda *a, **k: played.append(a))
    with pytest.raises(DataError, match="completed all 2 sessions"):
        runner.run_next(root, "P001", {}, RunOptions(keys=False, quiet=True), progress=io.StringIO())
    assert not played and not (root / "locks" / "P001.lock").exists()
