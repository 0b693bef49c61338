"""The console's defences that are not about one command: sockets, hosts, and what is logged.

* ``connection_limit``: how many sockets the console may hold, well below the process's
  ``RLIMIT_NOFILE``, so that the session's own files never hit EMFILE because of the console.
* ``guarded_protocol``: uvicorn's h11 protocol with a cap on open connections (at the cap, a new
  connection evicts the oldest one that has no request in progress: a half-open socket, or an
  idle keep-alive) and a header deadline (uvicorn has none: a client that never finishes its
  headers would hold its socket forever). An event stream is a request in progress: not evicted
  (their number is capped by the application).
* ``CappedListener``: the hard bound under both: the listening socket closes a new connection at
  once while ``limit`` accepted sockets are open (whatever state they are in, a TLS handshake too).
* ``HostCheck``: the DNS-rebinding defence, an allow-list of the names the console was started for.
* ``RejectLog``: refused requests are logged (``events.jsonl``) at most ``burst`` at once and then
  one per ``every_s``, each field truncated; the rest are counted and the count logged later.
* ``QuietServerLog``: the same for uvicorn's own warnings on the operator's terminal.
"""
from __future__ import annotations

import asyncio
import collections
import ipaddress
import errno
import logging
import os
import resource
import socket
import threading
import time
from typing import Any, Callable, Iterable

#: A connection must finish a request's headers this long after it opened or its last request.
HEADER_TIMEOUT_S = 10.0
#: Longest a field of a refused request (path, method, host) is logged.
FIELD_MAX = 120


