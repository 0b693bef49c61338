"""A study folder of the JSON registry (nao-trainer before the database) is migrated by `study init`,
once, with a backup: participants, arms, sessions and amendments kept; session seeds unchanged."""
from __future__ import annotations

import hashlib

from _study_data import write_protocol
from nao_trainer.cli import main
from nao_trainer.study.protocol import load_protocol
from nao_trainer.study.registry import ALLOCATION, REGISTRY, file_sha256, open_study
from nao_trainer.study.runner import plan_next


def _json_study(tmp_path):
    """What `study init` + 3 enrolments + one session wrote before (registry.json, allocation.json)."""
    protocol_path = write_protocol(tmp_path)
    protocol = load_protocol(protocol_path)
    root = tmp_path / "study"
    (root / "sessions").mkdir(parents=True)
    (root / "protocol.yaml").write_text(protocol.text)
    arms = ["level2", "random", "personalised", "random", "personalised", "level2"] * 2
    ALLOCATION.write(root / "allocation.json", {"seed": 7, "block_size": 6, "sequences": {"": arms}})
    people = [{"pseudonym": f"P{i:03d}", "arm": arms[i - 1], "stratum": "", "allocation_index": i - 1,
               "consent_date": "2026-11-02", "consent_version": "v1", "enrolled": "2026-11-02T10:00:00+00:00",
               "withdrawn": None, "sessions": []} for i in (1, 2, 3)]
    people[0]["sessions"].append({"number": 1, "folder": "P001_20261102-100000", "status": "completed",
                                  "exit_code": 0, "started": None, "ended": "2026-11-02T10:30:00+00:00",
                                  "outside_interval": False, "protocol_sha256": protocol.sha256})
    (root / "sessions" / "P001_20261102-100000").mkdir()
    registry = {"protocol": {"name": protocol.name, "sha256": protocol.sha256, "source": str(protocol_path),
                             "base": str(tmp_path), "study_config": str(protocol.study_config),
                             "study_config_sha256": file_sha256(protocol.study_config)},
                "created": "2026-11-01T09:00:00+00:00", "amendments": [], "participants": people,
                "next": {"": 3}, "allocation_sha256": ""}
    ALLOCATION.write(root / "allocation.json", {"seed": 7, "block_size": 6, "sequences": {"": arms}})
    registry["allocation_sha256"] = file_sha256(root / "allocation.json")
    REGISTRY.write(root / "registry.json", registry)
    return root, protocol_path, arms


def test_a_json_study_is_migrated_once_with_a_backup(tmp_path, capsys):
    root, protocol_path, arms = _json_study(tmp_path)
    assert main(["study", "status", str(root)]) == 2
    assert "migrate it once" in capsys.readouterr().err
    assert main(["study", "init", str(protocol_path), "--out", str(root)]) == 0
    assert "JSON study migrated" in capsys.readouterr().out
    assert (root / "backup-json" / "registry.json").is_file() and not (root / "registry.json").exists()
    study = open_study(root)
    assert [study.arm_of(p["pseudonym"]) for p in study.participants] == arms[:3]
    (s,) = study.participants[0]["sessions"]
    assert s["status"] == "completed" and s["folder"] == "P001_20261102-100000"
    # the session seeds continue as the JSON study drew them (from the protocol's seed)
    expected = int(hashlib.sha256(b"7:P001:2").hexdigest()[:8], 16) % 2**31
    assert plan_next(study, "P001", {}).config.session.seed == expected
    assert main(["study", "enrol", str(root), "--consent-date", "2026-11-02", "--consent-version", "v1"]) == 0
    assert capsys.readouterr().out.startswith("P004: enrolled (arm random;")  # the old sequence continues
    assert main(["study", "init", str(protocol_path), "--out", str(root)]) == 2  # once
    assert "already holds a study" in capsys.readouterr().err


def test_a_json_registry_of_100000_nested_brackets_is_one_line(tmp_path, capsys):
    """Issue 30, finding 5: a registry of 100,000 nested '[' raised RecursionError (a traceback); the JSON study
    is now read only by the migration (`study init` on the folder), and every checksummed JSON file by JsonFormat."""
    folder = tmp_path / "old"
    folder.mkdir()
    (folder / "registry.json").write_text("[" * 100_000)
    code = main(["study", "init", str(write_protocol(tmp_path)), "--out", str(folder)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "nested too deeply" in err, err
