"""The stand-in as a real NAO behaves around the task, over real qi: Autonomous Life, motors, sleep,
system volume and mute, battery, identity, latency, a frozen link."""
from __future__ import annotations

import time

import pytest
import qi

from nao_trainer.robot.standin import SLEEP_HOLD_S, StandIn, StandInClient

FAST = 50.0


@pytest.fixture
def standin():
    s = StandIn.start(speed=FAST)
    yield s
    s.stop()


@pytest.fixture
def client(standin):
    session = qi.Session()
    session.connect(standin.url)
    yield session
    session.close()


def test_a_nao_boots_solitary_with_its_motors_off(standin, client):
    life, motion = client.service("ALAutonomousLife"), client.service("ALMotion")
    assert life.getState() == "solitary" and motion.robotIsWakeUp() is False
    assert client.service("ALRobotPosture").goToPosture("Stand", 1.0) is False  # no stiffness, no motion
    motion.wakeUp()
    assert motion.robotIsWakeUp() is True and client.service("ALRobotPosture").getPosture() == "Stand"
    motion.rest()
    assert motion.robotIsWakeUp() is False and standin.body()["posture"] == "Crouch"


def test_autonomous_life_states_as_documented(client):
    life = client.service("ALAutonomousLife")
    life.setState("disabled")
    assert life.getState() == "disabled"
    life.setState("interactive")
    with pytest.raises(RuntimeError, match="interactive to solitary"):
        life.setState("solitary")
    with pytest.raises(RuntimeError, match="unknown state"):
        life.setState("asleep")


def test_a_hand_held_3_s_with_life_on_puts_nao_to_sleep_and_it_stops_the_task(standin, client):
    tts = client.service("ALTextToSpeech")
    assert standin.hold("B", SLEEP_HOLD_S) == "asleep"
    body = standin.body()
    assert body["asleep"] and not body["motors_on"] and body["life"] == "disabled"
    with pytest.raises(RuntimeError, match="NAO is asleep"):
        tts.say("three")
    with pytest.raises(RuntimeError, match="NAO is asleep"):
        client.service("ALAudioPlayer").playSine(880, 50, 0, 0.1)
    standin.press("A")  # a touch wakes NAO (sleep_nao.html); it is not an answer
    assert not standin.body()["asleep"] and standin.body()["life"] == "solitary"
    tts.say("awake again")


def test_with_life_disabled_a_held_head_is_only_a_press(standin, client):
    client.service("ALAutonomousLife").setState("disabled")
    assert standin.hold("B", SLEEP_HOLD_S + 1) == "nothing"
    assert not standin.body()["asleep"]
    client.service("ALTextToSpeech").say("still here")


def test_a_held_head_for_1_s_stops_the_activity_but_nao_stays_awake(standin):
    assert standin.hold("front", 1.5) == "activity stopped"
    assert not standin.body()["asleep"]


def test_system_volume_mute_battery_and_identity(standin, client):
    audio = client.service("ALAudioDevice")
    assert audio.getOutputVolume() == 60 and audio.isAudioOutMuted() is False
    audio.setOutputVolume(25)
    audio.muteAudioOut(True)
    assert audio.getOutputVolume() == 25 and audio.isAudioOutMuted() is True
    with pytest.raises(RuntimeError, match="0..100"):
        audio.setOutputVolume(120)
    assert client.service("ALTextToSpeech").getVolume() == 1.0  # the speech gain says nothing of the above
    with StandInClient.connect(standin.url) as control:
        control.set_battery(12)
    assert client.service("ALBattery").getBatteryCharge() == 12
    system = client.service("ALSystem")
    assert system.robotName() == "nao-standin" and system.systemVersion().startswith("2.8")


def test_configured_latency_is_the_least_a_call_takes(standin, client):
    memory = client.service("ALMemory")
    standin.set_latency(round_trip_s=0.15)
    t0 = time.monotonic()
    memory.getData("FrontTactilTouched")
    assert time.monotonic() - t0 >= 0.15 * 0.99  # a lower bound: a loaded machine can only add to it


