"""The console's server over HTTP (no browser): several viewers, reconnection, commands, binding rules."""
from __future__ import annotations

import http.client
import json
import shutil

import pytest

from nao_trainer.console.server import COOKIE, Console, ConsoleHub
from nao_trainer.errors import ConfigError
from nao_trainer.ports import CommandQueue
from nao_trainer.session.config import load_config
from nao_trainer.session.wiring import RunOptions, _console_bind

NEEDS_OPENSSL = pytest.mark.skipif(shutil.which("openssl") is None,
                                   reason="no openssl command (apt-get install openssl): the console's TLS was not tested")


def read_events(console: Console, n: int) -> list[tuple[str, dict]]:
    """Open /events, read ``n`` events (the snapshot first) and drop the connection."""
    conn = http.client.HTTPConnection(console.host, console.port, timeout=10)
    conn.request("GET", console.prefix + "events", headers={"Cookie": f"{COOKIE}={console.token}"})
    resp = conn.getresponse()
    assert resp.status == 200 and resp.getheader("content-type").startswith("text/event-stream")
    out, kind = [], None
    while len(out) < n:
        line = resp.readline().decode().rstrip("\n")
        if line.startswith("event: "):
            kind = line[7:]
        elif line.startswith("data: ") and kind != "tick":
            out.append((kind, json.loads(line[6:])))
    conn.close()
    return out


@pytest.fixture()
def console():
    queue = CommandQueue()
    c = Console.start(queue, "127.0.0.1", 0, hub=ConsoleHub())
    c.queue = queue
    yield c
    c.stop()


def test_viewers_get_a_snapshot_then_live_events_and_a_reconnect_gets_everything(console):
    hub = console.hub
    hub.notify("session", {"turns": 5, "state": "greet", "robot": "connected"})
    hub.notify("row", {"turn": 1, "success": True, "score": 1, "total": 1})
    first = read_events(console, 1)
    assert first[0][0] == "snapshot" and first[0][1]["rows"][0]["turn"] == 1
    # two viewers at once, both see a new row
    import threading

    got: dict[int, list] = {}
    threads = [threading.Thread(target=lambda i=i: got.__setitem__(i, read_events(console, 2))) for i in range(2)]
    for t in threads:
        t.start()
    import time

    deadline = time.monotonic() + 5
    while console.hub.viewers < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    hub.notify("row", {"turn": 2, "success": False, "score": -1, "total": 0})
    for t in threads:
        t.join(10)
    assert all(g[1] == ("row", {"turn": 2, "success": False, "score": -1, "total": 0}) for g in got.values())
    # a dropped viewer that reconnects gets the whole state again
    again = read_events(console, 1)[0][1]
    assert [r["turn"] for r in again["rows"]] == [1, 2]


def test_commands_are_queued_with_their_source_and_bad_ones_refused(console):
    def post(body, ctype="application/json", token=console.token):
        conn = http.client.HTTPConnection(console.host, console.port, timeout=10)
        conn.request("POST", console.prefix + "command", body=json.dumps(body), headers={"Content-Type": ctype, "x-console-token": token})
        r = conn.getresponse()
        return r.status, r.read()

    assert post({"kind": "override", "args": {"action": "L3"}})[0] == 202
    assert post({"kind": "dance"})[0] == 400
    assert post({"kind": "pause"}, ctype="text/plain")[0] == 415  # a plain form cannot send commands
    assert post({"kind": "pause"}, token="wrong")[0] == 403
    cmds = console.queue.drain()
    assert [(c.kind, c.args, c.source) for c in cmds] == [("override", {"action": "L3"}, "console")]


def test_only_loopback_unless_asked_on_the_command_line():
    cfg = load_config(None, {"console.enabled": True, "console.bind": "0.0.0.0"})
    with pytest.raises(ConfigError, match="--console-bind"):
        _console_bind(cfg, RunOptions())
    assert _console_bind(cfg, RunOptions(console_bind="0.0.0.0")) == "0.0.0.0"
    assert _console_bind(load_config(None, {}), RunOptions()) is None  # no console unless asked
    assert _console_bind(load_config(None, {}), RunOptions(console=True)) == "127.0.0.1"


