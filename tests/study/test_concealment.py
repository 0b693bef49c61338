"""Issue 28 item 5: the operator plays the study and tries to learn the arms before unblinding.

Everything a blinded operator can read before a session runs (every byte of the study folder, the
protocol, every command's output) must not predict an arm better than chance: no arm or policy name in
it, no seed, every participant's row and sealed slot of the same shape whatever the arm, and the same
protocol initialised twice draws two different sequences (the protocol's seed decides nothing)."""
from __future__ import annotations

import sqlite3
from collections import Counter

import pytest

from _study_data import PROTOCOL, write_protocol
from nao_trainer.cli import main
from nao_trainer.study.registry import open_study

BLINDED = PROTOCOL.replace("blinding: false", "blinding: true")
SECRETS = ("personalised", "level2", "random", "schedule")


def _run(capsys, *args) -> str:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out + err


def _study(tmp_path, capsys, name="study"):
    protocol = write_protocol(tmp_path, BLINDED)
    root = tmp_path / name
    seen = _run(capsys, "study", "init", protocol, "--out", root)
    for _ in range(12):
        seen += _run(capsys, "study", "enrol", root, "--consent-date", "2026-11-02", "--consent-version", "v1")
    seen += _run(capsys, "study", "status", root)
    return root, seen


@pytest.mark.slow
def test_nothing_an_operator_reads_names_or_predicts_an_arm(tmp_path, capsys):
    root, seen = _study(tmp_path, capsys)
    # the operator's outputs: no arm, no policy (the seed is stored nowhere: drawn, used, forgotten)
    assert not any(s in seen for s in SECRETS), seen
    # every byte of the study folder but the protocol (its copy and its text in the registry list the arms,
    # as a protocol must) and the database's pages (read through SQL below, every value)
    blobs = {p: p.read_bytes() for p in root.rglob("*") if p.is_file() and p.name != "protocol.yaml"}
    for path, data in blobs.items():
        assert "registry.db" in path.name or not any(s.encode() in data for s in SECRETS), f"{path} names an arm"
    conn = sqlite3.connect(root / "registry.db")
    for (table,) in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'").fetchall():
        for row in conn.execute(f"SELECT * FROM {table}"):
            if table == "meta" and row[0] == "protocol_text":
                continue
            assert not any(s in str(v) for v in row for s in SECRETS), (table, row)
    rows = conn.execute("SELECT * FROM participants ORDER BY number").fetchall()
    sealed = [r[0] for r in conn.execute("SELECT sealed_arm FROM allocation ORDER BY position")]
    conn.close()
    # rows differ only in what does not depend on the arm: pseudonym, number, position, enrolment time
    assert len({(r[2], r[3], r[5], r[6], r[8]) for r in rows}) == 1
    assert [r[4] for r in rows] == list(range(12))  # the position is the enrolment order, for every arm
    assert len({len(t) for t in sealed}) == 1 and len(set(sealed)) == len(sealed)  # one length, never repeated
    # the study key is outside the study folder; without it not even nao-trainer can read an arm
    assert not any(b"=" in data[-2:] and len(data.strip()) == 44 for data in blobs.values())
    arms = [open_study(root).arm_of(f"P{i:03d}") for i in range(1, 13)]  # (what `study next` does internally)
    assert Counter(arms) == {"personalised": 4, "level2": 4, "random": 4}
    again, _ = _study(tmp_path, capsys, "again")  # the same protocol, the same seed in it: another sequence
    assert [open_study(again).arm_of(f"P{i:03d}") for i in range(1, 13)] != arms


def test_analysis_and_export_wait_for_a_recorded_unblinding(tmp_path, capsys):
    root, _ = _study(tmp_path, capsys)
    for args in (("analyse", root), ("export", root, "--bids", tmp_path / "bids")):
        assert main(["study", *map(str, args)]) == 2
        assert "study unblind" in capsys.readouterr().err
    out = _run(capsys, "study", "unblind", root, "--reason", "final analysis", "--who", "statistician")
    assert out.count("\t") == 12 and "unblinding recorded" in out
    (entry,) = open_study(root).registry["unblindings"]
    assert entry["who"] == "statistician" and entry["reason"] == "final analysis"
    assert "unblinded" in _run(capsys, "study", "status", root)
