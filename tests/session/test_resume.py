"""`nao-trainer run --resume SESSION_DIR`: a session killed with SIGKILL continues as if never interrupted."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nao_trainer.errors import DataError
from nao_trainer.session.record import read_events, read_turns
from nao_trainer.session.resume import prepare_resume

ROOT = Path(__file__).resolve().parents[2]
TIMING = {"start_time", "reaction_time", "completion_time"}  # wall-clock columns differ between runs


def study(tmp_path: Path) -> Path:
    text = (ROOT / "config" / "studies" / "demo.yaml").read_text()
    text = text.replace("mode: simulated", 'mode: "off"').replace("speed: 25", "speed: 10")
    text = text.replace('state_path: "{session}"', "state_path: null")  # per participant (the default)
    # Both runs must see the same presses: without a debounce no press of the simulated hand can be
    # merged with the one before when the machine is busy (the comparison is about the random streams).
    text = text.replace("answers:\n  input: simulated", "answers:\n  input: simulated\n  debounce_s: 0.0")
    path = tmp_path / "study.yaml"
    path.write_text(text)
    return path


def run(*args: str, **kw) -> subprocess.Popen:
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    return subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, stdin=subprocess.DEVNULL, **kw)


def comparable(rows):
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


def test_a_killed_session_resumes_and_plays_the_same_turns_as_an_uninterrupted_one(tmp_path):
    cfg = study(tmp_path)
    assert "debounce_s: 0.0" in cfg.read_text()
    flags = ["--config", str(cfg), "--turns", "10", "--seed", "77", "--pseudonym", "R", "--quiet"]
    whole = run(*flags, "--out", str(tmp_path / "a"))
    killed = run(*flags, "--out", str(tmp_path / "b"))
    try:
        deadline = time.monotonic() + 90
        folder = None
        while time.monotonic() < deadline:
            folders = list((tmp_path / "b").glob("R_*"))
            if folders and (folders[0] / "turns.csv").exists() and len(read_turns(folders[0])) >= 4:
                folder = folders[0]
                break
            time.sleep(0.02)
        assert folder is not None, "the session did not play 4 turns"
        killed.send_signal(signal.SIGKILL)
        killed.wait(10)
    finally:
        killed.kill()
    assert whole.wait(120) == 0, whole.stderr.read()
    before = (folder / "turns.csv").read_bytes()
    n_before = len(read_turns(folder))
    assert json.loads((folder / "session.json").read_text())["status"] == "running"  # killed: never closed
    shutil.copytree(folder, tmp_path / "copy")

    resumed = run("--resume", str(folder))
    out, err = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, err
    assert "resuming" in err and "status: completed" in out

    expected = read_turns(next((tmp_path / "a").glob("R_*")))
    got = read_turns(folder)
    assert (folder / "turns.csv").read_bytes().startswith(before)  # appended, never rewritten
    assert len(got) == 10 and n_before < 10
    assert comparable(got) == comparable(expected)
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "completed" and len(info["resumptions"]) == 1
    assert info["resumptions"][0]["after_turn"] in (n_before, n_before + 1)  # +1: killed between checkpoint and row
    resumed_ev = [e for e in read_events(folder) if e["event"] == "resumed"]
    assert len(resumed_ev) == 1 and resumed_ev[0]["after_turn"] >= n_before

    # refused: a complete folder, another version, a changed configuration; flags with --resume
    res = run("--resume", str(folder))
    _, err = res.communicate(timeout=60)
    assert res.returncode == 2 and "the session is complete" in err and "Traceback" not in err
    with pytest.raises(DataError, match="another|written by nao-trainer 0.0.1"):
        other = tmp_path / "other"
        shutil.copytree(tmp_path / "copy", other)
        info = json.loads((other / "session.json").read_text())
        info["nao_trainer"] = "0.0.1"
        (other / "session.json").write_text(json.dumps(info))
        prepare_resume(other)
    prepare_resume(tmp_path / "copy")  # still resumable before the study changes
    cfg.write_text(cfg.read_text().replace("turns: 25", "turns: 24"))
    with pytest.raises(DataError, match="configuration changed since the session started"):
        prepare_resume(tmp_path / "copy")
    res = run("--resume", str(tmp_path / "copy"), "--turns", "3")
    _, err = res.communicate(timeout=60)
    assert res.returncode == 2 and "drop session.turns" in err


def test_a_folder_without_a_completed_turn_or_session_json_is_refused(tmp_path):
    with pytest.raises(DataError, match="not a session folder"):
        prepare_resume(tmp_path)
    (tmp_path / "session.json").write_text(json.dumps({"status": "interrupted", "nao_trainer": __import__("nao_trainer").__version__}))
    with pytest.raises(DataError, match="no completed turn to resume from"):
        prepare_resume(tmp_path)
