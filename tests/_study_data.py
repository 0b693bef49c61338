"""A small three-arm protocol for the study tests (tests/study/)."""
from __future__ import annotations

from pathlib import Path

BASE = """\
study: {name: unit}
robot: {url: mock}
session: {turns: 4, practice: false}
timing: {speed: 50}
answers: {input: simulated}
eeg: {mode: "off"}
"""
PROTOCOL = """\
protocol: {name: unit-3arm, description: three arms}
study_config: base.yaml
arms:
  - {name: personalised, policy: personalised}
  - {name: level2, policy: schedule, overrides: {policy.schedule: [L2]}}
  - {name: random, policy: random}
sessions: {per_participant: 2, interval_days: {min: 0, max: 7}}
target_n: 12
allocation: {method: blocked, block_size: 6, seed: 7}
blinding: false
outcomes: {primary: score, secondary: [engagement, success_rate]}
analysis: {model: "outcome ~ arm + session + (1|participant)", reference_arm: level2}
"""


def write_protocol(folder: Path, text: str = PROTOCOL, name: str = "protocol.yaml") -> Path:
    (folder / "base.yaml").write_text(BASE)
    (folder / name).write_text(text)
    return folder / name


def study_with_one_participant(tmp_path: Path) -> Path:
    """``study init`` of the protocol above under ``tmp_path/study`` and one ``study enrol``; the study folder."""
    from nao_trainer.cli import main

    root = tmp_path / "study"
    assert main(["study", "init", str(write_protocol(tmp_path)), "--out", str(root)]) == 0
    assert main(["study", "enrol", str(root), "--consent-date", "2026-11-02", "--consent-version", "v1"]) == 0
    return root


def edit_registry(root: Path, sql: str, params: tuple = ()) -> None:
    """Edit a study's registry.db behind nao-trainer's back (what a careless or hostile user can do with the
    sqlite3 shell)."""
    import sqlite3

    conn = sqlite3.connect(root / "registry.db", isolation_level=None)
    try:
        conn.execute(sql, params) if params else conn.executescript(sql)
    finally:
        conn.close()


def registry_state(root: Path) -> dict:
    """The registry's contents (to compare before and after a refused command)."""
    from nao_trainer.study.registry import open_study

    reg = open_study(root).registry
    return {k: v for k, v in reg.items()}


#: two sealed allocation slots swapped (each a valid ciphertext of the study's key)
SWAP = ("UPDATE allocation SET position = 1000 WHERE position = 0; UPDATE allocation SET position = 0 WHERE "
        "position = 1; UPDATE allocation SET position = 1 WHERE position = 1000")
