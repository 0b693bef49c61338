"""`--robot desktop`: real espeak-ng speech and sine beeps, written as WAV files when there is no sound device."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from _waits import returns
from scipy.io import wavfile

from nao_trainer.errors import ConfigError, RobotUnavailable
from nao_trainer.ports import Robot
from nao_trainer.robot import desktop
from nao_trainer.robot.desktop import DesktopRobot, choose_player



@pytest.fixture()
def robot(tmp_path):
    assert desktop.shutil.which("espeak-ng"), "espeak-ng is missing: `make test` installs it (apt-get install espeak-ng)"
    r = DesktopRobot(speed=50, player=None)
    r.record_audio_to(tmp_path / "audio")
    yield r
    r.close()


def _read(path):
    rate, samples = wavfile.read(path)
    return rate, samples.astype(float)


def test_implements_the_robot_port(robot):
    assert isinstance(robot, Robot)


def test_speech_is_a_real_voice_in_a_wav_file(robot, tmp_path):
    t0 = time.monotonic()
    robot.say("Level two. Five letters.")
    waited = time.monotonic() - t0
    (path,) = sorted((tmp_path / "audio").glob("*-say.wav"))
    rate, x = _read(path)
    duration = len(x) / rate
    assert 1.0 < duration < 5.0  # a short sentence at ~160 words per minute
    assert np.sqrt(np.mean(x ** 2)) > 300  # not silence
    assert np.mean(np.abs(x) > 1000) > 0.1  # voiced for a good part of it
    assert waited >= duration / 50 * 0.9  # the session's rhythm: as long as the speech lasts, sped up


def test_beep_has_the_asked_frequency_length_and_gain(robot, tmp_path):
    robot.beep(880, 0.3, 0.5)
    robot.beep(440, 0.2, 1.0)
    beeps = sorted((tmp_path / "audio").glob("*-beep.wav"))
    assert [p.name for p in beeps] == ["0001-beep.wav", "0002-beep.wav"]
    for path, hz, seconds, gain in zip(beeps, (880, 440), (0.3, 0.2), (0.5, 1.0)):
        rate, x = _read(path)
        assert len(x) / rate == pytest.approx(seconds, abs=1 / rate)
        spectrum = np.abs(np.fft.rfft(x))
        peak = np.fft.rfftfreq(len(x), 1 / rate)[int(np.argmax(spectrum))]
        assert peak == pytest.approx(hz, abs=rate / len(x))
        assert np.max(np.abs(x)) == pytest.approx(gain * 0.9 * 32767, rel=0.02)


def test_stop_all_cuts_a_long_utterance_short(tmp_path):
    """Minutes of speech: only stop_all ends it within the wait, whether it comes while espeak-ng is still
    synthesising (the first stop) or while the sound lasts (a second, later one)."""
    r = DesktopRobot(speed=1, player=None)
    done = threading.Event()

    def stopper():
        for delay in (0.3, 3.0):
            if done.wait(delay):
                return
            r.stop_all()

    th = threading.Thread(target=stopper)
    try:
        th.start()
        returns(lambda: r.say("This is a long sentence that would take several seconds to say at a normal pace, "
                              "really." * 20))
    finally:
        done.set()
        th.join()
        r.close()


def test_a_stop_during_the_synthesis_is_not_lost(monkeypatch):
    """stop_all while espeak-ng is still making the sound: say returns at once, nothing waits for it."""
    r = DesktopRobot(speed=1, player=None)
    real_popen = subprocess.Popen

    class StoppedSynth(real_popen):  # the stop arrives while espeak-ng runs
        def communicate(self, *args, **kwargs):
            r.stop_all()
            return super().communicate(*args, **kwargs)

    slow_synth = StoppedSynth

    try:
        monkeypatch.setattr(desktop.subprocess, "Popen", slow_synth)
        waited = []
        monkeypatch.setattr(r._stop, "wait", lambda s: waited.append(s))
        r.say("A sentence that lasts a few seconds when it is said out loud.")
        assert waited == []  # the files mode waits as long as the sound lasts: here not at all
    finally:
        r.close()


def test_no_buttons_and_no_espeak_are_clear_errors(monkeypatch, robot):
    with pytest.raises(ConfigError, match="--input keyboard"):
        robot.subscribe_buttons(lambda letter, t: None)
    monkeypatch.setenv("PATH", "/nonexistent")
    with pytest.raises(RobotUnavailable, match=r"espeak-ng, which is not installed; install it: `sudo apt-get install"):
        DesktopRobot.start()


def test_audio_output_choice(monkeypatch):
    assert choose_player({"NAO_TRAINER_AUDIO": "files"}) is None
    with pytest.raises(ConfigError, match="NAO_TRAINER_AUDIO='loud': use auto, files or device"):
        choose_player({"NAO_TRAINER_AUDIO": "loud"})
    monkeypatch.setattr(desktop, "sound_device_present", lambda: False)
    assert choose_player({}) is None  # no sound device (CI): WAV files


def test_a_person_plays_a_session_on_the_keyboard_with_the_desktop_robot(tmp_path):
    """Prompt at the beep, keys echoed, practice result shown; every utterance and beep kept as WAV."""
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", "--robot", "desktop", "--input", "keyboard", "--pseudonym", "P1",
                             "--turns", "1", "--speed", "10", "--eeg", "off", "--policy", "schedule", "--out", str(out),
                             "--seed", "3"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=dict(os.environ, NAO_TRAINER_AUDIO="files"))
    err = bytearray()

    def reader():
        while chunk := os.read(proc.stderr.fileno(), 256):
            err.extend(chunk)

    t = threading.Thread(target=reader, daemon=True)
    t.start()
    typed = set()
    deadline = time.monotonic() + 90
    while proc.poll() is None and time.monotonic() < deadline:
        text = err.decode(errors="replace")
        if "your answer (practice)" in text and "practice" not in typed:
            proc.stdin.write(b"ccc")
            proc.stdin.flush()
            typed.add("practice")
        folders = list(out.glob("*")) if out.exists() else []
        if "your answer, " in text and 1 not in typed and folders:
            try:
                events = [json.loads(line) for line in (folders[0] / "events.jsonl").read_text().splitlines()]
            except ValueError:  # caught the session mid-line: read again on the next pass
                events = []
            seq = next((e["sequence"] for e in events if e["event"] == "turn_start"), None)
            if seq is not None:
                proc.stdin.write(seq.lower().encode())
                proc.stdin.flush()
                typed.add(1)
        time.sleep(0.02)
    proc.wait(timeout=30)
    t.join(5)
    for f in (proc.stdin, proc.stdout, proc.stderr):
        f.close()
    text = err.decode(errors="replace")
    assert proc.returncode == 0, text
    assert typed == {"practice", 1}
    practice = next(line for line in text.splitlines() if line.startswith("your answer (practice)"))
    assert "CCC" in practice and ("practice: correct" in practice or "practice: the sequence was" in practice)
    (folder,) = out.glob("*")
    events = [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]
    seq = next(e["sequence"] for e in events if e["event"] == "turn_start")
    turn_line = next(line for line in text.splitlines() if line.startswith("your answer, "))
    assert turn_line.endswith(seq.upper())
    audio = folder / "audio"
    beeps = sorted(audio.glob("*-beep.wav"))
    assert len(beeps) == 2  # practice + one turn
    rate, x = _read(beeps[0])
    assert np.fft.rfftfreq(len(x), 1 / rate)[int(np.argmax(np.abs(np.fft.rfft(x))))] == pytest.approx(880, abs=40)
    says = sorted(audio.glob("*-say.wav"))
    assert len(says) >= 8 and all(_read(p)[1].std() > 100 for p in says)
    session = json.loads((folder / "session.json").read_text())
    assert "DesktopRobot" in session["robot"]


def test_desktop_refuses_head_button_answers(tmp_path):
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--robot", "desktop", "--input", "tactile", "--pseudonym", "P1",
                          "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "--robot desktop has no head buttons" in res.stderr
    assert "Traceback" not in res.stderr and not list((tmp_path / "out").glob("*"))  # no session folder
