"""NaoqiRobot against the stand-in over real qi on 127.0.0.1: calls, head buttons, addresses, credentials."""
from __future__ import annotations

import logging
import threading
import time

import pytest
from _waits import returns
import qi

from nao_trainer.errors import ConfigError
from nao_trainer.ports import Robot, RobotCallFailed, RobotConnectionLost
from nao_trainer.robot.naoqi import (
    CallTimeouts,
    Credentials,
    MissingService,
    NaoqiRobot,
    AuthenticatorFactory,
    credentials_from_env,
    is_connection_lost,
    normalize_url,
    redact_url,
)
from nao_trainer.robot.standin import StandIn, StandInClient


@pytest.fixture
def standin():
    s = StandIn.start(speed=50.0)
    yield s
    s.stop()


@pytest.fixture
def robot(standin):
    r = NaoqiRobot.connect(standin.url, deadline_s=3.0)
    yield r
    r.close()


@pytest.fixture
def memory(standin):
    """ALMemory seen by a second, plain qi client (as another NAOqi module would raise events)."""
    session = qi.Session()
    session.connect(standin.url)
    yield session.service("ALMemory")
    session.close()


class Presses:
    """Collects (letter, time) from qi threads."""

    def __init__(self):
        self.items: list[tuple[str, float]] = []
        self._cond = threading.Condition()

    def __call__(self, letter: str, t: float) -> None:
        with self._cond:
            self.items.append((letter, t))
            self._cond.notify_all()

    def wait_for(self, n: int, timeout: float = 3.0) -> list[str]:
        with self._cond:
            self._cond.wait_for(lambda: len(self.items) >= n, timeout)
            return [letter for letter, _ in self.items]


def _calls(standin, service=None):
    return [(e["service"], e["method"], e["args"]) for e in standin.transcript() if service in (None, e["service"])]


def test_implements_the_robot_port(robot):
    assert isinstance(robot, Robot)
    assert robot.is_connected()


def test_say_beep_leds_posture_reach_the_robot_with_naoqi_signatures(standin, robot):
    robot.say("Hello, let us play.")
    robot.say("Well done!", animated=True)
    robot.say("Listen.", animated=True, mode="disabled")
    robot.beep(880, 0.2, gain=0.3)
    robot.set_eye_leds(0x0000FF, 0.1)
    assert robot.go_to_posture("Stand", 0.6) is False  # motors off: a NAO's joints do not move
    robot.wake_up()
    assert robot.go_to_posture("Stand", 0.6) is True
    robot.rest()
    assert _calls(standin) == [
        ("ALTextToSpeech", "say", ["Hello, let us play."]),
        ("ALAnimatedSpeech", "say", ["Well done!", {"bodyLanguageMode": "contextual"}]),
        ("ALAnimatedSpeech", "say", ["Listen.", {"bodyLanguageMode": "disabled"}]),
        ("ALAudioPlayer", "playSine", [880, 30, 0, 0.2]),
        ("ALLeds", "fadeRGB", ["FaceLeds", 0x0000FF, 0.1]),
        ("ALRobotPosture", "goToPosture", ["Stand", 0.6]),
        ("ALMotion", "wakeUp", []),
        ("ALRobotPosture", "goToPosture", ["Stand", 0.6]),
        ("ALMotion", "rest", []),
    ]


def test_non_ascii_speech_arrives_intact(tmp_path):
    path = tmp_path / "t.jsonl"
    with StandIn.start(speed=100.0, transcript_path=path) as s:
        with NaoqiRobot.connect(s.url, 3.0) as robot:
            robot.say("Γεια σου! Très bien.", animated=True)
    assert "Γεια σου! Très bien." in path.read_text(encoding="utf-8")  # readable, not \u-escaped
    assert s.transcript()[0]["args"][0] == "Γεια σου! Très bien."


def test_say_returns_when_speech_is_done(standin, robot):
    standin.set_speed(10.0)
    t0 = time.monotonic()
    robot.say("x" * 50)  # 0.06 s/char / 10 = 0.3 s
    assert time.monotonic() - t0 >= 0.3


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda r: r.say("hi", animated=True, mode="wild"), "body language mode"),
        (lambda r: r.beep(5, 0.1), "frequency"),
        (lambda r: r.beep(440, 0.0), "duration"),
        (lambda r: r.beep(440, 0.1, gain=2.0), "gain"),
        (lambda r: r.set_eye_leds(0x1000000, 0.1), "0x000000..0xFFFFFF"),
        (lambda r: r.go_to_posture("Stand", 0.0), "posture speed"),
    ],
)
def test_bad_arguments_are_rejected_before_reaching_the_robot(standin, robot, call, message):
    with pytest.raises(ValueError, match=message):
        call(robot)
    assert standin.transcript() == []


