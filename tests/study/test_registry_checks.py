"""A registry edited with its checksum recomputed: refused in one line, exit 2, nothing written.

The checksum only catches edits that do not recompute it; the registry must also agree with itself and
with the concealed allocation (each participant's arm is the one the sequence gave)."""
from __future__ import annotations

import json

import pytest

from _study_data import write_protocol
from nao_trainer.cli import main
from nao_trainer.files import canonical_sha256


def _participants(pl):
    return pl["participants"]


EDITS = {
    "arm swapped": (lambda pl: _participants(pl)[0].update(
        arm="random" if _participants(pl)[0]["arm"] != "random" else "level2"), "not the one the allocation gave"),
    "arm removed": (lambda pl: _participants(pl)[0].pop("arm"), "not the one the allocation gave"),
    "participants not a list": (lambda pl: pl.update(participants="x"), "not lists"),
    "protocol entry removed": (lambda pl: pl.pop("protocol"), "protocol entry"),
    "participant repeated": (lambda pl: _participants(pl).append(dict(_participants(pl)[0])), "repeated"),
    "pseudonym a path": (lambda pl: _participants(pl)[0].update(pseudonym="../../x"), "malformed"),
    "sessions not a list": (lambda pl: _participants(pl)[0].update(sessions=5), "sessions are malformed"),
    "allocation position": (lambda pl: pl.update(next={"": "a"}), "allocation position"),
    "position moved back": (lambda pl: pl.update(next={"": 0}), "allocation is at 0"),
    "withdrawal malformed": (lambda pl: _participants(pl)[0].update(withdrawn="yes"), "withdrawal"),
}


def _study(tmp_path, capsys):
    study = tmp_path / "study"
    assert main(["study", "init", str(write_protocol(tmp_path)), "--out", str(study)]) == 0
    for _ in range(2):
        assert main(["study", "enrol", str(study), "--consent-date", "2026-11-02", "--consent-version", "v1"]) == 0
    capsys.readouterr()
    return study


@pytest.mark.parametrize("case", sorted(EDITS))
def test_a_consistently_checksummed_but_edited_registry_is_refused_by_every_command(tmp_path, capsys, case):
    edit, message = EDITS[case]
    study = _study(tmp_path, capsys)
    doc = json.loads((study / "registry.json").read_text())
    edit(doc["payload"])
    doc["sha256"] = canonical_sha256(doc["payload"])
    (study / "registry.json").write_text(json.dumps(doc))
    before = sorted(p.relative_to(study) for p in study.rglob("*"))
    registry = (study / "registry.json").read_bytes()
    for args in (["status", study], ["enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1"],
                 ["next", study, "P001", "--no-keys"], ["analyse", study], ["export", study, "--bids", tmp_path / "b"],
                 ["withdraw", study, "P001", "--data", "delete"]):
        code = main(["study", *map(str, args)])
        out, err = capsys.readouterr()
        assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, (args, err)
        assert message in err and "registry.json" in err, err
    assert (study / "registry.json").read_bytes() == registry
    assert sorted(p.relative_to(study) for p in study.rglob("*")) == before and not (tmp_path / "b").exists()


def test_an_untouched_registry_still_opens(tmp_path, capsys):
    study = _study(tmp_path, capsys)
    assert main(["study", "status", str(study)]) == 0
    assert "enrolled 2 of 12" in capsys.readouterr().out
