"""Issue 18 "done when": the attacks of items 1-4 against a running 25-turn session.

`nao-trainer run --console` (the in-process NAO stand-in over qi on loopback, simulated
participant, EEG off) runs in a subprocess whose file limit is lowered to 256, so that the
half-open sockets of the attack outnumber what the process may open. While it plays, this test
sends malformed authenticated commands, holds 400 half-open sockets, floods 403s with long paths
and oversized requests, and posts oversized, deep and NaN bodies, all on loopback and bounded in
count. The session must complete every turn with exit code 0, `events.jsonl` stay under 1 MB, the
operator's terminal show uvicorn's "Invalid HTTP request" at most once, and the token holder's
`/state` answer throughout (a generous time-out: no timing assertion).
"""
from __future__ import annotations

import http.client
import json
import os
import resource
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from nao_trainer.session.record import read_turns

NOFILE = 256
TURNS = 25


def _lower_nofile() -> None:
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    resource.setrlimit(resource.RLIMIT_NOFILE, (NOFILE, hard))


def _launch(out: Path) -> tuple[subprocess.Popen, list[str], threading.Thread]:
    """The 25-turn session under the lowered file limit, its stderr read into a list as it comes."""
    # PYTHONFAULTHANDLER: a native crash (qi, uvicorn's C parts) prints every thread's Python stack.
    env = dict(os.environ, QI_LOG_LEVEL="silent", PYTHONFAULTHANDLER="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "nao_trainer", "run", "--console", "--turns", str(TURNS), "--speed", "25",
         "--eeg", "off", "--no-practice", "--policy", "usp:2", "--out", str(out), "--pseudonym", "A1",
         "--no-keys"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, stdin=subprocess.DEVNULL,
        preexec_fn=_lower_nofile)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(ln.rstrip("\n") for ln in proc.stderr), daemon=True)
    reader.start()
    return proc, lines, reader


def _start_session(tmp_path: Path) -> tuple[subprocess.Popen, list[str], threading.Thread]:
    """The session, once its console is up (before any attack).

    One native crash of the process before its console is up (a SIGSEGV inside qi while the in-process
    stand-in starts, seen once in ~40 CI runs and 0 of 40 runs by hand under load) is retried once, with its
    stack printed: it happens before anything this test attacks, and is not what the test is about. A
    second crash, an exit with a code, or any crash once the console is up fails the test.
    """
    for attempt in range(2):
        out = tmp_path / f"attempt{attempt}"
        proc, lines, reader = _launch(out)
        deadline = time.monotonic() + 60
        while not any(ln.startswith("console: ") for ln in lines) and time.monotonic() < deadline:
            rc = proc.poll()
            if rc is not None:
                break
            time.sleep(0.05)
        else:
            assert any(ln.startswith("console: ") for ln in lines), "no console within 60 s:\n" + "\n".join(lines[-20:])
            return proc, lines, reader
        proc.wait(30)
        reader.join(10)  # the rest of stderr, with the crash's stack
        assert rc < 0 and attempt == 0, f"exit {rc} before the console was up:\n" + "\n".join(lines[-40:])
        print(f"native crash (signal {-rc}) before the console was up; retried once:\n" + "\n".join(lines[-40:]))
    raise AssertionError("unreachable")


class Target:
    def __init__(self, link: str) -> None:
        base = link.split("?")[0]
        host_port, self.prefix = base.split("//")[1].split("/", 1)
        self.host, port = host_port.rsplit(":", 1)
        self.port, self.prefix, self.token = int(port), "/" + self.prefix, link.split("token=")[1]

    def request(self, method: str, path: str, body: bytes | None = None, headers: dict | None = None,
                token: bool = True, timeout: float = 30) -> tuple[int, bytes]:
        conn = http.client.HTTPConnection(self.host, self.port, timeout=timeout)
        try:
            h = {"Content-Type": "application/json", **(headers or {})}
            if token:
                h["X-Console-Token"] = self.token
            conn.request(method, self.prefix + path, body=body, headers=h)
            r = conn.getresponse()
            return r.status, r.read()
        finally:
            conn.close()


def _flood_403(t: Target, n: int, path_len: int) -> list[int]:
    """``n`` unauthenticated requests with long paths over keep-alive connections."""
    statuses = []
    conn = http.client.HTTPConnection(t.host, t.port, timeout=30)
    for i in range(n):
        try:
            conn.request("GET", t.prefix + "state/" + "a" * path_len)
            r = conn.getresponse()
            r.read()
            statuses.append(r.status)
        except (http.client.HTTPException, OSError):
            conn.close()
            conn = http.client.HTTPConnection(t.host, t.port, timeout=30)
    conn.close()
    return statuses