def test_a_frozen_link_is_alive_but_silent_then_delivers(standin, client):
    memory = client.service("ALMemory")
    with StandInClient.connect(standin.url) as control:
        control.freeze(30.0)
    time.sleep(0.1)  # the freeze starts just after the control call's reply
    pending = memory.getData("FrontTactilTouched", _async=True)
    assert pending.wait(300) == qi.FutureState.Running  # no answer while frozen ...
    assert client.isConnected()  # ... and libqi still believes the link is up
    standin.link.thaw()
    assert pending.wait(10_000) == qi.FutureState.FinishedWithValue  # the held bytes arrive afterwards


def test_a_freeze_armed_on_the_beep_starts_once_the_beep_returned(standin, client):
    player, memory = client.service("ALAudioPlayer"), client.service("ALMemory")
    standin.freeze_after("ALAudioPlayer.playSine", 30.0)
    player.playSine(880, 50, 0, 0.1)  # returns: the freeze starts after its reply
    time.sleep(0.1)
    pending = memory.getData("FrontTactilTouched", _async=True)
    assert pending.wait(300) == qi.FutureState.Running
    standin.link.thaw()
    assert pending.wait(10_000) == qi.FutureState.FinishedWithValue


def test_a_bouncing_sensor_emits_several_contacts(standin, client):
    values = []
    sub = client.service("ALMemory").subscriber("RearTactilTouched")
    sub.signal.connect(values.append)
    with StandInClient.connect(standin.url) as control:
        control.bounce("C", 3)
    deadline = time.monotonic() + 10
    while len(values) < 6 and time.monotonic() < deadline:
        time.sleep(0.01)
    # three contacts, each a touch and a release; qi delivers a signal's callbacks on its own threads, so
    # their order across contacts is not guaranteed on a loaded machine
    assert sorted(values) == [0.0] * 3 + [1.0] * 3


# -- the command line: tcps with the login from the environment, SIGUSR1 freezes the link ----------


def _mock_robot(*args: str, **env: str):
    import os
    import subprocess
    import sys

    return subprocess.Popen([sys.executable, "-m", "nao_trainer", "mock-robot", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={k: v for k, v in dict(os.environ, QI_LOG_LEVEL="silent", **env).items()
                                 if k not in ("NAO_USER", "NAO_PASSWORD") or k in env})


def test_mock_robot_serves_tcps_with_the_login_from_the_environment_and_freezes_on_sigusr1():
    import signal

    from nao_trainer.errors import RobotUnavailable
    from nao_trainer.robot.naoqi import Credentials, NaoqiRobot
    from nao_trainer.robot.standin import READY_PREFIX

    proc = _mock_robot("--listen", "tcps://127.0.0.1:0", "--speed", "50", NAO_USER="lab", NAO_PASSWORD="pw-1")
    try:
        url = proc.stdout.readline()[len(READY_PREFIX):].strip()
        assert url.startswith("tcps://127.0.0.1:")
        with pytest.raises(RobotUnavailable, match="NAO_USER / NAO_PASSWORD"):
            NaoqiRobot.connect(url, 10.0, Credentials("lab", "not-it"))
        with NaoqiRobot.connect(url, 10.0, Credentials("lab", "pw-1")) as robot:
            robot.ping(10.0)
            proc.send_signal(signal.SIGUSR1)  # frozen for --freeze-s (10 s): the next ping gets no answer
            time.sleep(0.2)
            with pytest.raises(Exception, match="did not answer within 0.5 s"):
                robot.ping(0.5)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err


def test_mock_robot_tcps_without_a_login_is_refused_in_one_line():
    proc = _mock_robot("--listen", "tcps://127.0.0.1:0")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "set NAO_USER and NAO_PASSWORD" in err and "Traceback" not in err
