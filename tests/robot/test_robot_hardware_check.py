"""`nao-trainer hardware-check` against an in-process stand-in over qi, the operator played by a thread that
answers the robot's requests with the stand-in's simulated presses (right, wrong, or none)."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest

from nao_trainer.robot.hardware_check import ASK, CONFIRM
from nao_trainer.robot.standin import StandIn

PROMPTS = {CONFIRM: "A", **{ASK.format(name): letter for letter, name in (("A", "front"), ("B", "middle"),
                                                                            ("C", "rear"))}}


class Operator(threading.Thread):
    """Touches the button each spoken request asks for; ``answers`` overrides one (None: no touch)."""

    def __init__(self, standin: StandIn, answers: dict[str, str | None] | None = None) -> None:
        super().__init__(daemon=True)
        self.standin, self.answers = standin, answers or {}
        self.stop = threading.Event()

    def run(self) -> None:
        seen = 0
        while not self.stop.wait(0.02):
            said = [e["args"][0] for e in self.standin.transcript() if e["method"] == "say"]
            for text in said[seen:]:
                if text in PROMPTS:
                    letter = self.answers.get(text, PROMPTS[text])
                    if letter is not None:
                        self.stop.wait(0.3)  # a finger is not faster than the robot's debounce (0.15 s)
                        self.standin.press(letter)
            seen = len(said)


def hardware_check(standin: StandIn, answers=None, timeout: str = "20") -> subprocess.CompletedProcess:
    operator = Operator(standin, answers)
    operator.start()
    try:
        return subprocess.run([sys.executable, "-m", "nao_trainer", "hardware-check", "--robot", standin.url,
                               "--timeout", timeout], capture_output=True, text=True, timeout=180,
                              env=dict(os.environ, QI_LOG_LEVEL="silent"))
    finally:
        operator.stop.set()
        operator.join(5)


def verdict(res: subprocess.CompletedProcess) -> dict[str, str]:
    return {ln[6:20].strip(): ln[:4] for ln in res.stdout.splitlines() if ln[:4] in ("PASS", "FAIL")}


@pytest.fixture
def standin():
    s = StandIn.start(speed=50)
    yield s
    s.stop()


def test_every_item_passes_when_the_operator_presses_what_is_asked(standin):
    res = hardware_check(standin)
    assert res.returncode == 0, res.stdout + res.stderr
    assert verdict(res) == {"robot": "PASS", "volume": "PASS", "mute": "PASS", "battery": "PASS", "life": "PASS",
                            "speech+beep": "PASS", "heard": "PASS", "button A": "PASS", "button B": "PASS",
                            "button C": "PASS", "network": "PASS"}
    assert "pressed: middle (B)," in res.stdout and "s after the request began" in res.stdout
    assert "volume 60%" not in res.stdout and "60% (ALAudioDevice" in res.stdout
    said = [e["args"][0] for e in standin.transcript() if e["method"] == "say"]
    assert said[1:4] == ["A", "B", "C"]
    assert any(e["method"] == "playSine" for e in standin.transcript())
    assert standin.body()["life"] == "solitary"  # set to disabled for the check, then restored
    assert [e["args"] for e in standin.transcript() if e["method"] == "setState"] == [["disabled"], ["solitary"]]
    assert not any(e["service"] == "ALMotion" for e in standin.transcript())  # the motors are not touched


def test_a_wrong_button_a_missing_press_and_a_muted_robot_fail(standin):
    standin._control._body.muted = True  # as the robot's web page would leave it
    res = hardware_check(standin, {ASK.format("middle"): "C", ASK.format("rear"): None}, timeout="2")
    assert res.returncode == 3, res.stdout + res.stderr
    v = verdict(res)
    assert (v["mute"], v["button A"], v["button B"], v["button C"], v["heard"]) == ("FAIL", "PASS", "FAIL", "FAIL", "PASS")
    assert "asked for middle, got rear" in res.stdout and "no press of the rear button within 2 s" in res.stdout
    assert standin.body()["life"] == "solitary"


def test_a_hand_held_3_s_on_the_head_during_the_check_does_not_put_the_robot_to_sleep(standin):
    """With Autonomous Life left "solitary" this would put NAO to sleep; the check disables it first."""
    held: list[str] = []
    real_press = standin.press

    def press(letter: str) -> str:
        if letter == "A" and len(held) == 0 and any(e["args"] == [ASK.format("front")] for e in standin.transcript()
                                                    if e["method"] == "say"):
            held.append(standin.hold("A", 3.0))  # the operator rests a hand on the head instead of tapping
            return "FrontTactilTouched"
        return real_press(letter)

    standin.press = press  # the operator thread calls this
    res = hardware_check(standin)
    assert held == ["nothing"]
    assert res.returncode == 0, res.stdout + res.stderr
    assert not standin.body()["asleep"]


def test_without_a_robot_address_it_says_so_in_one_line():
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "hardware-check"], capture_output=True, text=True,
                         timeout=60, env=dict(os.environ, QI_LOG_LEVEL="silent"))
    assert res.returncode == 2 and "needs a robot address" in res.stderr and "Traceback" not in res.stderr


def test_a_robot_lost_while_recording_its_profile_is_one_line_and_no_file(standin, tmp_path, monkeypatch, capsys):
    from nao_trainer.cli import hardware_check as command
    from nao_trainer.cli import main
    from nao_trainer.ports import RobotConnectionLost

    def lost(robot, *args, **kwargs):
        raise RobotConnectionLost("ALAudioPlayer.playSine did not answer within 10 s")

    monkeypatch.setattr(command, "record_profile", lost)
    path = tmp_path / "profile.json"
    assert main(["hardware-check", "--robot", standin.url, "--record", str(path)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--record" in err[0] and "did not answer" in err[0] and "nothing was written" in err[0]
    assert not path.exists()