def connection_limit(soft_nofile: int | None = None) -> int:
    """Sockets the console may hold: a quarter of the process's file limit, 8 to 256.

    The other three quarters stay for the session (its files, the robot's and the EEG's sockets).
    """
    if soft_nofile is None:
        soft_nofile = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    if soft_nofile == resource.RLIM_INFINITY or soft_nofile <= 0:
        soft_nofile = 4096
    return max(8, min(256, soft_nofile // 4))


def guarded_protocol(base: type, max_connections: int, header_timeout_s: float = HEADER_TIMEOUT_S) -> type:
    """A subclass of uvicorn's ``H11Protocol`` with the connection cap and the header deadline.

    Each console gets its own class: the table of open connections is per server.
    """
    opened: collections.OrderedDict[Any, None] = collections.OrderedDict()  # oldest first

    class Guarded(base):  # type: ignore[misc, valid-type]
        evicted = 0

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._seen_cycle = None
            self._watch = self.loop.call_later(header_timeout_s, self._check_progress)
            opened[self] = None
            if len(opened) > max_connections:
                victim = next((p for p in opened if p is not self and not p._busy()), self)
                Guarded.evicted += 1
                victim._drop()

        def connection_lost(self, exc: Exception | None) -> None:
            opened.pop(self, None)
            self._watch.cancel()
            super().connection_lost(exc)

        def _busy(self) -> bool:
            """A request is being answered (an event stream, a command)."""
            return self.cycle is not None and not self.cycle.response_complete

        def _drop(self) -> None:
            opened.pop(self, None)
            self._watch.cancel()
            self.transport.abort()

        def _check_progress(self) -> None:
            """Close a connection that has no request in progress and started none since the last look."""
            if self.transport.is_closing():
                return
            if self._busy() or self.cycle is not self._seen_cycle:
                self._seen_cycle = self.cycle
                self._watch = self.loop.call_later(header_timeout_s, self._check_progress)
                return
            self._drop()

    Guarded.__name__ = Guarded.__qualname__ = f"Guarded{base.__name__}"
    Guarded.open_connections = staticmethod(lambda: len(opened))  # type: ignore[attr-defined]
    return Guarded


class CappedListener(socket.socket):
    """A listening socket whose ``accept`` keeps at most ``limit`` accepted sockets open at once.

    asyncio's server calls ``accept``; beyond the limit the new connection is closed at once and
    ``ConnectionAbortedError`` tells asyncio to go on. Each accepted socket counts itself out when closed.
    """

    def __init__(self, family: int, kind: int, proto: int, limit: int) -> None:
        super().__init__(family, kind, proto)
        self.limit = limit
        self.open = 0
        self.accepted = 0
        self.refused = 0
        self._count_lock = threading.Lock()

    def accept(self) -> tuple[socket.socket, Any]:
        fd, addr = self._accept()  # type: ignore[attr-defined]
        with self._count_lock:
            if self.open >= self.limit:
                self.refused += 1
                os.close(fd)
                raise ConnectionAbortedError(errno.ECONNABORTED, "the console holds as many sockets as it may")
            self.open += 1
            self.accepted += 1
        sock = _Counted(self.family, self.type, self.proto, fileno=fd)
        sock.listener = self
        return sock, addr

    def _closed_one(self) -> None:
        with self._count_lock:
            self.open -= 1


class _Counted(socket.socket):
    """An accepted socket that tells its listener when it is closed (once)."""

    listener: CappedListener | None = None

    def close(self) -> None:
        listener, self.listener = self.listener, None
        super().close()
        if listener is not None:
            listener._closed_one()


def _bare_host(value: str) -> str:
    """``name:port`` / ``[v6]:port`` / ``name`` -> the name, lower case, without brackets."""
    value = value.strip().lower()
    if value.startswith("["):
        return value[1:value.find("]")] if "]" in value else value
    if value.count(":") == 1:
        return value.split(":")[0]
    return value


class HostCheck:
    """Which ``Host`` headers the console answers (DNS rebinding: a page of another site that resolves
    its name to this machine sends its own name, which is not on the list)."""

    def __init__(self, names: Iterable[str]) -> None:
        self.names = frozenset(_bare_host(n) for n in names if n)

    @classmethod
    def for_bind(cls, bind: str, extra: Iterable[str] = ()) -> "HostCheck":
        """The loopback names, the bind address, and (bound wider than loopback) this machine's names."""
        names = {"127.0.0.1", "localhost", "::1", bind, *extra}
        if not is_loopback(bind):
            names |= {socket.gethostname(), socket.getfqdn()}
        return cls(names)

    def allows(self, host_header: str | None) -> bool:
        return host_header is not None and _bare_host(host_header) in self.names


def is_loopback(bind: str) -> bool:
    """Whether ``bind`` is reachable from this machine only (127.0.0.0/8, ::1, localhost)."""
    if bind.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(bind.strip("[]")).is_loopback
    except ValueError:
        return False


class RejectLog:
    """Logs refused requests at a bounded rate (token bucket); fields truncated to ``FIELD_MAX``."""

    def __init__(self, log: Callable[..., None], burst: int = 20, every_s: float = 3.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._log, self._burst, self._every, self._clock = log, burst, every_s, clock
        self._tokens = float(burst)
        self._last = clock()
        self._suppressed = 0
        self._lock = threading.Lock()

    def __call__(self, event: str, **fields: Any) -> None:
        with self._lock:
            now = self._clock()
            self._tokens = min(self._burst, self._tokens + (now - self._last) / self._every)
            self._last = now
            if self._tokens < 1:
                self._suppressed += 1
                return
            self._tokens -= 1
            suppressed, self._suppressed = self._suppressed, 0
        data = {k: (v[:FIELD_MAX] if isinstance(v, str) else v) for k, v in fields.items()}
        if suppressed:
            data["not_logged_before"] = suppressed
        self._log(event, **data)

    def flush(self) -> None:
        """Log how many refusals were not logged (at the end of the session)."""
        with self._lock:
            suppressed, self._suppressed = self._suppressed, 0
        if suppressed:
            self._log("console_rejected_not_logged", count=suppressed)


class QuietServerLog(logging.Filter):
    """Lets through one warning of each kind per ``every_s`` (uvicorn's "Invalid HTTP request received."
    would otherwise fill the operator's terminal), saying how many were held back."""

    def __init__(self, every_s: float = 60.0, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self._every, self._clock = every_s, clock
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = collections.Counter()

    def filter(self, record: logging.LogRecord) -> bool:
        key = str(record.msg)
        now = self._clock()
        if key in self._last and now - self._last[key] < self._every:
            self._held[key] += 1
            return False
        self._last[key] = now
        held = self._held.pop(key, 0)
        if held:
            record.msg = f"{record.msg} ({held} more like it not shown)"
        record.msg = f"console: {record.msg}"
        return True
