"""The console's server over HTTP (no browser): several viewers, reconnection, commands, binding rules."""
from __future__ import annotations

import http.client
import json

import pytest

from nao_trainer.console.server import COOKIE, Console, ConsoleHub
from nao_trainer.errors import ConfigError
from nao_trainer.ports import CommandQueue
from nao_trainer.session.config import load_config
from nao_trainer.session.wiring import RunOptions, _console_bind


def read_events(console: Console, n: int) -> list[tuple[str, dict]]:
    """Open /events, read ``n`` events (the snapshot first) and drop the connection."""
    conn = http.client.HTTPConnection(console.host, console.port, timeout=10)
    conn.request("GET", "/events", headers={"Cookie": f"{COOKIE}={console.token}"})
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
        conn.request("POST", "/command", body=json.dumps(body), headers={"Content-Type": ctype, "x-console-token": token})
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
