"""The NAO stand-in over real qi on 127.0.0.1: NAOqi names and signatures, timing, buttons, transcript, CLI."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest
import qi

from nao_trainer.errors import ConfigError, RobotUnavailable
from nao_trainer.robot.standin import (
    READY_PREFIX,
    SECONDS_PER_CHARACTER,
    StandIn,
    StandInClient,
    button_key,
    check_listen_url,
    spawn_standin,
)

FAST = 50.0  # stand-in speed for tests that do not measure timing


@pytest.fixture
def standin():
    s = StandIn.start(speed=FAST)
    yield s
    s.stop()


@pytest.fixture
def client(standin):
    """A plain qi client session, as NAOqi SDK code would use it."""
    session = qi.Session()
    session.connect(standin.url)
    yield session
    session.close()


def _calls(standin, service=None):
    return [(e["service"], e["method"], e["args"]) for e in standin.transcript() if service in (None, e["service"])]


class _Collector:
    """Collects signal values from qi threads."""

    def __init__(self):
        self.values = []
        self._cond = threading.Condition()

    def __call__(self, value):
        with self._cond:
            self.values.append(value)
            self._cond.notify_all()

    def wait_for(self, n, timeout=3.0):
        with self._cond:
            self._cond.wait_for(lambda: len(self.values) >= n, timeout)
        return list(self.values)


@pytest.fixture
def button_signal(client):
    """Subscribe to FrontTactilTouched through ALMemory.subscriber; disconnected at teardown."""
    memory = client.service("ALMemory")
    sub = memory.subscriber("FrontTactilTouched")
    got = _Collector()
    link = sub.signal.connect(got)
    yield memory, got
    sub.signal.disconnect(link)


def test_url_is_loopback_with_chosen_port(standin):
    assert standin.url.startswith("tcp://127.0.0.1:")
    assert int(standin.url.rsplit(":", 1)[1]) > 0


def test_speech_sound_leds_posture_with_naoqi_signatures(standin, client):
    client.service("ALTextToSpeech").say("Hello")
    anim = client.service("ALAnimatedSpeech")
    anim.say("Well done")
    anim.say("Again", {"bodyLanguageMode": "disabled"})
    client.service("ALAudioPlayer").playSine(440, 50, 0, 0.25)
    leds = client.service("ALLeds")
    leds.fadeRGB("FaceLeds", 0x00FF00, 0.1)
    leds.fadeRGB("FaceLeds", 1.0, 0.5, 0.0, 0.1)
    posture = client.service("ALRobotPosture")
    assert posture.goToPosture("StandInit", 0.5) is False  # motors off at boot: the joints do not move
    assert posture.getPosture() == "Crouch"
    client.service("ALMotion").wakeUp()
    assert posture.goToPosture("StandInit", 0.5) is True
    assert posture.getPosture() == "StandInit"
    assert _calls(standin) == [
        ("ALTextToSpeech", "say", ["Hello"]),
        ("ALAnimatedSpeech", "say", ["Well done"]),
        ("ALAnimatedSpeech", "say", ["Again", {"bodyLanguageMode": "disabled"}]),
        ("ALAudioPlayer", "playSine", [440, 50, 0, 0.25]),
        ("ALLeds", "fadeRGB", ["FaceLeds", 0x00FF00, 0.1]),
        ("ALLeds", "fadeRGB", ["FaceLeds", 1.0, 0.5, 0.0, 0.1]),
        ("ALRobotPosture", "goToPosture", ["StandInit", 0.5]),
        ("ALMotion", "wakeUp", []),
        ("ALRobotPosture", "goToPosture", ["StandInit", 0.5]),
    ]


def test_speech_overloads_and_bad_configurations(standin, client):
    client.service("ALTextToSpeech").say("Bonjour", "French")
    assert _calls(standin)[-1] == ("ALTextToSpeech", "say", ["Bonjour", "French"])
    with pytest.raises(RuntimeError, match="bodyLanguageMode must be one of"):
        client.service("ALAnimatedSpeech").say("hi", {"bodyLanguageMode": "wild"})
    with pytest.raises(RuntimeError, match="configuration must be a map"):
        client.service("ALAnimatedSpeech").say("hi", "contextual")
    with pytest.raises(RuntimeError, match=r"expects \(text\)"):
        client.service("ALTextToSpeech").say()


def test_text_to_speech_settings_round_trip(client):
    tts = client.service("ALTextToSpeech")
    tts.setLanguage("French")
    assert tts.getLanguage() == "French"
    with pytest.raises(RuntimeError, match="'Greek' is not installed"):  # modelled: only installed voices
        tts.setLanguage("Greek")
    tts.setParameter("speed", 80.0)
    assert tts.getParameter("speed") == pytest.approx(80.0)
    with pytest.raises(RuntimeError, match="unknown parameter"):
        tts.getParameter("nonsense")


@pytest.mark.parametrize(
    "args, problem",
    [
        (("FaceLeds", 0xFF),  "expects"),
        (("FaceLeds", 0x1000000, 0.1), "0xRRGGBB"),
        (("FaceLeds", 2.0, 0.0, 0.0, 0.1), "0..1"),
    ],
)
def test_fade_rgb_rejects_what_naoqi_rejects(client, args, problem):
    with pytest.raises(RuntimeError, match=problem):
        client.service("ALLeds").fadeRGB(*args)


def test_bad_posture_and_gain_are_errors(client):
    with pytest.raises(RuntimeError, match="unknown posture"):
        client.service("ALRobotPosture").goToPosture("Moonwalk", 0.5)
    with pytest.raises(RuntimeError, match="gain"):
        client.service("ALAudioPlayer").playSine(440, 150, 0, 0.1)


def _timed(fn, *args):
    t0 = time.monotonic()
    fn(*args)
    return time.monotonic() - t0


def test_speaking_time_scales_with_text_length_and_speed(monkeypatch):
    """The robot time each call takes, read where the stand-in waits (no wall-clock bound), then once for real."""
    from nao_trainer.robot.standin.recorder import Channel

    real_run = Channel.run
    waits: list[float] = []

    def run(self, seconds: float) -> bool:  # what the stand-in would wait, at its current speed
        waits.append(seconds / self._rec.speed)
        return True

    monkeypatch.setattr(Channel, "run", run)
    with StandIn.start(speed=10.0) as s:
        session = qi.Session()
        session.connect(s.url)
        try:
            tts = session.service("ALTextToSpeech")
            tts.say("x" * 10)
            tts.say("x" * 80)
            s.set_speed(20.0)
            tts.say("x" * 80)
            session.service("ALAudioPlayer").playSine(440, 50, 0, 2.0)
            waits = [w for w in waits if w]  # a zero wait: the beep's latency, none by default
            assert waits == pytest.approx([SECONDS_PER_CHARACTER * 10 / 10.0, SECONDS_PER_CHARACTER * 80 / 10.0,
                                           SECONDS_PER_CHARACTER * 80 / 20.0, 2.0 / 20.0])
            monkeypatch.setattr(Channel, "run", real_run)
            assert _timed(tts.say, "x" * 80) >= SECONDS_PER_CHARACTER * 80 / 20.0  # it really waits (lower bound)
        finally:
            session.close()


def test_long_speech_does_not_block_memory(standin, client):
    """ALTextToSpeech is multi-threaded: a long say must not delay ALMemory or the control service."""
    standin.set_speed(2.0)
    fut = client.service("ALTextToSpeech").say("x" * 30, _async=True)  # 0.9 s
    client.service("ALMemory").insertData("FrontTactilTouched", 0.0)
    standin.press("B")  # holds the button 0.025 s
    assert fut.isRunning()  # ALMemory and the press were served while the say still ran: not queued behind it
    fut.wait()


def test_stop_all_interrupts_speech_and_sound_in_progress(standin, client):
    standin.set_speed(0.05)  # two minutes of speech and of sound: only stopAll ends them within the waits
    tts, anim, audio = (client.service(n) for n in ("ALTextToSpeech", "ALAnimatedSpeech", "ALAudioPlayer"))
    speaking = anim.say("x" * 100, _async=True)
    beeping = audio.playSine(440, 50, 0, 6.0, _async=True)
    time.sleep(0.1)
    tts.stopAll()
    assert speaking.wait(60000) != qi.FutureState.Running  # ended by stopAll, long before its own end
    assert beeping.isRunning()  # speech only
    audio.stopAll()
    assert beeping.wait(60000) != qi.FutureState.Running
    standin.set_speed(1.0)
    assert _timed(tts.say, "x" * 5) >= 5 * SECONDS_PER_CHARACTER  # later speech runs in full


def test_echo_prints_one_line_per_call():
    import io

    echo = io.StringIO()
    with StandIn.start(speed=FAST, echo=echo) as s:
        s.press("A")
    assert echo.getvalue().split()[1:] == ['NaoTrainerStandIn.press("FrontTactilTouched")']


def test_memory_raise_event_reaches_subscribers_of_that_key_only(client, button_signal):
    memory, got = button_signal
    memory.raiseEvent("MiddleTactilTouched", 1.0)
    memory.raiseEvent("FrontTactilTouched", 1.0)
    memory.raiseEvent("FrontTactilTouched", 0.0)
    assert got.wait_for(2) == [1.0, 0.0]
    assert memory.getData("FrontTactilTouched") == 0.0
    assert memory.getData("MiddleTactilTouched") == 1.0
    memory.insertData("Custom/Key", "hello")
    assert memory.getData("Custom/Key") == "hello"
    with pytest.raises(RuntimeError, match="no data for key"):
        memory.getData("Missing/Key")


def test_press_via_control_service_emits_touch_then_release(standin, client, button_signal):
    _, got = button_signal
    control = client.service("NaoTrainerStandIn")
    assert control.press("A") == "FrontTactilTouched"
    assert control.press("front") == "FrontTactilTouched"
    assert control.press("RearTactilTouched") == "RearTactilTouched"
    assert got.wait_for(4) == [1.0, 0.0, 1.0, 0.0]
    assert ("NaoTrainerStandIn", "press", ["RearTactilTouched"]) in _calls(standin)
    with pytest.raises(RuntimeError, match="unknown head button"):
        control.press("Z")


def test_standin_client_controls_a_standin(standin, button_signal):
    _, got = button_signal
    with StandInClient.connect(standin.url) as remote:
        assert remote.press("a") == "FrontTactilTouched"
        remote.set_speed(7.0)
        assert remote.speed() == pytest.approx(7.0)
        assert standin.speed == pytest.approx(7.0)
        assert remote.transcript()[-1]["method"] == "press"
        remote.clear()
        assert standin.transcript() == []
        with pytest.raises(ValueError, match="unknown head button"):
            remote.press("D")
        with pytest.raises(ConfigError, match="positive"):
            remote.set_speed(0)
    assert got.wait_for(2) == [1.0, 0.0]


def test_standin_client_says_what_is_wrong():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]
    with pytest.raises(RobotUnavailable, match="cannot reach the stand-in .*Connection refused"):
        StandInClient.connect(f"tcp://127.0.0.1:{free}", 2.0)
    plain = qi.Session()  # a qi server without the control service, like a real NAO
    plain.listenStandalone("tcp://127.0.0.1:0")
    try:
        with pytest.raises(RobotUnavailable, match="offers no NaoTrainerStandIn control service"):
            StandInClient.connect(plain.endpoints()[0], 2.0)
    finally:
        plain.close()


def test_button_names():
    assert [button_key(b) for b in ("A", "b", "Rear", "MiddleTactilTouched")] == [
        "FrontTactilTouched", "MiddleTactilTouched", "RearTactilTouched", "MiddleTactilTouched",
    ]
    with pytest.raises(ValueError, match="unknown head button 'X'"):
        button_key("X")


def test_transcript_file_is_jsonl_flushed_per_line(tmp_path):
    path = tmp_path / "sub" / "transcript.jsonl"
    with StandIn.start(speed=FAST, transcript_path=path) as s:
        session = qi.Session()
        session.connect(s.url)
        try:
            session.service("ALTextToSpeech").say("one")
            lines = path.read_text().splitlines()  # readable while the stand-in still runs
            assert [json.loads(x)["args"] for x in lines] == [["one"]]
            session.service("ALLeds").fadeRGB("FaceLeds", 0xFF0000, 0.0)
        finally:
            session.close()
        in_memory = s.transcript()
    entries = [json.loads(x) for x in path.read_text().splitlines()]
    assert entries == in_memory
    assert set(entries[0]) == {"t", "service", "method", "args"}
    assert entries[0]["t"] <= entries[1]["t"]


def test_unwritable_transcript_is_a_config_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ConfigError, match="cannot open the transcript file"):
        StandIn.start(transcript_path=blocker / "t.jsonl")


def test_listen_address_checks():
    assert check_listen_url("tcp://127.0.0.1:0") == "tcp://127.0.0.1:0"
    assert check_listen_url("tcp://localhost:9559") == "tcp://localhost:9559"
    with pytest.raises(ConfigError, match="not a loopback address.*--allow-remote"):
        check_listen_url("tcp://192.168.1.20:9559")
    assert check_listen_url("tcp://192.168.1.20:9559", allow_remote=True)
    assert check_listen_url("tcps://127.0.0.1:9503") == "tcps://127.0.0.1:9503"  # NAOqi 2.9, with a login
    with pytest.raises(ConfigError, match="checks a login"):
        StandIn.start("tcps://127.0.0.1:0")
    with pytest.raises(ConfigError, match="not of the form"):
        check_listen_url("127.0.0.1")
    with pytest.raises(ConfigError, match="positive"):
        StandIn.start(speed=0)


def test_port_in_use_is_a_clear_error(standin):
    with pytest.raises(RobotUnavailable, match="cannot listen on .*pick another port"):
        StandIn.start(standin.url)


def test_stop_ends_a_pending_say_at_once():
    s = StandIn.start(speed=0.01)  # a 10-character say would take a minute
    session = qi.Session()
    session.connect(s.url)
    try:
        fut = session.service("ALTextToSpeech").say("0123456789", _async=True)
        time.sleep(0.2)
        s.stop()
        assert fut.wait(30000) != qi.FutureState.Running  # a minute of speech: ended by stop(), not by its end
    finally:
        session.close()


# --- the command line -------------------------------------------------------------------------


def _cli(*args):
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    return subprocess.Popen(
        [sys.executable, "-m", "nao_trainer", "mock-robot", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_cli_prints_ready_line_serves_and_exits_cleanly(tmp_path, sig):
    transcript = tmp_path / "t.jsonl"
    proc = _cli("--listen", "tcp://127.0.0.1:0", "--speed", "40", "--transcript", str(transcript), "--echo")
    try:
        line = proc.stdout.readline()
        assert line.startswith(READY_PREFIX)
        url = line[len(READY_PREFIX):].strip()
        assert url.startswith("tcp://127.0.0.1:") and not url.endswith(":0")
        with StandInClient.connect(url) as remote:
            remote.press("C")
            assert remote.speed() == pytest.approx(40.0)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert json.loads(transcript.read_text().splitlines()[0])["args"] == ["RearTactilTouched"]
    assert 'NaoTrainerStandIn.press("RearTactilTouched")' in err and out == ""


def test_cli_refuses_a_remote_address_in_one_line():
    proc = _cli("--listen", "tcp://10.1.2.3:9559")
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 2
    assert err.count("\n") == 1 and "not a loopback address" in err and "Traceback" not in err
    assert out == ""


def test_spawn_standin_returns_process_and_url():
    proc, url = spawn_standin(speed=30)
    try:
        with StandInClient.connect(url) as remote:
            assert remote.speed() == pytest.approx(30.0)
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0


def test_spawn_standin_on_a_busy_port_reports_why(standin):
    port = int(standin.url.rsplit(":", 1)[1])
    with pytest.raises(RobotUnavailable, match=f"did not start: .*cannot listen on tcp://127.0.0.1:{port}: the port is already in use"):
        spawn_standin(port=port)


def test_almemory_serves_only_what_naoqi_serves(client):
    """The stand-in's own helpers (emit a touch, forget subscribers on stop) are not on the wire (qi.nobind)."""
    names = {n for n in dir(client.service("ALMemory")) if not n.startswith("_")}
    assert {"raiseEvent", "insertData", "getData", "subscriber"} <= names
    assert not {"emit", "forget_subscribers"} & names