def test_another_loopback_address_serves_plain_http_and_the_link_never_reaches_the_files(tmp_path):
    import io

    from nao_trainer.session.record import read_events
    from nao_trainer.session.wiring import run_session

    cfg = load_config(None, {"session.turns": 1, "timing.speed": 50.0, "eeg.mode": "off", "session.practice": False,
                             "session.output": str(tmp_path)})
    out = io.StringIO()
    result = run_session(cfg, RunOptions(console=True, console_bind="127.0.0.2"), progress=out)
    text = out.getvalue()
    assert result.exit_code == 0
    assert "warning" not in text  # 127.0.0.0/8 is this machine only: nothing crosses a network
    link = next(ln.split()[1] for ln in text.splitlines() if ln.startswith("console: "))
    assert link.startswith("http://127.0.0.2:") and "token=" in link
    token = link.split("token=")[1]
    assert token not in "".join(p.read_text() for p in result.path.iterdir() if p.is_file())
    ev = next(e for e in read_events(result.path) if e["event"] == "console")
    assert ev["bind"] == "127.0.0.2" and "token" not in ev["url"]


def test_ctrl_c_still_reaches_the_session_with_the_console_running(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", "--console", "--speed", "5", "--eeg", "off",
                             "--out", str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, QI_LOG_LEVEL="silent"), stdin=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        for line in proc.stderr:
            if line.startswith("console: ") or time.monotonic() > deadline:
                break
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 130 and "status: interrupted (exit 130)" in out


def test_the_eeg_alert_is_kept_for_viewers_that_connect_later():
    hub = ConsoleHub()
    hub.notify("eeg", {"missing_turns": 3, "turn": 4, "reason": "EEG stream lost"})
    assert hub.state["eeg_missing"] == {"missing_turns": 3, "turn": 4, "reason": "EEG stream lost"}
    hub.notify("eeg", {"missing_turns": 0, "turn": 6})  # back
    assert hub.state["eeg_missing"] is None


def _post_raw(console, body: bytes, headers: dict) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection(console.host, console.port, timeout=10)
    conn.putrequest("POST", console.prefix + "command")
    for k, v in {"x-console-token": console.token, "Content-Type": "application/json", **headers}.items():
        conn.putheader(k, v)
    conn.endheaders()
    try:
        conn.send(body)
    except (BrokenPipeError, ConnectionResetError):
        pass
    r = conn.getresponse()
    out = r.status, r.read()
    conn.close()
    return out


def test_size_depth_and_nan_are_refused_at_the_door_and_nothing_reaches_the_queue(console):
    # issue 18 items 1 and 4: each of these was queued (or a 500) before
    huge = _post_raw(console, b"{" + b" " * 1024, {"Content-Length": str(300 * 1024 * 1024)})  # announced 300 MB
    assert huge[0] == 413 and b"at most" in huge[1]
    chunked = _post_raw(console, b"".join(b"%x\r\n%s\r\n" % (4096, b" " * 4096) for _ in range(8)) + b"0\r\n\r\n",
                        {"Transfer-Encoding": "chunked"})
    assert chunked[0] == 413
    for body in (b"[" * 100_000, b'{"kind":"note","args":{"text":NaN}}', b'{"kind":"invalid","args":{"turn":"abc"}}',
                 b'{"kind":"invalid","args":{"turn":1e400}}', b'{"kind":"note","args":{"text":"' + b"x" * 3000 + b'"}}'):
        status, text = _post_raw(console, body, {"Content-Length": str(len(body))})
        assert status in (400, 413) and json.loads(text)["error"].count("\n") == 0
    assert len(console.queue) == 0


def test_state_and_the_event_stream_never_carry_nan(console):
    console.hub.notify("session", {"turns": 3, "state": "greet"})
    console.hub.notify("row", {"turn": 1, "engagement": float("nan"), "success": True})
    conn = http.client.HTTPConnection(console.host, console.port, timeout=10)
    conn.request("GET", console.prefix + "state", headers={"x-console-token": console.token})
    r = conn.getresponse()
    text = r.read().decode()
    assert r.status == 200 and "NaN" not in text
    assert json.loads(text, parse_constant=lambda c: pytest.fail(c))["rows"][0]["engagement"] is None
    assert "NaN" not in console.hub.snapshot()[1]  # what a new viewer's stream starts with
    assert read_events(console, 1)[0][1]["rows"][0]["engagement"] is None