def test_robot_side_error_propagates_with_context_in_one_line(robot):
    with pytest.raises(RobotCallFailed) as info:
        robot.go_to_posture("Moonwalk", 0.5)
    text = str(info.value)
    assert "ALRobotPosture.goToPosture failed on the robot at tcp://127.0.0.1:" in text
    assert "unknown posture 'Moonwalk'" in text and "\n" not in text
    assert not isinstance(info.value, RobotConnectionLost)
    assert robot.is_connected()


def test_missing_service_is_a_user_error_not_a_connection_loss(robot):
    with pytest.raises(MissingService, match="offers no ALNoSuchThing service"):
        robot._call("ALNoSuchThing", "run", timeout_s=1.0)


def test_a_frozen_call_hits_its_deadline(standin):
    standin.set_speed(0.001)  # say("hello") would take five minutes
    robot = NaoqiRobot.connect(standin.url, 3.0, timeouts=CallTimeouts(say_base_s=0.4, say_per_char_s=0.0))
    try:
        with pytest.raises(RobotConnectionLost, match="did not answer within 0.4 s"):
            returns(lambda: robot.say("hello"))  # five minutes of speech: ended by the deadline (its message)
    finally:
        robot.close()


def test_stop_all_from_another_thread_ends_a_say_early(standin, robot):
    standin.set_speed(0.01)  # ten minutes of speech unless stopped: only stopAll can end it within the wait
    timer = threading.Timer(0.3, robot.stop_all)
    t0 = time.monotonic()  # before the timer starts: taken after, a loaded machine made the bound 0.296 s
    timer.start()
    returns(lambda: robot.say("x" * 100))
    timer.join()
    assert time.monotonic() - t0 >= 0.3  # it spoke until stopped (a lower bound)
    assert [m for _, m, _ in _calls(standin)] == ["say", "stopAll", "stopAll"]


# --- head buttons ---------------------------------------------------------------------------


def test_presses_via_control_service_arrive_as_letters(standin, robot):
    presses = Presses()
    robot.subscribe_buttons(presses)
    assert sorted(args[0] for service, method, args in _calls(standin, "ALMemory") if method == "subscriber") == [
        "FrontTactilTouched", "MiddleTactilTouched", "RearTactilTouched",
    ]
    before = time.monotonic()
    for button in ("A", "B", "C"):
        standin.press(button)
    assert presses.wait_for(3) == ["A", "B", "C"]
    assert all(before <= t <= time.monotonic() for _, t in presses.items)


def test_presses_via_memory_raise_event_arrive_and_releases_do_not(robot, memory):
    presses = Presses()
    robot.subscribe_buttons(presses)
    memory.raiseEvent("RearTactilTouched", 1.0)
    memory.raiseEvent("RearTactilTouched", 0.0)
    memory.raiseEvent("MiddleTactilTouched", 1.0)
    memory.raiseEvent("MiddleTactilTouched", 0.0)
    memory.raiseEvent("FrontTactilTouched", 0.0)  # a release alone is no press
    assert presses.wait_for(2) == ["C", "B"]
    time.sleep(0.1)
    assert len(presses.items) == 2


def test_debounce_drops_a_quick_second_press_of_the_same_button(robot, memory):
    presses = Presses()
    robot.subscribe_buttons(presses)
    memory.raiseEvent("FrontTactilTouched", 1.0)
    memory.raiseEvent("FrontTactilTouched", 1.0)  # bounce: within 0.15 s
    memory.raiseEvent("MiddleTactilTouched", 1.0)  # another button is not debounced
    assert presses.wait_for(2) == ["A", "B"]
    time.sleep(0.2)
    memory.raiseEvent("FrontTactilTouched", 1.0)  # after the debounce interval
    assert presses.wait_for(3) == ["A", "B", "A"]


