"""The supervisor console: a web page served by the session process (Starlette + uvicorn in a thread).

* ``ConsoleHub`` is the session's ``ports.SessionObserver``: ``notify`` updates a snapshot of what
  the page shows and appends the event to a numbered log, under a lock, and returns (microseconds;
  it never wakes the server thread). Each viewer's stream polls the log every ``POLL_S`` and sends
  what is new, so the server's work comes in batches. A viewer that connects or reconnects gets the
  snapshot first, then live events, as Server-Sent Events.
* Commands are POSTed as JSON and put on the session's ``ports.CommandQueue``, the same queue the
  terminal keys use; the session acts on them at defined points.
* Security: a random token per session, compared in constant time on every request. The first
  load carries it in the URL; the answer sets an HttpOnly, SameSite=Strict cookie scoped to this
  console's path (``/c/<id>/``: two consoles in one browser keep their own) and redirects to a
  URL without it. A ``Host`` not on the console's list gets 421, a request without a valid token
  403; both are logged at a bounded rate (``guard.RejectLog``). Commands are checked when they
  arrive (``command_schema``: body size, depth, finite numbers, each kind's arguments, existing turns);
  sockets are capped and timed out (``guard.guarded_protocol``). Loopback only unless the operator
  asks otherwise (``session.wiring`` enforces that); beyond loopback over TLS (``tls``). The page
  holds no participant name and no credential; it loads nothing from elsewhere (uPlot is vendored).

Why Starlette + uvicorn: small (a few MB, ~0.2 s import, loaded only with ``--console``), SSE
fits a one-way live feed with automatic browser reconnection, and uvicorn runs in a non-main
thread without taking the signal handlers, so Ctrl-C still reaches the session.
"""
from __future__ import annotations

import asyncio
import collections
import functools
import hmac
import json
import logging
import math
import secrets
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

from nao_trainer.console.command_schema import MAX_BODY, CommandRejected, check_command, parse_body
from nao_trainer.console.guard import (HEADER_TIMEOUT_S, CappedListener, HostCheck, QuietServerLog, RejectLog, connection_limit, guarded_protocol,
                                       is_loopback)
from nao_trainer.errors import ConfigError
from nao_trainer.ports import COMMAND_KINDS, CommandQueue
from nao_trainer.console import tls as console_tls

STATIC = Path(__file__).parent / "static"
STATIC_FILES = {"console.js": "text/javascript", "console.css": "text/css", "uPlot.iife.min.js": "text/javascript",
                "uPlot.min.css": "text/css"}
COOKIE = "nao_console"
HEADER = "x-console-token"
TICK_S = 0.5  # how often viewers get elapsed time and the live EEG
POLL_S = 0.1  # how often a viewer's stream looks for new events
MAX_STREAMS = 16  # event streams at once (each viewer's page holds one)
BODY_TIMEOUT_S = 5.0  # a command's body must arrive within this
BACKLOG = 128  # connections the kernel queues before accept (they hold no file of this process)
HANDSHAKE_TIMEOUT_S = 10.0  # a TLS handshake must be over within this (asyncio's default: 60 s)
START_TIMEOUT_S = 30.0  # the server must listen within this after its thread starts (generous: a loaded machine)
_QUIET = QuietServerLog()


