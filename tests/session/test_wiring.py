"""session.wiring: a failed write ends the session in one line naming the cause, with the answered turn on disk,
session.json saying why and no second exception in the clean-up; the pre-session check tries every folder written."""
from __future__ import annotations

import builtins
import errno
import json
from pathlib import Path

import pytest

from nao_trainer import files
from nao_trainer.errors import DataError, UserError
from nao_trainer.session.config import DEFAULT_CONFIG, load_config
from nao_trainer.session.record import CHECKPOINT, read_events, read_turns
from nao_trainer.session.resume import prepare_resume
from nao_trainer.session.wiring import RunOptions, run_session


def config(tmp_path: Path, **over):
    values = {"session.turns": 5, "timing.speed": 50.0, "session.output": str(tmp_path / "out"), "eeg.mode": "off",
              "session.practice": False, "participant.pseudonym": "W1", "policy.kind": "usp:2", "session.seed": 4}
    values.update({k.replace("__", "."): v for k, v in over.items()})
    return load_config(DEFAULT_CONFIG, values)


class Turns:
    """An observer counting recorded turns (the injected failure starts after ``after`` of them)."""

    def __init__(self, after: int) -> None:
        self.after, self.rows = after, 0

    @property
    def failing(self) -> bool:
        return self.rows >= self.after

    def notify(self, kind: str, data: dict) -> None:
        if kind == "row" and data.get("success") is not None:
            self.rows += 1


def fail_writes(monkeypatch, turns: Turns, matches, code: int) -> None:
    """Fault injection at the files.py layer: its writes of matching paths fail with ``code`` once ``turns`` says so."""
    def failing_open(path, mode="r", *args, **kw):
        if "w" in mode and turns.failing and matches(str(path)):
            raise OSError(code, __import__("os").strerror(code), str(path))
        return builtins.open(path, mode, *args, **kw)

    monkeypatch.setattr(files, "open", failing_open, raising=False)


def session_folder(tmp_path: Path) -> Path:
    return next((tmp_path / "out").glob("W1_*"))


def test_a_full_disk_for_the_participant_state_keeps_the_answered_turn_and_says_why(tmp_path, monkeypatch, capsys):
    turns = Turns(after=2)
    fail_writes(monkeypatch, turns, lambda p: "/participants/" in p, errno.ENOSPC)
    with pytest.raises(DataError) as err:
        run_session(config(tmp_path), RunOptions(quiet=True, observer=turns))
    message = str(err.value)
    assert "\n" not in message and "the disk is full" in message and "run --resume" in message, message
    assert "warning" not in capsys.readouterr().err  # no second report from the clean-up
    folder = session_folder(tmp_path)
    rows = read_turns(folder)
    assert [r["turn"] for r in rows] == ["1", "2", "3"]  # turn 3 was answered: it is on disk
    assert json.loads((folder / CHECKPOINT).read_text())["completed"] == 3
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "error" and "the disk is full" in info["error"]

    # space again: the resumption learns turn 3 (recorded, not yet learned) and plays on
    monkeypatch.undo()
    cfg, resumption = prepare_resume(folder)
    result = run_session(cfg, RunOptions(quiet=True), resume=resumption)
    assert result.exit_code == 0 and [r["turn"] for r in read_turns(folder)] == ["1", "2", "3", "4", "5"]
    state = tmp_path / "out" / "participants" / "W1" / "policy_state.json"
    assert json.loads(state.read_text())["payload"]["live"]["turns_learned"] == 5


def test_too_many_open_files_at_the_checkpoint_is_one_line_and_session_json_says_why(tmp_path, monkeypatch):
    turns = Turns(after=1)
    fail_writes(monkeypatch, turns, lambda p: Path(p).name.startswith(f".{CHECKPOINT}.tmp"), errno.EMFILE)
    with pytest.raises(DataError, match=r"cannot write \(too many open files\); raise the limit"):
        run_session(config(tmp_path, policy__kind="schedule"), RunOptions(quiet=True, observer=turns))
    folder = session_folder(tmp_path)
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "error" and "too many open files" in info["error"]
    assert [r["turn"] for r in read_turns(folder)][:1] == ["1"]


def test_a_read_only_session_folder_for_session_json_still_closes_without_a_second_exception(tmp_path, monkeypatch):
    turns = Turns(after=1)
    fail_writes(monkeypatch, turns, lambda p: "/W1_" in p, errno.EROFS)  # every later write in the folder
    with pytest.raises(DataError, match=r"the file system is read-only"):
        run_session(config(tmp_path), RunOptions(quiet=True, observer=turns))
    folder = session_folder(tmp_path)
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "error" and "read-only" in info["error"]  # rewritten in place, the last resort
    assert any(e["event"] == "turn_end" for e in read_events(folder))


def test_the_pre_session_check_tries_the_participant_folder_before_anything_is_written(tmp_path):
    (tmp_path / "blocker").write_text("a file where the participant's folder would go")
    cfg = config(tmp_path, policy__state_path=str(tmp_path / "blocker" / "{pseudonym}" / "state.json"))
    # refused by the participant's lock or the pre-session check, whichever tries the folder first
    with pytest.raises(UserError, match=r"blocker/W1: cannot (write there|create the participant's folder)"):
        run_session(cfg, RunOptions(quiet=True))
    assert not list((tmp_path / "out").glob("W1_*"))  # refused before the robot moved or a folder was made


def test_a_console_port_in_use_leaves_no_session_folder(tmp_path):
    import socket

    from nao_trainer.errors import ConfigError

    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen(1)
    try:
        with pytest.raises(ConfigError, match=r"console: cannot listen on 127.0.0.1:\d+"):
            run_session(config(tmp_path, policy__kind="schedule"),
                        RunOptions(quiet=True, console=True, console_port=taken.getsockname()[1]))
    finally:
        taken.close()
    assert (tmp_path / "out").is_dir() and not list((tmp_path / "out").iterdir())  # no empty W1_* folder