def test_a_bouncing_sensor_counts_as_one_press(standin):
    """The stand-in's worn sensor: three contacts for one touch; the adapter's debounce keeps one."""
    robot = NaoqiRobot.connect(standin.url, 3.0, debounce_s=5.0)  # wide: a loaded machine cannot split it
    try:
        presses = Presses()
        robot.subscribe_buttons(presses)
        with StandInClient.connect(standin.url) as control:
            control.bounce("C", 3)
            control.press("A")  # another button is not held back
        assert presses.wait_for(2) == ["C", "A"]
        time.sleep(0.1)
        assert len(presses.items) == 2
    finally:
        robot.close()


def test_debounce_is_configurable(standin, memory):
    robot = NaoqiRobot.connect(standin.url, 3.0, debounce_s=0.0)
    try:
        presses = Presses()
        robot.subscribe_buttons(presses)
        memory.raiseEvent("FrontTactilTouched", 1.0)
        memory.raiseEvent("FrontTactilTouched", 1.0)
        assert presses.wait_for(2) == ["A", "A"]
    finally:
        robot.close()
    with pytest.raises(ConfigError, match="debounce"):
        NaoqiRobot.connect(standin.url, 3.0, debounce_s=-1)


def test_unsubscribe_stops_callbacks(standin, robot, memory):
    presses = Presses()
    robot.subscribe_buttons(presses)
    standin.press("A")
    assert presses.wait_for(1) == ["A"]
    robot.unsubscribe_buttons()
    standin.press("B")
    memory.raiseEvent("RearTactilTouched", 1.0)
    time.sleep(0.3)
    assert [letter for letter, _ in presses.items] == ["A"]


def test_unsubscribe_waits_for_a_callback_in_progress(standin, robot):
    started, log = threading.Event(), []

    def slow_callback(letter, t):
        started.set()
        time.sleep(0.3)
        log.append("callback done")

    robot.subscribe_buttons(slow_callback)
    standin.press("A")
    assert started.wait(3.0)
    robot.unsubscribe_buttons()
    log.append("unsubscribed")
    assert log == ["callback done", "unsubscribed"]


def test_subscribing_again_replaces_the_callback(standin, robot):
    first, second = Presses(), Presses()
    robot.subscribe_buttons(first)
    robot.subscribe_buttons(second)
    standin.press("C")
    assert second.wait_for(1) == ["C"]
    time.sleep(0.1)
    assert first.items == []


def test_a_failing_callback_is_logged_and_later_presses_still_arrive(standin, robot, caplog):
    presses = Presses()

    def callback(letter, t):
        presses(letter, t)
        if letter == "A":
            raise ValueError("participant code bug")

    robot.subscribe_buttons(callback)
    with caplog.at_level(logging.ERROR, logger="nao_trainer.robot.naoqi"):
        standin.press("A")
        standin.press("B")
        assert presses.wait_for(2) == ["A", "B"]
    assert "head-button callback failed for FrontTactilTouched" in caplog.text


# --- addresses and credentials --------------------------------------------------------------


@pytest.mark.parametrize(
    "given, expected",
    [
        ("192.168.1.12", "tcp://192.168.1.12:9559"),
        ("tcp://nao.local", "tcp://nao.local:9559"),
        ("tcps://10.0.0.5", "tcps://10.0.0.5:9503"),
        ("TCP://127.0.0.1:40000", "tcp://127.0.0.1:40000"),
    ],
)
def test_normalize_url(given, expected):
    assert normalize_url(given) == expected


def test_urls_with_credentials_are_refused_and_never_echoed():
    with pytest.raises(ConfigError) as info:
        normalize_url("tcps://nao:s3cret@10.0.0.5:9503")
    assert "s3cret" not in str(info.value) and "NAO_PASSWORD" in str(info.value)
    assert redact_url("tcps://nao:s3cret@10.0.0.5:9503") == "tcps://***@10.0.0.5:9503"
    assert redact_url("tcp://10.0.0.5:9559") == "tcp://10.0.0.5:9559"
    with pytest.raises(ConfigError, match="scheme 'http'"):
        normalize_url("http://10.0.0.5")
    with pytest.raises(ConfigError, match="out of range"):
        normalize_url("tcp://10.0.0.5:70000")


LEAKY = [("tcps://nao:S3c/retPW@127.0.0.1:9503", "tcps://***@127.0.0.1:9503", ("S3c", "retPW")),
         ("tcps://nao:S3c@retPW@127.0.0.1:9503", "tcps://***@127.0.0.1:9503", ("S3c", "retPW")),
         ("nao:S3cretPW@127.0.0.1", "***@127.0.0.1", ("S3cretPW", "nao:")),
         ("tcp://a@b:pw@10.0.0.5", "tcp://***@10.0.0.5", ("pw", "a@b"))]