def test_the_link_stops_quietly_with_connections_mid_relay():
    """stop() cancelled the relay's tasks and stopped its loop at once: a connection still open printed
    "Exception in callback ... CancelledError" (asyncio's stream callback) on a session's terminal
    (seen with two suites side by side, and "_GatheringFuture exception was never retrieved")."""
    import asyncio
    import gc
    import socket

    from nao_trainer.robot.standin.link import Link

    target = socket.create_server(("127.0.0.1", 0))
    link = Link(target.getsockname()[1]).start()
    said: list[dict] = []
    link._loop.set_exception_handler(lambda loop, context: said.append(context))
    clients = [socket.create_connection(("127.0.0.1", link.port), timeout=5) for _ in range(20)]
    upstream = [target.accept()[0] for _ in clients]  # every relay connected both ways, its pumps running
    for c in clients:
        c.sendall(b"hello")
    for u in upstream:
        assert u.recv(5) == b"hello"
    async def relays() -> list:
        return [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]

    tasks = asyncio.run_coroutine_threadsafe(relays(), link._loop).result(5)
    assert len(tasks) >= len(clients) * 5  # per connection: the client's task, two pumps, their two senders
    try:
        link.stop()
        gc.collect()  # a future never retrieved says so when it is collected
    finally:
        for s in (*clients, *upstream, target):
            s.close()
    assert not link._thread.is_alive()
    # every relay task ended before the loop stopped (left pending, they end cancelled whenever the loop runs on,
    # which is what printed the traceback) and the loop had nothing to complain of
    assert [t for t in tasks if not t.done()] == []
    # and no connection's task ended cancelled: asyncio's stream callback asks it for its exception, which for a
    # cancelled task raises CancelledError inside the callback (the traceback seen)
    handlers = [t for t in tasks if t.get_coro().__qualname__ == "Link._client"]
    assert len(handlers) == len(clients) and not any(t.cancelled() for t in handlers)
    assert said == []