def test_the_cookie_is_scoped_to_this_console_and_the_link_carries_its_path(console):
    assert console.link.startswith(f"http://127.0.0.1:{console.port}/c/") and console.prefix.endswith("/")
    conn = http.client.HTTPConnection(console.host, console.port, timeout=10)
    conn.request("GET", f"{console.prefix}?token={console.token}")
    r = conn.getresponse()
    cookie = r.getheader("set-cookie")
    assert r.status == 303 and r.getheader("location") == console.prefix
    assert f"Path={console.prefix}" in cookie and "HttpOnly" in cookie and "SameSite=strict" in cookie
    conn.close()


@NEEDS_OPENSSL
def test_a_console_over_tls_prints_its_fingerprint_and_answers_only_over_tls(tmp_path):
    # issue 18 item 7; TLS forced on loopback: tests never bind a real network interface
    import ssl

    from nao_trainer.console.tls import fingerprint

    queue = CommandQueue()
    c = Console.start(queue, "127.0.0.1", 0, hub=ConsoleHub(), tls=True)
    try:
        assert c.link.startswith("https://127.0.0.1:") and len(c.fingerprint.split(":")) == 32
        ctx = ssl.create_default_context()
        ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE  # self-signed: the fingerprint is the check
        conn = http.client.HTTPSConnection(c.host, c.port, timeout=10, context=ctx)
        conn.request("GET", c.prefix + "state", headers={"x-console-token": c.token})
        assert conn.getresponse().status == 200
        assert fingerprint(ssl.DER_cert_to_PEM_cert(conn.sock.getpeercert(binary_form=True))) == c.fingerprint
        conn.close()
        plain = http.client.HTTPConnection(c.host, c.port, timeout=10)
        with pytest.raises((http.client.HTTPException, ConnectionError, OSError)):
            plain.request("GET", c.prefix + "state", headers={"x-console-token": c.token})
            plain.getresponse()
    finally:
        c.stop()


def test_beyond_loopback_the_console_serves_tls_or_needs_the_insecure_flag(monkeypatch):
    # The rule of console.launch, checked with the server's start recorded instead of binding 0.0.0.0.
    import io

    from nao_trainer.console import launch

    started, logged = [], []

    class Fake:
        hub, url, link, fingerprint = ConsoleHub(), "https://192.0.2.7:1/c/x/", "https://192.0.2.7:1/c/x/?token=t", "AB:CD"

        @classmethod
        def start(cls, commands, bind, port, log, tls):
            started.append((bind, tls))
            return cls()

    monkeypatch.setattr(launch, "Console", Fake)
    out = io.StringIO()
    log = lambda event, **kw: logged.append((event, kw))  # noqa: E731
    launch.open_console(CommandQueue(), "0.0.0.0", 0, log, out)
    launch.open_console(CommandQueue(), "0.0.0.0", 0, log, out, insecure=True)
    launch.open_console(CommandQueue(), "127.0.0.1", 0, log, out)
    launch.open_console(CommandQueue(), "127.0.0.1", 0, log, out, force_tls=True)
    assert started == [("0.0.0.0", True), ("0.0.0.0", False), ("127.0.0.1", False), ("127.0.0.1", True)]
    text = out.getvalue()
    assert "SHA-256 fingerprint: AB:CD" in text and "in clear text (--console-insecure)" in text
    assert "console: https://192.0.2.7:1/c/x/?token=t (open it in a browser on this machine or another" in text
    assert [(e, kw["tls"], kw["fingerprint"]) for e, kw in logged][:2] == [("console", True, "AB:CD"),
                                                                          ("console", False, "AB:CD")]


def test_a_wildcard_bind_prints_an_address_another_machine_can_open():
    from nao_trainer.console.server import reachable_address

    assert reachable_address("127.0.0.1") == "127.0.0.1"
    wide = reachable_address("0.0.0.0")
    assert wide not in ("0.0.0.0", "", "127.0.0.1")