@pytest.mark.parametrize("url, shown, secrets", LEAKY)
def test_no_part_of_a_password_survives_redaction_or_the_refusal(url, shown, secrets):
    assert redact_url(url) == shown
    with pytest.raises(ConfigError) as info:
        normalize_url(url)
    assert "NAO_PASSWORD" in str(info.value)
    for secret in secrets:
        assert secret not in str(info.value)


def test_credentials_from_env():
    assert credentials_from_env({}) is None
    creds = credentials_from_env({"NAO_USER": "nao", "NAO_PASSWORD": "pw"})
    assert (creds.user, creds.password) == ("nao", "pw")
    assert "pw" not in repr(creds) and "pw" not in str(creds)
    with pytest.raises(ConfigError, match="NAO_PASSWORD is not set"):
        credentials_from_env({"NAO_USER": "nao"})


def test_tcps_without_credentials_is_a_config_error(monkeypatch):
    monkeypatch.delenv("NAO_USER", raising=False)
    monkeypatch.delenv("NAO_PASSWORD", raising=False)
    with pytest.raises(ConfigError, match="tcps.*NAO_USER and NAO_PASSWORD"):
        NaoqiRobot.connect("tcps://127.0.0.1:9503", 1.0)


def test_authenticator_sends_user_and_token():
    auth = AuthenticatorFactory(Credentials("nao", "pw")).newAuthenticator()
    assert auth.initialAuthData() == {"user": "nao", "token": "pw"}


def test_credentials_from_env_go_into_the_qi_handshake_and_are_not_shown(standin, monkeypatch):
    """libqi asks the authenticator during the handshake even when the server (here the stand-in) does not check."""
    import nao_trainer.robot.address as address

    sent = []
    original = address._Authenticator.initialAuthData
    monkeypatch.setattr(address._Authenticator, "initialAuthData", lambda self: sent.append(1) or original(self))
    monkeypatch.setenv("NAO_USER", "nao")
    monkeypatch.setenv("NAO_PASSWORD", "pw-123")
    robot = NaoqiRobot.connect(standin.url, 3.0)
    try:
        assert sent == [1]
        assert robot._credentials == Credentials("nao", "pw-123")
        assert "pw-123" not in repr(robot)
        robot.say("ok")
    finally:
        robot.close()


def test_no_credentials_means_no_authenticator(standin, monkeypatch):
    import nao_trainer.robot.address as address

    monkeypatch.delenv("NAO_USER", raising=False)
    monkeypatch.delenv("NAO_PASSWORD", raising=False)
    sent = []
    monkeypatch.setattr(address._Authenticator, "initialAuthData", lambda self: sent.append(1) or {})
    robot = NaoqiRobot.connect(standin.url, 3.0)
    robot.close()
    assert sent == []


def test_connection_lost_messages():
    for message in ("Session closed", "Socket is not connected", "Connect error: 111: Connection refused"):
        assert is_connection_lost(message)
    assert not is_connection_lost("ALRobotPosture::goToPosture: unknown posture")


def test_close_is_idempotent_and_final(standin):
    robot = NaoqiRobot.connect(standin.url, 3.0)
    robot.subscribe_buttons(Presses())
    robot.close()
    robot.close()
    assert not robot.is_connected()
    with pytest.raises(RobotCallFailed, match="is closed"):
        robot.say("hi")


def test_beep_reports_its_round_trip_and_an_onset_inside_the_call():
    """Network round trip 0.2 s, audio latency 0.1 s, tone 0.3 s (speed 1): lower bounds only (a loaded
    machine can only add time); the onset estimate lies between the call and its return minus the tone."""
    with StandIn.start(speed=1.0) as standin:
        standin.set_latency(round_trip_s=0.2, beep_s=0.1)
        with NaoqiRobot.connect(standin.url, 10.0) as robot:
            timing = robot.beep(880, 0.3)
    assert timing.rtt_s >= 0.2 * 0.99
    assert timing.returned - timing.start >= (0.2 + 0.1 + 0.3) * 0.99
    assert timing.start <= timing.onset <= timing.returned - timing.duration_s
    assert timing.duration_s == 0.3
