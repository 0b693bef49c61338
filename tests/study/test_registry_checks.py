"""A registry edited behind nao-trainer's back (the sqlite3 shell): refused in one line by every command,
exit 2, nothing written. The registry's HMAC (a key outside the study folder) covers every row, so a
participant removed with the allocation position moved back (issue 30, finding 9) is caught like any edit;
a registry too deep or not a database is refused the same way."""
from __future__ import annotations

import pytest

from _study_data import SWAP, edit_registry, write_protocol
from nao_trainer.cli import main

EDITS = {
    "arm slot swapped": SWAP,
    "participant moved to another slot": "UPDATE participants SET allocation_index = 5 WHERE number = 1",
    "last participant removed, position moved back": "DELETE FROM participants WHERE number = 2",
    "position moved back": "UPDATE meta SET value = '{\"\": 1}' WHERE key = 'next'",
    "pseudonym a path": "UPDATE participants SET pseudonym = '../../x' WHERE number = 1",
    "pseudonym with a newline": "UPDATE participants SET pseudonym = 'P' || char(10) || '001' WHERE number = 1",
    "withdrawal forged": "UPDATE participants SET withdrawn = '{\"data\": \"keep\"}' WHERE number = 1",
    "protocol entry nested 100000 deep": "UPDATE meta SET value = '" + "[" * 100000 + "' WHERE key = 'protocol'",
    "a session added": "INSERT INTO sessions (key, pseudonym, number, status, protocol_sha256) "
                       "VALUES ('k', 'P001', 1, 'completed', 'x')",
}


def _study(tmp_path, capsys):
    study = tmp_path / "study"
    assert main(["study", "init", str(write_protocol(tmp_path)), "--out", str(study)]) == 0
    for _ in range(2):
        assert main(["study", "enrol", str(study), "--consent-date", "2026-11-02", "--consent-version", "v1"]) == 0
    capsys.readouterr()
    return study


COMMANDS = (["status"], ["enrol", "--consent-date", "2026-11-02", "--consent-version", "v1"],
            ["next", "P001", "--no-keys"], ["analyse"], ["withdraw", "P001", "--data", "delete"], ["repair"],
            ["amend", "protocol.yaml", "--reason", "x"])


def _refused_by_every_command(tmp_path, capsys, study, message):
    before = sorted(p.relative_to(study) for p in study.rglob("*") if "registry.db" not in p.name)
    registry = (study / "registry.db").read_bytes()
    for words in COMMANDS:
        args = [words[0], str(study), *[str(tmp_path / w) if w.endswith(".yaml") else w for w in words[1:]]]
        code = main(["study", *args])
        out, err = capsys.readouterr()
        assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, (args, err)
        assert message in err and "registry.db" in err, err
    assert (study / "registry.db").read_bytes() == registry
    assert sorted(p.relative_to(study) for p in study.rglob("*") if "registry.db" not in p.name) == before


@pytest.mark.parametrize("case", sorted(EDITS))
def test_a_registry_edited_with_the_sqlite_shell_is_refused_by_every_command(tmp_path, capsys, case):
    study = _study(tmp_path, capsys)
    edit_registry(study, EDITS[case])
    _refused_by_every_command(tmp_path, capsys, study, "edited outside nao-trainer")


def test_a_file_that_is_not_a_database_is_refused(tmp_path, capsys):
    study = _study(tmp_path, capsys)
    for extra in ("registry.db-wal", "registry.db-shm"):
        (study / extra).unlink(missing_ok=True)
    (study / "registry.db").write_bytes(b"[" * 100000)
    _refused_by_every_command(tmp_path, capsys, study, "not a readable study registry")


def test_an_untouched_registry_still_opens(tmp_path, capsys):
    study = _study(tmp_path, capsys)
    assert main(["study", "status", str(study)]) == 0
    assert "enrolled 2 of 12" in capsys.readouterr().out
