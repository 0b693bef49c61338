"""Issue 30's study findings: a kill or a full disk leaves a study every command opens; a session is in
the registry from its start; locks never block for ever; names are checked whole."""
from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from _study_data import PROTOCOL, registry_state, study_with_one_participant, write_protocol
from nao_trainer.cli import main
from nao_trainer.study.registry import open_study

HANG = 120  # seconds: only a hang reaches it


def _cli(*args, limit_bytes: int | None = None, env=None) -> subprocess.CompletedProcess:
    def limit():
        if limit_bytes is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return subprocess.run([sys.executable, "-m", "nao_trainer", *map(str, args)], capture_output=True, text=True,
                          timeout=HANG, preexec_fn=limit, env=env or dict(os.environ, QI_LOG_LEVEL="silent"))


def _wait(predicate, what: str) -> None:
    deadline = time.monotonic() + HANG
    while not predicate():
        assert time.monotonic() < deadline, f"hang: {what}"
        time.sleep(0.05)


def _rows(folder: Path) -> int:
    try:
        return max(0, len((folder / "turns.csv").read_text().splitlines()) - 1)
    except OSError:
        return 0


def _folders(root: Path, pseudonym: str) -> list[Path]:
    return sorted((root / "sessions").glob(f"{pseudonym}_*"))


def test_a_killed_study_next_is_listed_resumable_and_counted(tmp_path, capsys):
    """Finding 2: SIGKILL after some turns: status lists it, --resume continues it, and it counts once."""
    root = study_with_one_participant(tmp_path)
    capsys.readouterr()
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "study", "next", str(root), "P001", "--no-keys",
                             "--user-model", "1", "--turns", "12", "--speed", "5"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(os.environ, QI_LOG_LEVEL="silent"))
    try:
        _wait(lambda: _folders(root, "P001") and _rows(_folders(root, "P001")[0]) >= 2, "two turns")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    (entry,) = open_study(root).participants[0]["sessions"]
    assert entry["status"] == "running" and entry["number"] == 1  # registered when it started
    res = _cli("study", "status", root)
    assert res.returncode == 0 and "not yet recorded: 1 session(s)" in res.stdout, res.stdout + res.stderr
    assert f"P001 session 1: {_folders(root, 'P001')[0].name} (interrupted)" in res.stdout
    res = _cli("study", "next", root, "P001", "--resume", "--no-keys")
    assert res.returncode == 0, res.stderr
    assert "was interrupted; recorded as interrupted" in res.stderr and "(resumed)" in res.stderr
    (entry,) = open_study(root).participants[0]["sessions"]
    assert entry["status"] == "completed" and entry["folder"] == _folders(root, "P001")[0].name
    assert _rows(_folders(root, "P001")[0]) == 12 and entry["files"]["turns.csv"]
    res = _cli("study", "status", root)
    assert "not yet recorded" not in res.stdout and " 1  completed" in res.stdout


def test_a_session_folder_the_registry_does_not_know_is_shown_and_adopted(tmp_path, capsys):
    root = study_with_one_participant(tmp_path)
    orphan = root / "sessions" / "P001_20261102-100000"
    orphan.mkdir()
    (orphan / "session.json").write_text(json.dumps({"status": "completed", "exit_code": 0,
                                                     "started": "2026-11-02T10:00:00+00:00",
                                                     "ended": "2026-11-02T10:20:00+00:00"}))
    capsys.readouterr()
    assert main(["study", "status", str(root)]) == 0
    assert "P001 session 1: P001_20261102-100000 (completed)" in capsys.readouterr().out
    assert main(["study", "repair", str(root)]) == 0
    assert "1 session(s) recorded" in capsys.readouterr().out
    assert main(["study", "repair", str(root)]) == 0  # idempotent: nothing twice
    assert "0 session(s) recorded" in capsys.readouterr().out
    (s,) = open_study(root).participants[0]["sessions"]
    assert s["status"] == "completed" and s["folder"] == orphan.name


def test_withdraw_delete_counts_the_folders_it_deleted_recorded_or_not(tmp_path, capsys):
    root = study_with_one_participant(tmp_path)
    (root / "sessions" / "P001_20261102-100000").mkdir()  # on disk, not in the registry (a killed session)
    capsys.readouterr()
    assert main(["study", "withdraw", str(root), "P001", "--data", "delete"]) == 0
    out = capsys.readouterr().out
    assert "1 session folder(s) deleted" in out and not _folders(root, "P001")


@pytest.mark.parametrize("content", ["", "{", '{"pid": -1, "host": "%s"}', '{"pid": 0, "host": "%s"}'])
def test_a_lock_that_cannot_be_read_or_names_no_process_is_stale(tmp_path, capsys, content):
    """Finding 3: an empty lock (or pid -1: os.kill(-1, 0) succeeds) no longer blocks a participant."""
    import socket

    root = study_with_one_participant(tmp_path)
    (root / "locks").mkdir()
    (root / "locks" / "P001.lock").write_text(content.replace("%s", socket.gethostname()))
    res = _cli("study", "next", root, "P001", "--no-keys", "--user-model", "1")
    assert res.returncode == 0 and "stale lock of P001" in res.stderr, res.stderr
    assert not (root / "locks" / "P001.lock").exists()


