"""Robustness of `nao-trainer run`, each case against the stand-in over real qi in a subprocess:
an unreachable robot, a robot lost and back mid-session, a robot lost for good, and Ctrl-C."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest


from nao_trainer.session.record import read_events, read_turns
from nao_trainer.robot.standin import spawn_standin


def run_cli(*args: str) -> subprocess.Popen:
    env = dict(os.environ, QI_LOG_LEVEL="silent", PYTHONUNBUFFERED="1")
    pseudonym = () if "--pseudonym" in args else ("--pseudonym", "P1")  # a robot address needs an entered one
    return subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", *args, *pseudonym], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


def study(tmp_path: Path, text: str) -> str:
    path = tmp_path / "study.yaml"
    path.write_text(text)
    return str(path)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_rows(out: Path, n: int, proc: subprocess.Popen, timeout_s: float = 60) -> Path:
    """The session folder once its turns.csv holds ``n`` rows."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        folders = list(out.glob("*_*"))
        if folders and (folders[0] / "turns.csv").exists() and len(read_turns(folders[0])) >= n:
            return folders[0]
        time.sleep(0.05)
    raise AssertionError(f"no {n} turns within {timeout_s} s")


def wait_port_free(port: int, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) != 0:
                return
        time.sleep(0.05)
    raise AssertionError(f"port {port} still in use")


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_unreachable_robot_fails_fast_and_writes_nothing(tmp_path):
    out = tmp_path / "out"
    proc = run_cli("--config", str(Path(__file__).resolve().parents[2] / "config" / "default.yaml"),
                   "--robot", f"tcp://127.0.0.1:{free_port()}", "--out", str(out))
    _, err = proc.communicate(timeout=60)  # a generous limit for a hang; "fast" is the refusal's message
    assert proc.returncode == 3
    lines = [ln for ln in err.splitlines() if "error" in ln]
    assert len(lines) == 1 and "cannot reach the robot" in lines[0] and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())


def test_silent_endpoint_times_out_within_the_configured_deadline(tmp_path):
    out = tmp_path / "out"
    with socket.socket() as server:  # accepts TCP but never speaks qi
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        cfg = study(tmp_path, "robot:\n  connect_deadline_s: 1.5\n")
        proc = run_cli("--config", cfg, "--robot", f"tcp://127.0.0.1:{port}", "--out", str(out))
        _, err = proc.communicate(timeout=60)  # only a hang reaches this; the deadline is in the message
    assert proc.returncode == 3 and "within 1.5 s" in err
    assert not out.exists() or not any(out.iterdir())


def test_robot_lost_and_back_pauses_replays_and_completes(tmp_path):
    out = tmp_path / "out"
    standin, url = spawn_standin(speed=20)
    port = int(url.rsplit(":", 1)[1])
    cfg = study(tmp_path, "robot:\n  max_reconnect_s: 30\n  backoff_initial_s: 0.2\n  backoff_max_s: 1\n"
                          "session:\n  practice: false\n")
    proc = run_cli("--config", cfg, "--robot", url, "--input", "simulated", "--turns", "6", "--speed", "20",
                   "--out", str(out), "--seed", "3")
    restarted = None
    try:
        folder = wait_rows(out, 2, proc)
        standin.kill()
        standin.wait()
        wait_port_free(port)
        time.sleep(2.0)  # the robot is away for a while
        restarted, _ = spawn_standin(port=port, speed=20)
        _, err = proc.communicate(timeout=90)
    finally:
        stop(proc)
        for p in (standin, restarted):
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGINT)
                p.wait(10)
    assert proc.returncode == 0, err
    rows = read_turns(folder)
    completed = [r for r in rows if r["success"] in ("True", "False")]
    interrupted = [r for r in rows if r["notes"].startswith("interrupted: robot lost")]
    assert [int(r["turn"]) for r in completed] == [1, 2, 3, 4, 5, 6]
    assert len(interrupted) == 1  # one loss, one interrupted turn (no spurious second pause after the return)
    replay = next(r for r in completed if r["turn"] == interrupted[0]["turn"])
    assert replay["action"] == interrupted[0]["action"] and replay["state"] == interrupted[0]["state"]
    assert "replay of interrupted turn" in replay["notes"]
    events = read_events(folder)
    names = [e["event"] for e in events]
    assert "robot_lost" in names and "reconnected" in names and "turn_interrupted" in names
    assert any(e["event"] == "transition" and e["dest"] == "paused" for e in events)
    assert any(e["event"] == "transition" and e["trigger"] == "resume_turn" for e in events)
    assert "reconnecting" in err and json.loads((folder / "session.json").read_text())["status"] == "completed"


