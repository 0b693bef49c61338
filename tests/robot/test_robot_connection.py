"""Connection robustness over real qi on 127.0.0.1: unreachable, silent, lost and returning robots."""
from __future__ import annotations

import signal
import socket
import threading
import time

import pytest
from _waits import returns

from nao_trainer.errors import RobotUnavailable
from nao_trainer.ports import RobotConnectionLost
from nao_trainer.robot.naoqi import CallTimeouts, NaoqiRobot
from nao_trainer.robot.standin import StandInClient, spawn_standin


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except Exception:
            proc.kill()
            proc.wait()


class Presses:
    def __init__(self):
        self.letters: list[str] = []
        self._cond = threading.Condition()

    def __call__(self, letter, t):
        with self._cond:
            self.letters.append(letter)
            self._cond.notify_all()

    def wait_for(self, n, timeout=3.0):
        with self._cond:
            self._cond.wait_for(lambda: len(self.letters) >= n, timeout)
            return list(self.letters)


def test_closed_port_is_unavailable_at_once():
    url = f"tcp://127.0.0.1:{_free_port()}"
    with pytest.raises(RobotUnavailable) as info:  # refused at once: the message says so, not a 5 s wait
        returns(lambda: NaoqiRobot.connect(url, deadline_s=5.0))
    text = str(info.value)
    assert url in text and "connection refused" in text and "nao-trainer mock-robot" in text
    assert "\n" not in text


def test_silent_server_is_unavailable_within_the_deadline():
    """A port that accepts TCP but never speaks qi would hang `Session.connect` forever."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(4)
        url = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        t0 = time.monotonic()
        with pytest.raises(RobotUnavailable, match="within 1.5 s .*does not speak NAOqi"):
            returns(lambda: NaoqiRobot.connect(url, deadline_s=1.5))
        elapsed = time.monotonic() - t0
    assert elapsed >= 1.4  # it waited for its deadline (a lower bound: load only lengthens it)


def test_lost_robot_raises_connection_lost_and_reconnects_when_back():
    proc, url = spawn_standin(speed=50)
    port = int(url.rsplit(":", 1)[1])
    robot = NaoqiRobot.connect(url, 3.0)
    try:
        presses = Presses()
        robot.subscribe_buttons(presses)
        with StandInClient.connect(url) as remote:
            remote.press("A")
        assert presses.wait_for(1) == ["A"]

        proc.kill()  # the robot dies without saying goodbye
        proc.wait()
        with pytest.raises(RobotConnectionLost, match="lost the robot at"):
            robot.say("are you there?")
        with pytest.raises(RobotConnectionLost):
            robot.beep(440, 0.1)
        assert not robot.is_connected()

        with pytest.raises(RobotUnavailable, match="connection refused"):
            returns(lambda: robot.reconnect(1.0))  # still down

        proc, url2 = spawn_standin(port=port, speed=50)  # back on the same port
        assert url2 == url
        robot.reconnect(3.0)
        assert robot.is_connected()
        robot.say("welcome back")
        with StandInClient.connect(url) as remote:
            remote.press("C")
            assert ("ALTextToSpeech", "say", ["welcome back"]) in [
                (e["service"], e["method"], e["args"]) for e in remote.transcript()
            ]
        assert presses.wait_for(2) == ["A", "C"]  # the same callback, re-subscribed
    finally:
        robot.close()
        _stop(proc)


def test_robot_dying_during_a_call_interrupts_that_call():
    proc, url = spawn_standin(speed=1.0)
    robot = NaoqiRobot.connect(url, 3.0)
    try:
        outcome: list[BaseException] = []

        def speak():
            try:
                robot.say("x" * 100)  # six seconds of speech
            except BaseException as exc:  # noqa: BLE001 - handed to the test thread
                outcome.append(exc)

        worker = threading.Thread(target=speak)
        worker.start()
        time.sleep(0.5)
        proc.kill()
        proc.wait()
        worker.join(60.0)  # the six-second say must end by the loss, not by finishing: it raised
        assert not worker.is_alive()
        assert len(outcome) == 1 and isinstance(outcome[0], RobotConnectionLost)
    finally:
        robot.close()
        _stop(proc)


def test_reconnect_after_close_is_refused():
    proc, url = spawn_standin(speed=50)
    try:
        robot = NaoqiRobot.connect(url, 3.0)
        robot.close()
        with pytest.raises(RobotUnavailable, match="was closed"):
            robot.reconnect(1.0)
    finally:
        _stop(proc)


def test_reconnect_to_a_silent_port_ends_within_its_deadline_and_a_later_try_works():
    proc, url = spawn_standin(speed=50)
    port = int(url.rsplit(":", 1)[1])
    robot = NaoqiRobot.connect(url, 3.0)
    try:
        presses = Presses()
        robot.subscribe_buttons(presses)
        proc.kill()
        proc.wait()
        with socket.socket() as squatter:  # something else took the port and says nothing
            squatter.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            squatter.bind(("127.0.0.1", port))
            squatter.listen(4)
            with pytest.raises(RobotUnavailable, match=r"within [0-9.]+ s .*does not speak NAOqi"):
                returns(lambda: robot.reconnect(1.0))
        proc, _ = spawn_standin(port=port, speed=50)
        robot.reconnect(3.0)
        with StandInClient.connect(url) as remote:
            remote.press("B")
        assert presses.wait_for(1) == ["B"]
    finally:
        robot.close()
        _stop(proc)


def test_frozen_robot_cannot_freeze_calls_reconnect_or_close():
    """SIGSTOP the stand-in: the link stays up but nothing answers (a hung NAOqi)."""
    proc, url = spawn_standin(speed=50)
    timeouts = CallTimeouts(say_base_s=0.5, say_per_char_s=0.0, subscribe_s=1.0)
    robot = NaoqiRobot.connect(url, 3.0, timeouts=timeouts)
    try:
        robot.subscribe_buttons(Presses())
        proc.send_signal(signal.SIGSTOP)
        # each call ends by its own deadline (its message says which), never hangs on the frozen robot
        with pytest.raises(RobotConnectionLost, match="did not answer within 0.5 s"):
            returns(lambda: robot.say("hello?"))
        with pytest.raises(RobotConnectionLost, match="did not answer within 1 s"):
            returns(lambda: robot.subscribe_buttons(Presses()))  # 1 s to drop the old signals, 1 s for the new
        with pytest.raises(RobotUnavailable):
            returns(lambda: robot.reconnect(1.0))  # the deadline covers dropping the old signals too
        returns(robot.close)
    finally:
        robot.close()
        proc.send_signal(signal.SIGCONT)
        _stop(proc)


def test_mistyped_host_says_the_name_cannot_be_resolved_not_login(monkeypatch):
    # .invalid never resolves (RFC 6761); credentials set so a login path would be taken if reached.
    monkeypatch.setenv("NAO_USER", "nao")
    monkeypatch.setenv("NAO_PASSWORD", "secret")
    for url in ("tcp://nao-typo.invalid", "tcps://nao-typo.invalid:9503"):
        with pytest.raises(RobotUnavailable) as info:
            NaoqiRobot.connect(url, deadline_s=5.0)
        text = str(info.value)
        assert "'nao-typo.invalid' cannot be resolved" in text and "--robot" in text
        assert "authentication" not in text and "secret" not in text and "\n" not in text
