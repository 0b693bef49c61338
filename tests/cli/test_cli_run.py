"""`nao-trainer run` end to end, as users start it (a subprocess), against the stand-in over qi."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from nao_trainer.files import PROJECT_ROOT
from nao_trainer.session.record import read_events, read_turns

#: A study for a robot address: real speed, no simulation the flags do not ask for (the demo study is refused).
DEFAULT_STUDY = str(PROJECT_ROOT / "config" / "default.yaml")


def cli(*args: str, stdin=None, timeout: float = 120) -> subprocess.CompletedProcess:
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    return subprocess.run([sys.executable, "-m", "nao_trainer", "run", *args], capture_output=True, text=True,
                          env=env, timeout=timeout, stdin=stdin)


def only_folder(out: Path) -> Path:
    folders = list(out.iterdir())
    assert len(folders) == 1, folders
    return folders[0]




def test_default_output_is_sessions_in_the_current_folder(tmp_path):
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--turns", "2", "--speed", "50", "--quiet"],
                         capture_output=True, text=True, cwd=tmp_path, env=dict(os.environ, QI_LOG_LEVEL="silent"),
                         timeout=120)
    assert res.returncode == 0, res.stderr
    assert len(read_turns(only_folder(tmp_path / "sessions"))) == 2
    assert "turn " not in res.stderr.replace("turns completed", "")  # --quiet: no progress lines


def test_invalid_config_starts_nothing(tmp_path):
    study = tmp_path / "bad.yaml"
    study.write_text("session:\n  turns: 25\ntiming:\n  sped: 3\n")
    res = cli("--config", str(study), "--out", str(tmp_path / "out"))
    assert res.returncode == 2
    assert res.stderr.strip() == (f"nao-trainer run: error: {study}:4: unknown key 'timing.sped'; "
                                  "did you mean 'timing.speed'?")
    assert not (tmp_path / "out").exists()
    res = cli("--turns", "0", "--out", str(tmp_path / "out"))
    assert res.returncode == 2 and "'session.turns' must be >= 1" in res.stderr and not (tmp_path / "out").exists()


def test_user_model_drives_the_simulated_participant(tmp_path):
    res = cli("--user-model", "1", "--turns", "3", "--speed", "50", "--eeg", "off", "--out", str(tmp_path), "--quiet")
    assert res.returncode == 0, res.stderr
    info = json.loads((only_folder(tmp_path) / "session.json").read_text())
    assert info["user_model"] == "cluster-1" and info["config"]["values"]["participant_model"]["user_model"] == "1"
    res = cli("--user-model", "9", "--out", str(tmp_path / "x"))
    assert res.returncode != 0 and "unknown user model '9'" in res.stderr and not (tmp_path / "x").exists()




def test_keyboard_answers_end_to_end(tmp_path):
    """A person typing: the right answer (after keys typed too early), a wrong one with an invalid key,
    one key too many, and no answer at all."""
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", "--input", "keyboard", "--pseudonym", "P1", "--turns", "4",
                             "--speed", "20", "--no-practice", "--out", str(out), "--seed", "4", "--eeg", "off"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, QI_LOG_LEVEL="silent"))

    def typist():
        answered, early = set(), set()
        deadline = time.monotonic() + 90
        while proc.poll() is None and time.monotonic() < deadline:
            folders = list(out.glob("*")) if out.exists() else []
            if folders and (folders[0] / "events.jsonl").exists():
                try:
                    events = read_events(folders[0])
                except ValueError:  # caught the session mid-line: read again on the next pass
                    time.sleep(0.02)
                    continue
                seqs = {e["turn"]: e["sequence"] for e in events if e["event"] == "turn_start"}
                beeps = {e["turn"] for e in events if e["event"] == "beep"}
                for turn, seq in seqs.items():
                    if turn == 1 and turn not in early:
                        proc.stdin.write("cc")  # while the robot speaks: must be discarded
                        proc.stdin.flush()
                        early.add(turn)
                    if turn in beeps and turn not in answered:
                        text = {1: seq.lower(), 2: "x" + seq[1:].lower(), 3: seq.lower() + "a", 4: ""}[turn]
                        proc.stdin.write(text + "\n")
                        proc.stdin.flush()
                        answered.add(turn)
            time.sleep(0.02)

    t = threading.Thread(target=typist, daemon=True)
    t.start()
    proc.wait(timeout=120)
    t.join(5)
    err = proc.stderr.read()
    for f in (proc.stdin, proc.stdout, proc.stderr):
        f.close()
    assert proc.returncode == 0, err
    rows = read_turns(only_folder(out))
    assert [r["success"] for r in rows] == ["True", "False", "False", "False"], [(r["sequence"], r["response"], r["notes"], r["completion_time"]) for r in rows]
    assert rows[0]["response"] == rows[0]["sequence"]
    assert rows[1]["response"].startswith("?") and "invalid key 'x'" in rows[1]["notes"]
    assert float(rows[0]["reaction_time"]) > 0
    assert rows[2]["response"] == rows[2]["sequence"] + "A" and "too many presses" in rows[2]["notes"]
    assert rows[3]["response"] == "" and rows[3]["notes"] == "timeout: no answer" and rows[3]["reaction_time"] == ""


@pytest.mark.slow
def test_naoqi_29_credentials_come_from_the_environment_and_stay_out_of_files(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if k not in ("NAO_USER", "NAO_PASSWORD")}
    env["QI_LOG_LEVEL"] = "silent"
    base = [sys.executable, "-m", "nao_trainer", "run", "--config", DEFAULT_STUDY, "--robot", f"tcps://127.0.0.1:{port}",
            "--out", str(tmp_path / "a"), "--pseudonym", "P1"]
    res = subprocess.run(base, capture_output=True, text=True, env=env, timeout=60)
    assert res.returncode == 2 and "NAO_USER" in res.stderr and "NAO_PASSWORD" in res.stderr
    secret = "pw-0f9e8d7c"
    res = subprocess.run(base, capture_output=True, text=True, env=dict(env, NAO_USER="nao", NAO_PASSWORD=secret), timeout=60)
    assert res.returncode == 3 and secret not in res.stderr + res.stdout
    # a whole session with the variables set: the secret is in no file
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--turns", "2", "--speed", "50", "--out",
                          str(tmp_path / "b"), "--quiet"], capture_output=True, text=True,
                         env=dict(env, NAO_USER="nao", NAO_PASSWORD=secret), timeout=60)
    assert res.returncode == 0, res.stderr
    for f in only_folder(tmp_path / "b").rglob("*"):
        if f.is_file():
            assert secret not in f.read_text(errors="replace"), f


def test_tactile_answers_from_any_naoqi_endpoint(tmp_path):
    """`--robot tcp://HOST:PORT --input tactile`: a person pressing the head buttons of a separate robot process."""
    import signal

    from nao_trainer.robot.standin import StandInClient, spawn_standin

    robot, url = spawn_standin(speed=20)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", "--config", DEFAULT_STUDY, "--robot", url, "--input", "tactile", "--pseudonym", "P1",
                             "--turns", "2", "--speed", "20", "--no-practice", "--out", str(out), "--seed", "8"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, QI_LOG_LEVEL="silent"))
    hand = StandInClient.connect(url)
    try:
        answered: set[int] = set()
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline and len(answered) < 2:
            folders = list(out.glob("*")) if out.exists() else []
            if folders and (folders[0] / "events.jsonl").exists():
                try:
                    events = read_events(folders[0])
                except ValueError:  # caught the session mid-line: read again on the next pass
                    time.sleep(0.02)
                    continue
                seqs = {e["turn"]: e["sequence"] for e in events if e["event"] == "turn_start"}
                for turn in {e["turn"] for e in events if e["event"] == "beep"} - answered:
                    wrong = {"A": "B", "B": "C", "C": "A"}[seqs[turn][0]] + seqs[turn][1:]  # first letter wrong
                    for letter in seqs[turn] if turn == 1 else wrong:
                        hand.press(letter)
                        time.sleep(0.03)
                    answered.add(turn)
            time.sleep(0.02)
        _, err = proc.communicate(timeout=60)
    finally:
        hand.close()
        if proc.poll() is None:
            proc.kill()
        robot.send_signal(signal.SIGINT)
        robot.wait(10)
    assert proc.returncode == 0, err
    rows = read_turns(only_folder(out))
    assert rows[0]["success"] == "True" and rows[0]["response"] == rows[0]["sequence"]
    assert rows[1]["success"] == "False" and len(rows[1]["response"]) == len(rows[1]["sequence"])


def test_torn_policy_state_is_refused_before_the_robot_moves(tmp_path):
    state = tmp_path / "p01_policy_state.json"
    state.write_text('{"format": "nao-trainer/user-specific-policy", "format_ver')  # torn mid-write
    study = tmp_path / "study.yaml"
    study.write_text(f"policy:\n  kind: usp:1\n  state_path: {state}\n")
    res = cli("--config", str(study), "--out", str(tmp_path / "out"), "--turns", "2", "--speed", "50")
    assert res.returncode == 2, res.stderr
    assert str(state) in res.stderr and "torn or corrupt" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "out").exists()  # nothing written, the robot never connected
    assert state.read_text().endswith('"format_ver')  # never silently reset


def test_an_output_folder_that_cannot_be_created_is_one_line_before_the_robot_connects(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    res = cli("--config", DEFAULT_STUDY, "--out", str(blocker / "sub"), "--turns", "2", "--speed", "50",
              "--robot", "tcp://127.0.0.1:1", "--pseudonym", "P1")
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip() == (f"nao-trainer run: error: session.output: cannot create the folder {blocker / 'sub'} "
                                  "(Not a directory); point session.output (or --out) at a folder you can write to")
    assert "connecting" not in res.stderr


def test_bare_nao_trainer_prints_help_and_plays_nothing(tmp_path):
    res = subprocess.run([sys.executable, "-m", "nao_trainer"], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert res.returncode == 0 and res.stdout.startswith("usage: nao-trainer")
    for command in ("run", "check", "fit", "train"):
        assert f"    {command} " in res.stdout
    assert not (tmp_path / "sessions").exists()  # no demo session was played


def test_a_robot_address_never_runs_the_demo_study(tmp_path):
    """Issue: `--robot tcp://IP --input tactile` silently ran demo.yaml (x25, simulated Muse, policy usp:2, pseudonym demo)."""
    res = cli("--robot", "tcp://127.0.0.1:1", "--input", "tactile", "--out", str(tmp_path / "out"))
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip().count("\n") == 0 and "--robot tcp://127.0.0.1:1 needs --config FILE" in res.stderr
    assert "connecting" not in res.stderr and not (tmp_path / "out").exists()
    # the refusal never echoes a password given in the address
    res = cli("--robot", "tcps://nao:S3c/ret@PW@127.0.0.1:9", "--input", "tactile", "--out", str(tmp_path / "out"))
    assert res.returncode == 2 and "--robot tcps://***@127.0.0.1:9 needs --config FILE" in res.stderr
    assert "S3c" not in res.stderr and "PW" not in res.stderr
    # with a study: a simulated Muse is refused while a person answers
    res = cli("--config", DEFAULT_STUDY, "--robot", "tcp://127.0.0.1:1", "--input", "tactile", "--eeg", "simulated",
              "--out", str(tmp_path / "out"))
    assert res.returncode == 2 and "key 'eeg.mode' is 'simulated', but a person answers (answers.input: tactile)" in res.stderr


def test_relative_paths_resolve_against_the_current_folder_and_the_study_file(tmp_path):
    """--config relative to where the command runs; a dialogue path inside a study relative to the study's folder."""
    study_dir = tmp_path / "studies"
    study_dir.mkdir()
    (study_dir / "words.yaml").write_text((PROJECT_ROOT / "dialogue" / "en.yaml").read_text())
    (study_dir / "s.yaml").write_text("session: {dialogue: words.yaml, turns: 1}\nanswers: {input: simulated}\n")
    work = tmp_path / "elsewhere"
    work.mkdir()
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--config", "../studies/s.yaml", "--speed", "50",
                          "--quiet", "--out", "out", "--no-practice"], capture_output=True, text=True, cwd=work,
                         env=dict(os.environ, QI_LOG_LEVEL="silent"), timeout=60)
    assert res.returncode == 0, res.stderr
    session = json.loads((only_folder(work / "out") / "session.json").read_text())
    assert session["config"]["values"]["session"]["dialogue"] == str(study_dir / "words.yaml")
    assert session["config"]["sources"][-1] == str(study_dir / "s.yaml")
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--config", "studies/missing.yaml"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert res.returncode == 2 and f"{tmp_path / 'studies' / 'missing.yaml'}: file not found; check the path" in res.stderr
    (study_dir / "bad.yaml").write_text("session:\n  dialogue: nowhere.yaml\n")
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--config", str(study_dir / "bad.yaml")],
                         capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert res.returncode == 2
    assert (f"bad.yaml:2: key 'session.dialogue': {study_dir / 'nowhere.yaml'} is not a file (relative paths resolve "
            f"against {study_dir}") in res.stderr
