"""The console's socket, host and logging defences (issue 18 items 2, 3 and 6), on loopback, bounded in count."""
from __future__ import annotations

import http.client
import logging
import shutil
import socket
import time

import pytest

from nao_trainer.console.guard import (HostCheck, QuietServerLog, RejectLog, connection_limit, is_loopback)
from nao_trainer.console.server import Console, ConsoleHub
from nao_trainer.ports import CommandQueue

NEEDS_OPENSSL = pytest.mark.skipif(shutil.which("openssl") is None,
                                   reason="no openssl command (apt-get install openssl): the console's TLS was not tested")


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_refusals_are_logged_at_a_bounded_rate_truncated_and_counted():
    clock, logged = Clock(), []
    log = RejectLog(lambda event, **kw: logged.append((event, kw)), burst=5, every_s=2.0, clock=clock)
    for _ in range(1000):
        log("console_forbidden", path="/" + "a" * 100_000, client="127.0.0.1")
    assert len(logged) == 5 and all(len(kw["path"]) == 120 for _, kw in logged)
    clock.t = 2.0  # one more allowed every 2 s; it says how many were not logged
    log("console_forbidden", path="/x")
    assert logged[-1][1] == {"path": "/x", "not_logged_before": 995}
    log("console_forbidden", path="/y")
    log.flush()
    assert logged[-1] == ("console_rejected_not_logged", {"count": 1})


def test_server_warnings_are_shown_once_a_minute_with_a_count():
    clock = Clock()
    quiet = QuietServerLog(every_s=60, clock=clock)
    rec = lambda: logging.LogRecord("uvicorn.error", logging.WARNING, "", 0, "Invalid HTTP request received.", (), None)
    shown = [r for r in (rec() for _ in range(802)) if quiet.filter(r)]
    assert len(shown) == 1
    clock.t = 61
    again = rec()
    assert quiet.filter(again) and "801 more like it not shown" in again.getMessage()


def test_host_allow_list_and_loopback_rule():
    hosts = HostCheck.for_bind("127.0.0.1")
    assert all(hosts.allows(h) for h in ("127.0.0.1:8000", "localhost:1", "LOCALHOST", "[::1]:80", "127.0.0.1"))
    assert not any(hosts.allows(h) for h in ("evil.example", "evil.example:8000", "127.0.0.1.nip.io", "", None))
    wide = HostCheck.for_bind("0.0.0.0", ["192.168.1.20"])
    assert wide.allows("192.168.1.20:5000") and wide.allows(socket.gethostname()) and not wide.allows("10.0.0.1")
    assert is_loopback("127.0.0.2") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.20") and not is_loopback("my-laptop")


def test_the_console_keeps_a_quarter_of_the_file_limit_at_most():
    assert connection_limit(1024) == 256 and connection_limit(256) == 64 and connection_limit(20) == 8
    assert connection_limit(1 << 20) == 256


def _state(console, timeout=10.0):
    conn = http.client.HTTPConnection(console.host, console.port, timeout=timeout)
    conn.request("GET", console.prefix + "state", headers={"x-console-token": console.token})
    status = conn.getresponse().status
    conn.close()
    return status


def _state_with_retries(console, tries: int = 3) -> int:
    """``/state`` as a browser gets it: a connection reset while the cap evicts an old socket is retried."""
    for attempt in range(tries):
        try:
            return _state(console)
        except (ConnectionResetError, http.client.RemoteDisconnected):
            if attempt == tries - 1:
                raise
            time.sleep(0.2)
    raise AssertionError("unreachable")


def _closed_by_server(sock: socket.socket, within: float) -> bool:
    sock.settimeout(within)
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True
    except socket.timeout:
        return False


