"""Where a participant's state lives and how a replaced one is kept (policies.participant_state)."""
from __future__ import annotations

import re
import time
from datetime import datetime, timezone

from nao_trainer.policies.participant_state import (SESSION_FOLDER, participant_dir, participant_template, session_state_file,
                                                    set_aside, state_file)


def test_one_rule_for_every_policy(tmp_path):
    out = tmp_path / "out"
    assert state_file("usp:2", None, "P7", out) == out.resolve() / "participants" / "P7" / "policy_state.json"
    assert state_file("personalised", None, "P7", out) == out.resolve() / "participants" / "P7" / "personalised.json"
    template = str(tmp_path / "s" / "{pseudonym}-state.json")
    assert state_file("personalised", template, "P7", out) == tmp_path / "s" / "P7-state.json"
    assert state_file("usp:2", SESSION_FOLDER, "P7", out) is None
    assert session_state_file("personalised", tmp_path) == tmp_path / "personalised.json"
    assert session_state_file("usp:1:qaug", tmp_path) == tmp_path / "policy_state.json"


def test_set_aside_keeps_every_replaced_file_with_a_utc_stamp(tmp_path, monkeypatch):
    monkeypatch.setenv("TZ", "Pacific/Kiritimati")  # UTC+14: a local-time stamp would be 14 hours off
    time.tzset()
    path = tmp_path / "personalised.json"
    kept = []
    for text in ("first", "second", "third"):  # within one second: the names must not collide
        path.write_text(text)
        kept.append(set_aside(path))
    assert not path.exists() and [k.read_text() for k in kept] == ["first", "second", "third"]
    stamp = re.fullmatch(r"personalised\.json\.replaced-(\d{8}-\d{6})(_\d+)?", kept[0].name).group(1)
    when = datetime.strptime(stamp, "%Y%m%d-%H%M%S").replace(tzinfo=timezone.utc)
    monkeypatch.undo()
    time.tzset()
    assert abs((datetime.now(timezone.utc) - when).total_seconds()) < 3600  # UTC, not local time
    assert len({k.name for k in kept}) == 3


def test_a_study_arms_template_and_the_withdrawal_folder_follow_the_default_rule(tmp_path):
    for kind in ("personalised", "usp:2"):
        default = state_file(kind, None, "P01", tmp_path)
        assert state_file(kind, participant_template(kind), "P01", tmp_path) == default
        assert default.parent == participant_dir(tmp_path, "P01").resolve()
    assert participant_template("personalised").endswith("personalised.json")


def test_open_saved_reads_sets_aside_or_finds_nothing(tmp_path):
    import logging

    import pytest

    from nao_trainer.errors import DataError
    from nao_trainer.policies.participant_state import check_owner, open_saved

    log = logging.getLogger("test")
    path = tmp_path / "bayes.json"
    read = lambda p: {"text": p.read_text()}  # noqa: E731
    assert open_saved(None, False, read, "bayes", log) is None  # kept in the session folder
    assert open_saved(path, False, read, "bayes", log) is None  # nothing saved yet
    path.write_text("old")
    assert open_saved(path, False, read, "bayes", log) == {"text": "old"}
    assert open_saved(path, True, read, "bayes", log) is None  # --fresh-policy: kept beside, not read
    assert not path.exists() and [p.read_text() for p in tmp_path.glob("bayes.json.replaced-*")] == ["old"]
    check_owner(path, {"pseudonym": "P1"}, "P1", "fix")
    check_owner(path, {}, "P1", "fix")  # an older file naming no one passes
    with pytest.raises(DataError, match=r"the participant state of 'P1', not of 'P2' .*; fix$"):
        check_owner(path, {"pseudonym": "P1"}, "P2", "fix")


def test_one_participant_file_base_saves_reads_and_checks_owner_and_fingerprint(tmp_path):
    """The shared base of every persisting policy (bayes, personalised, learned): one save, read, owner check
    and fingerprint check."""
    import json as _json

    import pytest

    from nao_trainer.errors import DataError
    from nao_trainer.policies import bayes, learned, personalised
    from nao_trainer.policies.participant_state import ParticipantState

    assert all(isinstance(m.PARTICIPANT, ParticipantState) for m in (bayes, learned, personalised))
    state = ParticipantState(lambda p: _json.loads(p.read_text()), lambda p, d: p.write_text(_json.dumps(d)),
                             lambda saved: saved.get("fp"), "other models")
    path = tmp_path / "deep" / "state.json"
    state.save(path, {"pseudonym": "P1", "fp": "abc"})
    assert state.read(path, "abc", "P1") == {"pseudonym": "P1", "fp": "abc"}
    with pytest.raises(DataError, match=r"the participant state of 'P1', not of 'P2'"):
        state.read(path, "abc", "P2")
    with pytest.raises(DataError, match=r"state.json: participant state made with other models \(fingerprint abc, now "
                                        r"xyz\); use what it was made with, or start afresh with --fresh-policy"):
        state.read(path, "xyz", "P1")
    (tmp_path / "file").write_text("")
    with pytest.raises(DataError, match=r"cannot save the participant's state .*; make session.output writable"):
        state.save(tmp_path / "file" / "state.json", {})
