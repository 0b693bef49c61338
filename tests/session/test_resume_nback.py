"""`run --resume` of a killed n-back session (issue 26): the session continues with the task's own turns, and the
resumed turns present the same letter streams as an uninterrupted run of the same seed (the random stream is
restored; what the simulated observer presses depends on timing, so only the stimuli are compared)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nao_trainer.session.record import read_turns

STUDY = """\
study: {name: nback-resume}
task: {name: nback, settings: {fillers: 8, targets: 3, soa_s: 2.0}}
robot: {url: mock}
session: {turns: 4, practice: false}
timing: {speed: 20}
answers: {input: simulated}
policy: {kind: schedule, schedule: [L1, L2, L3, L4]}
eeg: {mode: "off", xdf: false}
"""


def _run(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, QI_LOG_LEVEL="silent"),
                            stdin=subprocess.DEVNULL)


@pytest.mark.slow
def test_a_killed_nback_session_resumes_with_the_same_streams(tmp_path):
    cfg = tmp_path / "nback.yaml"
    cfg.write_text(STUDY)
    flags = ["--config", str(cfg), "--seed", "5", "--pseudonym", "NB", "--quiet", "--no-keys"]
    whole = _run(*flags, "--out", str(tmp_path / "a"))
    killed = _run(*flags, "--out", str(tmp_path / "b"))
    try:
        deadline, folder = time.monotonic() + 90, None
        while time.monotonic() < deadline:
            found = list((tmp_path / "b").glob("NB_*"))
            if found and (found[0] / "turns.csv").exists() and len(read_turns(found[0])) >= 1:
                folder = found[0]
                break
            time.sleep(0.02)
        assert folder is not None, "the session did not play a turn"
        killed.send_signal(signal.SIGKILL)
        killed.wait(10)
    finally:
        killed.kill()
    assert whole.wait(120) == 0, whole.stderr.read()
    n_before = len(read_turns(folder))
    assert n_before < 4 and json.loads((folder / "session.json").read_text())["status"] == "running"
    before = (folder / "turns.csv").read_bytes()

    resumed = _run("--resume", str(folder), "--no-keys")
    out, err = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, err
    assert "resuming" in err and "status: completed" in out and "d′ by level" in out

    got, expected = read_turns(folder), read_turns(next((tmp_path / "a").glob("NB_*")))
    assert (folder / "turns.csv").read_bytes().startswith(before)  # appended, never rewritten
    assert [r["level"] for r in got] == ["1", "2", "3", "4"]  # the schedule went on where it stopped
    assert [r["stimuli"] for r in got] == [r["stimuli"] for r in expected]  # the same streams as unbroken
    assert [r["targets"] for r in got] == [r["targets"] for r in expected]
    for r in got:  # each row is a judged n-back block
        assert len(r["stimuli"]) == 8 + int(r["n"]) and int(r["hits"]) + int(r["misses"]) == 3
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "completed" and len(info["resumptions"]) == 1