def test_half_open_sockets_are_capped_and_timed_out_and_the_token_holder_still_gets_state():
    console = Console.start(CommandQueue(), "127.0.0.1", 0, hub=ConsoleHub(), max_connections=8, header_timeout_s=1.0)
    socks: list[socket.socket] = []
    try:
        for i in range(40):  # 5x the cap: half-open, headers never finished
            s = socket.create_connection((console.host, console.port), timeout=10)
            socks.append(s)
            try:
                s.sendall(b"GET " + console.prefix.encode() + b"state HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
            except OSError:  # already closed by the server (evicted, or refused by the listener's bound)
                pass
        deadline = time.monotonic() + 20
        while console.protocol.open_connections() > 8 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert console.protocol.open_connections() <= 8  # the rest were evicted, oldest first
        assert _closed_by_server(socks[0], 10)
        assert _state_with_retries(console) == 200  # the token holder gets in (as a browser does, retrying)
        # the header deadline closes a socket that never finishes its headers (uvicorn has none)
        late = socket.create_connection((console.host, console.port), timeout=10)
        late.sendall(b"GET / HTTP/1.1\r\n")
        assert _closed_by_server(late, 20)
        late.close()
    finally:
        for s in socks:
            s.close()
        console.stop()


def test_event_streams_are_capped():
    from nao_trainer.console import server

    console = Console.start(CommandQueue(), "127.0.0.1", 0, hub=ConsoleHub())
    conns = []
    try:
        statuses = []
        for _ in range(server.MAX_STREAMS + 2):
            conn = http.client.HTTPConnection(console.host, console.port, timeout=10)
            conn.request("GET", console.prefix + "events", headers={"x-console-token": console.token})
            statuses.append(conn.getresponse().status)
            conns.append(conn)
        assert statuses.count(200) == server.MAX_STREAMS and statuses[-2:] == [503, 503]
        assert _state(console) == 200
    finally:
        for c in conns:
            c.close()
        console.stop()


@pytest.mark.parametrize("host", ["evil.example", "127.0.0.1.evil.example:80"])
def test_a_host_not_on_the_list_gets_421_even_with_the_token(host):
    logged = []
    console = Console.start(CommandQueue(), "127.0.0.1", 0, hub=ConsoleHub(), log=lambda e, **kw: logged.append(e))
    try:
        conn = http.client.HTTPConnection(console.host, console.port, timeout=10)
        conn.request("GET", console.prefix + "state", headers={"x-console-token": console.token, "Host": host})
        assert conn.getresponse().status == 421
        conn.close()
        assert _state(console) == 200 and logged == ["console_wrong_host"]
    finally:
        console.stop()


def _fds() -> int:
    import os

    return len(os.listdir("/proc/self/fd"))


@pytest.mark.parametrize("tls", [False, pytest.param(True, marks=NEEDS_OPENSSL)])
def test_the_listener_never_holds_more_sockets_than_its_bound_even_in_tls_handshakes(tls):
    # A TLS connection that never finishes its handshake does not reach the protocol's cap:
    # the listener's hard bound counts every accepted socket.
    console = Console.start(CommandQueue(), "127.0.0.1", 0, hub=ConsoleHub(), max_connections=8, tls=tls)
    bound = console.listener.limit
    socks = []
    try:
        before = _fds()
        for _ in range(3 * bound):
            s = socket.socket()
            s.setblocking(False)
            s.connect_ex((console.host, console.port))  # connect, then say nothing (no handshake, no request)
            socks.append(s)
        listener = console.listener
        deadline = time.monotonic() + 20
        while listener.accepted + listener.refused < len(socks) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert listener.accepted + listener.refused == len(socks)  # every connection came through accept
        assert listener.open <= bound and _fds() - before - len(socks) <= bound  # the server side: at most the bound
        if tls:  # no handshake: the protocol never sees them; the listener refuses beyond its bound
            assert listener.refused >= len(socks) - bound
        else:  # once the burst is through, the protocol's cap evicts the idle ones down to 8
            deadline = time.monotonic() + 20
            while listener.open > 8 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert listener.open <= 8
    finally:
        for s in socks:
            s.close()
        console.stop()
