"""NAOqi 2.9's login over ``tcps://``: the stand-in behind a TLS proxy on loopback, credentials from the environment."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import qi

from _tls_proxy import TlsProxy
from nao_trainer.errors import ConfigError, RobotUnavailable
from nao_trainer.files import PROJECT_ROOT
from nao_trainer.robot.address import AuthenticatorFactory
from nao_trainer.robot.naoqi import Credentials, NaoqiRobot
from nao_trainer.robot.standin import Login, StandIn

USER, PASSWORD = "nao-lab", "pw-Xy7-not-in-the-clear"


@pytest.fixture()
def tls(tmp_path):
    standin = StandIn.start("tcp://127.0.0.1:0", speed=50)
    proxy = TlsProxy(int(standin.url.rsplit(":", 1)[1]), tmp_path).start()
    yield standin, proxy
    proxy.stop()
    standin.stop()


def test_login_goes_over_tls_and_a_call_succeeds(tls, monkeypatch):
    standin, proxy = tls
    monkeypatch.setenv("NAO_USER", USER)
    monkeypatch.setenv("NAO_PASSWORD", PASSWORD)
    robot = NaoqiRobot.connect(proxy.url, 5.0)
    try:
        robot.say("over TLS")
        robot.wake_up()
        assert robot.go_to_posture("Stand", 1.0)
    finally:
        robot.close()
    said = [e["args"][0] for e in standin.transcript() if e["method"] == "say"]
    assert said == ["over TLS"]
    assert proxy.handshakes >= 1 and proxy.wire[:1] == b"\x16"  # a TLS handshake record opened the link
    assert USER.encode() in proxy.plain and PASSWORD.encode() in proxy.plain  # the authenticator's login was sent
    assert PASSWORD.encode() not in proxy.wire  # ... and never crossed the wire in the clear


@pytest.mark.parametrize("env, missing", [({"NAO_USER": USER}, "NAO_PASSWORD is not set"),
                                          ({"NAO_PASSWORD": PASSWORD}, "NAO_USER is not set"),
                                          ({}, "set NAO_USER and NAO_PASSWORD")])
def test_a_missing_credential_is_said_before_connecting(tls, monkeypatch, env, missing):
    _, proxy = tls
    for name in ("NAO_USER", "NAO_PASSWORD"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    with pytest.raises(ConfigError, match=missing) as info:
        NaoqiRobot.connect(proxy.url, 5.0)
    assert "\n" not in str(info.value) and PASSWORD not in str(info.value)
    assert proxy.connections == 0  # refused before any connection


def test_a_session_runs_over_tls_from_the_command_line(tls, tmp_path):
    standin, proxy = tls
    out = tmp_path / "out"
    env = dict(os.environ, NAO_USER=USER, NAO_PASSWORD=PASSWORD, QI_LOG_LEVEL="silent")
    study = str(PROJECT_ROOT / "config" / "default.yaml")  # a robot address needs a study (never the demo)
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--config", study, "--robot", proxy.url, "--turns", "2",
                          "--speed", "50", "--eeg", "off", "--policy", "schedule", "--input", "simulated", "--pseudonym", "P1",
                          "--out", str(out), "--seed", "1"], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    (folder,) = out.glob("*")
    assert len((folder / "turns.csv").read_text().splitlines()) == 3
    session = json.loads((folder / "session.json").read_text())
    assert session["robot"] == proxy.url
    for path in folder.rglob("*"):
        if path.is_file():
            assert PASSWORD not in path.read_text(errors="replace"), path
    assert PASSWORD not in res.stdout + res.stderr
    assert any(e["method"] == "playSine" for e in standin.transcript())


# -- the stand-in's own tcps front: a login checked as libqi's server checks it ---------------------


@pytest.fixture()
def tcps_standin():
    standin = StandIn.start("tcps://127.0.0.1:0", speed=50, login=Login(USER, PASSWORD))
    yield standin
    standin.stop()


def test_tcps_standin_accepts_the_right_login(tcps_standin):
    with NaoqiRobot.connect(tcps_standin.url, 5.0, Credentials(USER, PASSWORD)) as robot:
        robot.say("logged in")
    assert [e["args"] for e in tcps_standin.transcript() if e["method"] == "say"] == [["logged in"]]
    assert tcps_standin.link.refused_logins == 0


@pytest.mark.parametrize("creds", [Credentials(USER, "wrong-password"), Credentials("someone-else", PASSWORD)])
def test_tcps_standin_refuses_a_wrong_login_as_libqi_reports_it(tcps_standin, creds):
    with pytest.raises(RobotUnavailable) as info:
        NaoqiRobot.connect(tcps_standin.url, 5.0, creds)
    message = str(info.value)
    # qi 3.1.5 does not enforce authentication on its side, so libqi's "Authentication failed" reply
    # surfaces as the server closing the link; the message names the variables to check.
    assert "NAO_USER / NAO_PASSWORD" in message and "\n" not in message
    assert PASSWORD not in message and "wrong-password" not in message
    assert tcps_standin.link.refused_logins == 1
    assert not any(e["method"] == "say" for e in tcps_standin.transcript())


def test_raw_qi_client_sees_what_libqi_reports_for_a_refused_login(tcps_standin):
    """What the qi binding itself raises (no adapter in between), so the adapter's reading stays honest."""
    session = qi.Session()
    session.setClientAuthenticatorFactory(AuthenticatorFactory(Credentials(USER, "nope")))
    with pytest.raises(RuntimeError, match="disconnected"):
        session.connect(tcps_standin.url)
    session.close()
