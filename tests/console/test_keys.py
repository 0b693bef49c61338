"""Operator keys: the reader on a pseudo-terminal (fast), and `nao-trainer run` on a real terminal (tmux)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import termios
import time
import uuid
from pathlib import Path

import pytest

from nao_trainer.console.keys import HELP, KeyReader
from nao_trainer.ports import CommandQueue
from nao_trainer.session.record import read_events, read_turns

ROOT = Path(__file__).resolve().parents[2]


def wait_for(predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    pytest.fail(f"timed out after {timeout} s waiting for {what}")


def test_keys_become_commands_and_the_terminal_is_restored(tmp_path):
    master, slave = os.openpty()
    try:
        before = termios.tcgetattr(slave)
        queue = CommandQueue()
        out = open(tmp_path / "out.txt", "w+")
        reader = KeyReader.start_if_terminal(queue, out, fd=slave)
        assert reader is not None
        assert not termios.tcgetattr(slave)[3] & termios.ICANON  # character mode while it runs
        os.write(master, b"pxrSi")
        wait_for(lambda: len(queue) == 4, 5, "four commands")
        cmds = queue.drain()
        assert [(c.kind, c.source) for c in cmds] == [("pause", "keys"), ("resume", "keys"), ("stop", "keys"),
                                                       ("invalid", "keys")]
        reader.close()
        assert termios.tcgetattr(slave) == before
        out.seek(0)
        text = out.read()
        assert HELP in text and "[p] pause after the current utterance: requested" in text
    finally:
        os.close(master)
        os.close(slave)


def test_no_reader_without_a_terminal(tmp_path):
    r, w = os.pipe()
    try:
        assert KeyReader.start_if_terminal(CommandQueue(), None, fd=r) is None
    finally:
        os.close(r)
        os.close(w)


def _tmux() -> str:
    path = shutil.which("tmux")
    if path is None:
        pytest.skip("tmux is not installed (apt-get install -y tmux; .ci/run installs it): "
                    "the real-terminal test of the operator keys did not run")
    return path


@pytest.mark.slow
def test_keys_pause_resume_and_stop_a_session_on_a_real_terminal(tmp_path):
    tmux = _tmux()
    sock = f"nao-keys-{uuid.uuid4().hex[:8]}"
    out, done = tmp_path / "out", tmp_path / "done.txt"
    cmd = (f"cd {tmp_path} && QI_LOG_LEVEL=silent {sys.executable} -m nao_trainer run --turns 60 --speed 16 --eeg off "
           f"--policy random --no-practice --out {out} --pseudonym K; echo EXIT=$? > {done}; "
           f"stty -a >> {done}; sleep 60")
    env = dict(os.environ)
    subprocess.run([tmux, "-L", sock, "new-session", "-d", "-s", "k", "-x", "160", "-y", "40", cmd], check=True, env=env)

    def keys(k: str) -> None:
        subprocess.run([tmux, "-L", sock, "send-keys", "-t", "k", k], check=True)

    def events():
        folders = list(out.iterdir()) if out.exists() else []
        return read_events(folders[0]) if folders and (folders[0] / "events.jsonl").exists() else []

    try:
        folder = wait_for(lambda: out.exists() and next(iter(out.iterdir()), None), 60, "the session folder")
        screen = subprocess.run([tmux, "-L", sock, "capture-pane", "-p", "-t", "k"], capture_output=True, text=True).stdout
        wait_for(lambda: (folder / "turns.csv").exists() and len(read_turns(folder)) >= 2, 60, "two turns")
        assert HELP in subprocess.run([tmux, "-L", sock, "capture-pane", "-p", "-t", "k", "-S", "-200"],
                                      capture_output=True, text=True).stdout or HELP in screen
        keys("p")
        wait_for(lambda: any(e["event"] == "transition" and e["dest"] == "operator_pause" for e in events()), 30, "the pause")
        time.sleep(0.5)
        n_paused = len(read_turns(folder))
        time.sleep(1.0)
        assert len(read_turns(folder)) == n_paused  # nothing played while paused
        keys("r")
        wait_for(lambda: any(e["event"] == "transition" and e["trigger"] == "resume_turn" for e in events()), 30, "the resume")
        wait_for(lambda: len(read_turns(folder)) >= n_paused + 1, 30, "a turn after the resume")
        keys("s")
        text = wait_for(lambda: done.exists() and "EXIT=" in done.read_text() and "speed" in done.read_text()
                        and done.read_text(), 60, "the end of the run")
    finally:
        subprocess.run([tmux, "-L", sock, "kill-server"], capture_output=True)
    assert "EXIT=5" in text  # the operator stop's exit code
    assert " icanon" in text and " echo" in text and "-icanon" not in text  # the terminal was restored
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "stopped" and info["exit_code"] == 5
    cmds = [(e["kind"], e["source"], e["accepted"]) for e in events() if e["event"] == "command"]
    assert cmds == [("pause", "keys", True), ("resume", "keys", True), ("stop", "keys", True)]
    said = [e["args"][0] for e in map(json.loads, (folder / "robot_transcript.jsonl").read_text().splitlines())
            if e["method"] == "say"]
    assert "Sorry, I need a short break. Please wait a moment." in said and "Thank you" in " ".join(said[-2:])
    postures = [e["args"][0] for e in map(json.loads, (folder / "robot_transcript.jsonl").read_text().splitlines())
                if e["method"] == "goToPosture"]
    assert postures[-1] == "Crouch"  # the safe posture