def test_robot_lost_for_good_ends_cleanly_with_every_completed_turn(tmp_path):
    out = tmp_path / "out"
    standin, url = spawn_standin(speed=20)
    cfg = study(tmp_path, "robot:\n  max_reconnect_s: 2\n  backoff_initial_s: 0.2\n  backoff_max_s: 0.5\n"
                          "session:\n  practice: false\n")
    proc = run_cli("--config", cfg, "--robot", url, "--turns", "20", "--speed", "20", "--out", str(out))
    try:
        folder = wait_rows(out, 2, proc)
        standin.kill()
        standin.wait()
        _, err = proc.communicate(timeout=60)  # ends by robot.max_reconnect_s (2 s); a hang fails here
    finally:
        stop(proc)
    assert proc.returncode == 3, err
    rows = read_turns(folder)
    done = [r for r in rows if r["success"] in ("True", "False")]
    assert len(done) >= 2 and [int(r["turn"]) for r in done] == list(range(1, len(done) + 1))
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "robot lost" and info["exit_code"] == 3
    names = [e["event"] for e in read_events(folder)]
    assert "give_up" in names and names.count("reconnect_failed") >= 2
    assert "Traceback" not in err


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_ctrl_c_leaves_the_robot_safe_and_exits_130(tmp_path, signum):
    out = tmp_path / "out"
    proc = run_cli("--turns", "25", "--speed", "25", "--out", str(out), "--no-practice")  # stopped after turn 1
    try:
        folder = wait_rows(out, 1, proc)
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "interrupted" and info["exit_code"] == 130 and "ended" in info
    rows = read_turns(folder)
    assert 1 <= len(rows) < 25
    transcript = [json.loads(ln) for ln in (folder / "robot_transcript.jsonl").read_text().splitlines()]
    last_posture = [e["args"][0] for e in transcript if e["method"] == "goToPosture"][-1]
    last_leds = [e["args"] for e in transcript if e["method"] == "fadeRGB"][-1]
    assert last_posture in ("Crouch", "Sit") and last_leds[1] == 0xFFFFFF
    events = read_events(folder)
    names = [e["event"] for e in events]
    assert "interrupted" in names and "safe_state" in names
    by = next(e["by"] for e in events if e["event"] == "interrupted")
    assert by == ("operator (Ctrl-C)" if signum == signal.SIGINT else "SIGTERM received")


@pytest.mark.slow
def test_ctrl_c_cuts_a_long_utterance_short(tmp_path):
    """At real speed the instructions take ~15 s; Ctrl-C must not wait for them to end."""
    out = tmp_path / "out"
    proc = run_cli("--turns", "3", "--speed", "1", "--out", str(out), "--no-practice", "--eeg", "off",
                   "--policy", "random")
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # the greeting is said; the instructions have begun
            assert proc.poll() is None, proc.communicate()
            events = list(out.glob("*/events.jsonl"))
            if events and '"what": "greeting"' in events[0].read_text():
                break
            time.sleep(0.05)
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    folder = events[0].parent
    methods = [json.loads(ln)["method"] for ln in (folder / "robot_transcript.jsonl").read_text().splitlines()]
    assert "stopAll" in methods