def _finite(value: Any) -> Any:
    """``value`` with every NaN/Infinity replaced by None (JSON has no such numbers; ``JSON.parse`` refuses them)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def dumps(value: Any) -> str:
    """Compact JSON that ``JSON.parse`` accepts: non-finite numbers become null."""
    try:
        return json.dumps(value, default=str, separators=(",", ":"), allow_nan=False)
    except ValueError:
        return json.dumps(_finite(json.loads(json.dumps(value, default=str))), separators=(",", ":"), allow_nan=False)


class ConsoleHub:
    """What the console knows of the session, and the viewers to tell (``ports.SessionObserver``)."""

    MAX_LOG = 200
    MAX_EVENTS = 5000  # a viewer further behind than this gets a new snapshot

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._events: collections.deque[tuple[int, str, dict]] = collections.deque(maxlen=self.MAX_EVENTS)
        self._seq = 0
        self._viewers = 0
        self._sources: dict[str, Callable[[], Any]] = {}
        self.closed = False
        self.state: dict[str, Any] = {"session": {}, "machine": {}, "turn": None, "presses": [], "rows": [],
                                      "commands": [], "paused": False, "robot": "connecting", "summary": None,
                                      "policy_status": None, "eeg_missing": None}

    # -- the session's side (its thread) ------------------------------------------------------------

    def notify(self, kind: str, data: dict) -> None:
        with self._lock:
            self._update(kind, data)
            self._seq += 1
            self._events.append((self._seq, kind, data))

    def _update(self, kind: str, data: dict) -> None:
        st = self.state
        if kind == "session":
            st["session"] = dict(data)
            st["robot"] = data.get("robot", st["robot"])
            st["machine"] = st["machine"] or {"state": data.get("state")}
        elif kind == "state":
            st["machine"] = dict(data)
        elif kind == "turn_start":
            st["turn"], st["presses"] = dict(data), []
        elif kind == "press":
            st["presses"].append(dict(data))
        elif kind == "row":
            st["rows"].append(dict(data))
        elif kind == "command":
            st["commands"] = (st["commands"] + [dict(data)])[-self.MAX_LOG:]
        elif kind == "pause":
            st["paused"] = bool(data.get("paused"))
        elif kind == "robot":
            st["robot"] = data.get("robot", st["robot"])
        elif kind == "summary":
            st["summary"] = dict(data)
        elif kind == "policy":
            st["policy_status"] = dict(data)
        elif kind == "eeg":  # EEG missing for several turns in a row (or back)
            st["eeg_missing"] = dict(data) if data.get("missing_turns") else None

    def set_sources(self, **sources: Callable[[], Any]) -> None:
        """Read-only callables polled for the tick (``eeg``: the monitor's ``live``, ``elapsed``)."""
        with self._lock:
            self._sources.update(sources)

    # -- the server's side ---------------------------------------------------------------------

    def snapshot(self) -> tuple[int, str]:
        """(sequence number, the snapshot as JSON text): events after that number follow it."""
        with self._lock:
            return self._seq, dumps(self.state)

    def since(self, seq: int) -> tuple[int, list[tuple[str, dict]] | None]:
        """Events after ``seq`` (None when some were dropped: send a snapshot instead)."""
        with self._lock:
            if self._seq == seq:
                return seq, []
            if not self._events or self._events[0][0] > seq + 1:
                return self._seq, None
            start = seq + 1 - self._events[0][0]
            return self._seq, [(k, d) for _, k, d in list(self._events)[start:]]

    def tick(self) -> dict[str, Any]:
        with self._lock:
            sources = dict(self._sources)
        out: dict[str, Any] = {}
        for name, fn in sources.items():
            try:
                out[name] = fn()
            except Exception as exc:  # noqa: BLE001 - a viewer must not break on a probe
                out[name] = {"error": str(exc)}
        return out

    def viewer(self, delta: int) -> None:
        with self._lock:
            self._viewers += delta

    # -- ``commands.SessionView``: what a command may name ----------------------------------------------

    def turn_in_flight(self) -> int | None:
        with self._lock:
            turn = self.state["turn"]
            return turn.get("turn") if isinstance(turn, dict) else None

    def turns_planned(self) -> int | None:
        with self._lock:
            return self.state["session"].get("turns")

    @property
    def viewers(self) -> int:
        with self._lock:
            return self._viewers

    def close(self) -> None:
        """The session is over: viewers' streams send what is left and end."""
        self.closed = True


def _sse(kind: str, data: Any) -> str:
    return f"event: {kind}\ndata: {dumps(data)}\n\n"


def make_app(hub: ConsoleHub, commands: CommandQueue, token: str, log: Callable[..., None],
             prefix: str = "/", hosts: HostCheck | None = None):
    """The Starlette application of one session's console, served under ``prefix`` (``/c/<id>/``).

    ``log`` receives refused requests (already rate-limited: ``guard.RejectLog``).
    """
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import JSONResponse, PlainTextResponse, RedirectResponse, Response, StreamingResponse
    from starlette.routing import Route

    secret = token.encode()
    hosts = hosts or HostCheck.for_bind("127.0.0.1")

    def authorised(request: Request, allow_query: bool = False) -> bool:
        offered = [request.cookies.get(COOKIE), request.headers.get(HEADER)]
        if allow_query:
            offered.append(request.query_params.get("token"))
        return any(v is not None and hmac.compare_digest(v.encode(errors="replace"), secret) for v in offered)

    def refused(request: Request, allow_query: bool = False) -> Response | None:
        """421 for a Host not on the list (DNS rebinding), 403 without the token; None when the request may go on."""
        client = request.client.host if request.client else None
        if not hosts.allows(request.headers.get("host")):
            log("console_wrong_host", method=request.method, path=request.url.path,
                host=request.headers.get("host"), client=client)
            return PlainTextResponse("misdirected request: open the link printed by nao-trainer run\n", status_code=421)
        if not authorised(request, allow_query):
            log("console_forbidden", method=request.method, path=request.url.path, client=client)
            return PlainTextResponse("forbidden: open the link printed by nao-trainer run\n", status_code=403)
        return None

    async def page(request: Request) -> Response:
        if "token" in request.query_params:
            if (no := refused(request, allow_query=True)) is not None:
                return no
            # The token leaves the URL: from now on it travels in a cookie only this console's path gets.
            response = RedirectResponse(prefix, status_code=303)
            response.set_cookie(COOKIE, token, httponly=True, samesite="strict", path=prefix,
                                secure=request.url.scheme == "https")
            return response
        if (no := refused(request)) is not None:
            return no
        return Response((STATIC / "console.html").read_text(encoding="utf-8"), media_type="text/html",
                        headers={"Cache-Control": "no-store", "Referrer-Policy": "no-referrer",
                                 "Content-Security-Policy": "default-src 'self'; style-src 'self' 'unsafe-inline'"})

    async def static(request: Request) -> Response:
        if (no := refused(request)) is not None:
            return no
        name = request.path_params["name"]
        if name not in STATIC_FILES:
            return PlainTextResponse("not found\n", status_code=404)
        return Response((STATIC / name).read_bytes(), media_type=STATIC_FILES[name])

    async def state(request: Request) -> Response:
        if (no := refused(request)) is not None:
            return no
        _, text = hub.snapshot()
        return Response(f'{text[:-1]},"tick":{dumps(hub.tick())}}}', media_type="application/json",
                        headers={"Cache-Control": "no-store"})

    async def events(request: Request) -> Response:
        if (no := refused(request)) is not None:
            return no
        if hub.viewers >= MAX_STREAMS:
            return PlainTextResponse(f"too many live streams (at most {MAX_STREAMS}); close a console tab\n",
                                     status_code=503, headers={"Retry-After": "5"})

        async def stream():
            hub.viewer(+1)  # counted here, not before: a stream that never starts never ends either
            try:
                seq, text = hub.snapshot()
                yield f"retry: 1000\nevent: snapshot\ndata: {text}\n\n"
                last_tick = 0.0
                while True:
                    closing = hub.closed
                    seq, new = hub.since(seq)
                    if new is None:  # fell behind: start again from a snapshot
                        seq, text = hub.snapshot()
                        yield f"event: snapshot\ndata: {text}\n\n"
                    elif new:
                        yield "".join(_sse(kind, data) for kind, data in new)
                    if closing:
                        yield _sse("closed", {})
                        return
                    if time.monotonic() - last_tick >= TICK_S:
                        last_tick = time.monotonic()
                        yield _sse("tick", hub.tick())
                    await asyncio.sleep(POLL_S)
            finally:
                hub.viewer(-1)

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    async def read_body(request: Request) -> bytes:
        """The body, at most ``MAX_BODY`` bytes and within ``BODY_TIMEOUT_S`` (a slow body holds no socket)."""
        declared = request.headers.get("content-length", "")
        if declared.isdigit() and int(declared) > MAX_BODY:
            raise CommandRejected(f"body of {declared} bytes; a command is at most {MAX_BODY} bytes", 413)
        chunks: list[bytes] = []

        async def collect() -> None:
            size = 0
            async for chunk in request.stream():
                size += len(chunk)
                if size > MAX_BODY:
                    raise CommandRejected(f"body over {MAX_BODY} bytes; a command is at most {MAX_BODY} bytes", 413)
                chunks.append(chunk)

        try:
            await asyncio.wait_for(collect(), BODY_TIMEOUT_S)
        except asyncio.TimeoutError:
            raise CommandRejected(f"the body did not arrive within {BODY_TIMEOUT_S:g} s", 408) from None
        return b"".join(chunks)

    async def command(request: Request) -> Response:
        if (no := refused(request)) is not None:
            return no
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            return JSONResponse({"error": "send JSON (Content-Type: application/json)"}, status_code=415,
                                headers={"Connection": "close"})
        try:
            kind, args = check_command(parse_body(await read_body(request)), hub)
        except CommandRejected as exc:
            headers = {"Connection": "close"} if exc.status != 400 else {}
            return JSONResponse({"error": str(exc), "kinds": list(COMMAND_KINDS)}, status_code=exc.status,
                                headers=headers)
        cmd = commands.submit(kind, args, source="console")
        return JSONResponse({"id": cmd.id, "kind": cmd.kind, "queued_at": cmd.at}, status_code=202)

    async def not_allowed(request: Request) -> Response:
        if (no := refused(request)) is not None:
            return no
        return PlainTextResponse("commands are POST only\n", status_code=405)

    return Starlette(routes=[
        Route(prefix, page, methods=["GET"]),
        Route(prefix + "static/{name}", static, methods=["GET"]),
        Route(prefix + "state", state, methods=["GET"]),
        Route(prefix + "events", events, methods=["GET"]),
        Route(prefix + "command", command, methods=["POST"]),
        Route(prefix + "command", not_allowed, methods=["GET"]),
    ])


def _serve(server: Any, sock: socket.socket, tls: bool, failed: list[BaseException]) -> None:
    """uvicorn's server on its own event loop; over TLS with a short handshake time-out (uvicorn sets none).

    An exception (e.g. a certificate the TLS library refuses) is kept in ``failed`` for ``Console.start``
    to report in one line, or printed in one line once the console has run: never a thread's traceback.
    """
    async def main() -> None:
        if tls:
            loop = asyncio.get_running_loop()
            loop.create_server = functools.partial(loop.create_server,  # type: ignore[method-assign]
                                                   ssl_handshake_timeout=HANDSHAKE_TIMEOUT_S)
        await server.serve(sockets=[sock])

    try:
        asyncio.run(main())
    except Exception as exc:
        failed.append(exc)
        if server.started:
            print(f"console: the server stopped ({type(exc).__name__}: {exc}); the session goes on without it",
                  file=sys.stderr, flush=True)


def reachable_address(bind: str) -> str:
    """An address another machine can open for a console bound to ``bind`` (a wildcard is not one)."""
    if bind not in ("0.0.0.0", "::", ""):
        return bind
    family, probe = (socket.AF_INET6, "2001:db8::1") if bind == "::" else (socket.AF_INET, "192.0.2.1")
    try:
        with socket.socket(family, socket.SOCK_DGRAM) as s:
            s.connect((probe, 9))  # a UDP connect sends nothing: it only picks the outgoing interface
            address = s.getsockname()[0]
    except OSError:
        address = ""
    return address if address and not is_loopback(address) else socket.gethostname()


class Console:
    """The console's server, running in a daemon thread for the session's lifetime."""

    def __init__(self, hub: ConsoleHub, server: Any, thread: threading.Thread, host: str, port: int, token: str,
                 prefix: str = "/", scheme: str = "http", fingerprint: str | None = None,
                 rejected: RejectLog | None = None, protocol: Any = None) -> None:
        self.hub, self._server, self._thread = hub, server, thread
        self.host, self.port, self.token, self.prefix = host, port, token, prefix
        self.scheme, self.fingerprint = scheme, fingerprint
        self._rejected, self.protocol = rejected, protocol
        self.listener: CappedListener | None = None  # its ``open`` and ``refused`` counts

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{self.port}{self.prefix}"

    @property
    def link(self) -> str:
        """The URL to open once (it carries the token; the page then uses a cookie)."""
        return f"{self.url}?token={self.token}"

    @classmethod
    def start(cls, commands: CommandQueue, bind: str = "127.0.0.1", port: int = 0,
              log: Callable[..., None] | None = None, hub: ConsoleHub | None = None, tls: bool = False,
              max_connections: int | None = None, header_timeout_s: float = HEADER_TIMEOUT_S) -> "Console":
        """Serve the console on ``bind:port`` (0 = a free port); returns once it accepts connections.

        ``tls``: serve HTTPS with a self-signed certificate made now (``self.fingerprint``).
        ``max_connections``: connections without a request in progress held at most before the oldest
        is evicted; the listener's hard bound on open sockets adds ``MAX_STREAMS`` and 8 to it (by
        default the hard bound is ``guard.connection_limit()``, a quarter of the process's file limit).
        """
        import uvicorn
        from uvicorn.protocols.http.h11_impl import H11Protocol

        hub = hub or ConsoleHub()
        token = secrets.token_urlsafe(24)
        prefix = f"/c/{secrets.token_hex(4)}/"
        hard = connection_limit() if max_connections is None else max_connections + MAX_STREAMS + 8
        limit = max(8, hard - MAX_STREAMS - 8) if max_connections is None else max_connections
        try:
            family, kind, proto, _, addr = socket.getaddrinfo(bind, port, type=socket.SOCK_STREAM)[0]
            sock = CappedListener(family, kind, proto, hard)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(addr)
        except OSError as exc:
            raise ConfigError(f"console: cannot listen on {bind}:{port} ({exc.strerror or exc}); "
                              "choose another --console-port (0 = any free port)") from None
        sock.listen(BACKLOG)
        actual = sock.getsockname()[1]
        public = reachable_address(bind)
        hosts = HostCheck.for_bind(bind, [public])
        rejected = RejectLog(log or (lambda *a, **k: None))
        certificate = None
        if tls:
            try:
                certificate = console_tls.make_certificate(sorted(hosts.names))
            except BaseException:
                sock.close()
                raise
        app = make_app(hub, commands, token, rejected, prefix, hosts)
        protocol = guarded_protocol(H11Protocol, limit, header_timeout_s)
        config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off", http=protocol,
                                timeout_graceful_shutdown=1, timeout_keep_alive=5, backlog=BACKLOG,
                                limit_concurrency=limit + MAX_STREAMS, h11_max_incomplete_event_size=16 * 1024,
                                ssl_certfile=str(certificate.certfile) if certificate else None,
                                ssl_keyfile=str(certificate.keyfile) if certificate else None)
        server_log = logging.getLogger("uvicorn.error")
        if _QUIET not in server_log.filters:
            server_log.addFilter(_QUIET)
        server = uvicorn.Server(config)
        failed: list[BaseException] = []
        thread = threading.Thread(target=_serve, args=(server, sock, tls, failed), name="console", daemon=True)
        thread.start()
        deadline = time.monotonic() + START_TIMEOUT_S
        while not server.started and thread.is_alive() and time.monotonic() < deadline:
            time.sleep(0.01)
        if certificate is not None:
            certificate.remove()  # loaded by now (or never): the key stays in memory only
        if not server.started:
            server.should_exit = True
            thread.join(timeout=5)
            sock.close()
            why = f"{type(failed[0]).__name__}: {failed[0]}" if failed else f"not listening after {START_TIMEOUT_S:g} s"
            raise ConfigError(f"console: the server on {bind}:{actual} did not start ({why}); run again, "
                              "or without --console")
        console = cls(hub, server, thread, public, actual, token, prefix, "https" if tls else "http",
                      certificate.fingerprint if certificate else None, rejected, protocol)
        console.listener = sock
        return console

    def stop(self) -> None:
        """End the viewers' streams (after the final events reach them) and stop the server."""
        self.hub.close()
        deadline = time.monotonic() + 3 * POLL_S + 1.0
        while self.hub.viewers and time.monotonic() < deadline:
            time.sleep(0.02)
        self._server.should_exit = True
        self._thread.join(timeout=5)
        self.log_rejections()

    def log_rejections(self) -> None:
        """Log the count of refused requests the rate limit kept out of the log (``guard.RejectLog.flush``)."""
        if self._rejected is not None:
            self._rejected.flush()