def test_a_full_disk_while_taking_the_lock_leaves_no_empty_lock(tmp_path, capsys):
    root = study_with_one_participant(tmp_path)
    capsys.readouterr()
    res = _cli("study", "next", root, "P001", "--no-keys", "--user-model", "1", limit_bytes=0)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
    assert "free disk space" in res.stderr, res.stderr
    assert not (root / "locks" / "P001.lock").exists() and not list((root / "locks").glob(".*"))
    assert open_study(root).participants[0]["sessions"] == []


@pytest.mark.parametrize("args", [
    ("enrol", "{root}", "--consent-date", "2026-11-02", "--consent-version", "v1"),
    ("withdraw", "{root}", "P001", "--data", "keep"),
    ("amend", "{root}", "{amended}", "--reason", "holidays"),
])
def test_a_full_disk_in_a_command_changes_nothing_and_says_so_in_one_line(tmp_path, capsys, args):
    """Finding 5: every ENOSPC/EFBIG (here a file size limit below the registry's next page) is one line."""
    root = study_with_one_participant(tmp_path)
    amended = write_protocol(tmp_path, PROTOCOL.replace("max: 7", "max: 10"), "amended.yaml")
    capsys.readouterr()
    before = registry_state(root)
    res = _cli("study", *[a.format(root=root, amended=amended) for a in args], limit_bytes=4096)
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1, \
        res.stderr
    assert "nothing was changed" in res.stderr or "was not changed" in res.stderr, res.stderr
    assert registry_state(root) == before
    assert _cli("study", "status", root).returncode == 0


@pytest.mark.parametrize("edit, message", [
    (("pseudonym_prefix: P", 'pseudonym_prefix: "P\\n"'), "pseudonym_prefix"),
    (("name: unit-3arm", "name: ../../evil"), "protocol.name"),
    (("name: unit-3arm", 'name: "a\\nb"'), "protocol.name"),
    (("name: level2", 'name: "level2\\n"'), "arm name"),
])
def test_names_are_checked_whole(tmp_path, capsys, edit, message):
    """Finding 4: ``^...$`` let "P\\n" through; every name is checked with fullmatch, one validator."""
    text = PROTOCOL.replace("target_n: 12", "target_n: 12\npseudonym_prefix: P")
    assert edit[0] in text
    path = write_protocol(tmp_path, text.replace(*edit))
    code = main(["study", "init", str(path), "--out", str(tmp_path / "study")])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1 and ("\\n" in err or "/" in err), err
    assert not (tmp_path / "study").exists()


def test_an_amendment_changing_an_arm_or_the_blinding_needs_a_flag_and_is_marked(tmp_path, capsys):
    """Finding 9: level 2 -> level 4 after enrolment, or blinding off, only with --change-arms; recorded."""
    root = study_with_one_participant(tmp_path)
    capsys.readouterr()
    changed = write_protocol(tmp_path, PROTOCOL.replace("[L2]", "[L4]"), "v2.yaml")
    assert main(["study", "amend", str(root), str(changed), "--reason", "too easy"]) == 2
    assert "--change-arms" in capsys.readouterr().err and not open_study(root).registry["amendments"]
    assert main(["study", "amend", str(root), str(changed), "--reason", "too easy", "--change-arms"]) == 0
    assert "CHANGES ARMS: arm level2 changed" in capsys.readouterr().out
    (entry,) = open_study(root).registry["amendments"]
    assert entry["changes"] == ["arm level2 changed (schedule -> schedule)"]
    assert main(["study", "status", str(root)]) == 0
    assert "changed what arms do after 1 enrolment(s)" in capsys.readouterr().out
    blind = write_protocol(tmp_path, PROTOCOL.replace("blinding: false", "blinding: true"), "b.yaml")
    assert main(["study", "init", str(blind), "--out", str(tmp_path / "b")]) == 0
    assert main(["study", "enrol", str(tmp_path / "b"), "--consent-date", "2026-11-02", "--consent-version", "v1"]) == 0
    capsys.readouterr()
    assert main(["study", "amend", str(tmp_path / "b"), str(write_protocol(tmp_path, PROTOCOL, "open.yaml")),
                 "--reason", "x"]) == 2
    assert "blinding turned off" in capsys.readouterr().err


def test_a_kill_between_the_registry_and_the_protocol_copy_is_repaired_on_open(tmp_path, capsys):
    """Finding 1: amend commits protocol and registry together; a copy of the previous version left by a
    kill is restored, not refused."""
    root = study_with_one_participant(tmp_path)
    old = (root / "protocol.yaml").read_text()
    changed = write_protocol(tmp_path, PROTOCOL.replace("max: 7", "max: 10"), "v2.yaml")
    assert main(["study", "amend", str(root), str(changed), "--reason", "holidays"]) == 0
    (root / "protocol.yaml").write_text(old)  # what a kill after the commit, before the copy, leaves
    capsys.readouterr()
    assert main(["study", "status", str(root)]) == 0
    assert open_study(root).protocol.sessions.max_days == 10 and "max: 10" in (root / "protocol.yaml").read_text()