def _oversized(t: Target, n: int) -> None:
    """Requests whose head is larger than the server reads (uvicorn: "Invalid HTTP request received.")."""
    for _ in range(n):
        try:
            with socket.create_connection((t.host, t.port), timeout=10) as s:
                s.sendall(b"GET /" + b"b" * 100_000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                s.recv(1024)
        except OSError:
            pass


def _half_open(t: Target, n: int) -> list[socket.socket]:
    """``n`` sockets that connect and never finish (or never start) a request."""
    socks = []
    for i in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setblocking(False)
        s.connect_ex((t.host, t.port))
        socks.append(s)
    time.sleep(0.5)
    for s in socks[::2]:  # half of them start a request and stop mid-headers
        try:
            s.send(b"GET " + t.prefix.encode() + b"state HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        except OSError:
            pass
    return socks


@pytest.mark.slow
def test_the_attacks_of_issue_18_leave_a_running_session_complete_and_the_supervisor_in(tmp_path):
    proc, lines, reader = _start_session(tmp_path)
    socks: list[socket.socket] = []
    try:
        t = Target(next(ln.split()[1] for ln in lines if ln.startswith("console: ")))
        attack_start = time.monotonic()
        state_answers: list[int] = []
        waits: list[float] = []  # printed (pytest -s), not asserted: a loaded machine may be slow

        def state() -> int:
            t0 = time.monotonic()
            status = t.request("GET", "state")[0]
            waits.append(round(time.monotonic() - t0, 3))
            return status

        # item 1: malformed commands from the token holder: 400, nothing queued
        for args in ({"turn": "abc"}, {"turn": [1]}, {"turn": 10**30}):
            assert t.request("POST", "command", json.dumps({"kind": "invalid", "args": args}).encode())[0] == 400
        assert t.request("POST", "command", b'{"kind":"invalid","args":{"turn":1e400}}')[0] == 400
        # item 2: more half-open sockets than the session process may open files
        socks = _half_open(t, 400)
        state_answers.append(state())
        # item 3: a flood of 403s with long paths, and oversized requests
        floods = [threading.Thread(target=_flood_403, args=(t, 300, 8000)) for _ in range(4)]
        floods.append(threading.Thread(target=_oversized, args=(t, 100)))
        for th in floods:
            th.start()
        state_answers.append(state())
        # item 4: bodies too large, too deep, NaN; long notes within the limit are fine
        assert t.request("POST", "command", b"[" * 100_000)[0] == 413
        assert t.request("POST", "command", b'{"kind":"note","args":{"text":NaN}}')[0] == 400
        big = b'{"kind":"note","args":{"text":"' + b"n" * (50 * 1024 * 1024) + b'"}}'
        try:
            status = t.request("POST", "command", big)[0]
        except (BrokenPipeError, ConnectionResetError):
            status = 413  # the server answered 413 and closed while the body was still being sent
        assert status == 413
        for _ in range(3):
            assert t.request("POST", "command", json.dumps({"kind": "note", "args": {"text": "m" * 2000}}).encode())[0] == 202
        for th in floods:
            th.join(120)
        state_answers.append(state())
        attack_s = time.monotonic() - attack_start
        assert proc.poll() is None, "the session ended during the attack:\n" + "\n".join(lines[-20:])
        status, body = t.request("GET", "state")
        assert status == 200 and json.loads(body)["session"]["turns"] == TURNS
        assert state_answers == [200, 200, 200]
        print(f"the token holder's /state during the attack answered in {waits} s")
        assert proc.wait(240) == 0, "\n".join(lines[-30:])
        print(f"the attack lasted {attack_s:.1f} s of the session's {time.monotonic() - attack_start:.1f} s")
    finally:
        for s in socks:
            s.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)
    reader.join(10)
    folder = sorted(Path(tmp_path).glob("attempt*/A1_*"))[-1]  # the last attempt's
    rows = [r for r in read_turns(folder) if r["success"] in ("True", "False")]
    assert [int(r["turn"]) for r in rows] == list(range(1, TURNS + 1))
    assert json.loads((folder / "session.json").read_text())["status"] == "completed"
    size = (folder / "events.jsonl").stat().st_size
    print(f"events.jsonl after the attack: {size} bytes")
    assert size < 1_000_000
    assert sum("Invalid HTTP request" in ln for ln in lines) <= 1
    assert not any("Traceback" in ln or "Too many open files" in ln for ln in lines), "\n".join(lines[-30:])
