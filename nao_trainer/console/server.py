"""The supervisor console: a web page served by the session process (Starlette + uvicorn in a thread).

* ``ConsoleHub`` is the session's ``ports.SessionObserver``: ``notify`` updates a snapshot of what
  the page shows and appends the event to a numbered log, under a lock, and returns (microseconds;
  it never wakes the server thread). Each viewer's stream polls the log every ``POLL_S`` and sends
  what is new, so the server's work comes in batches. A viewer that connects or reconnects gets the
  snapshot first, then live events, as Server-Sent Events.
* Commands are POSTed as JSON and put on the session's ``ports.CommandQueue``, the same queue the
  terminal keys use; the session acts on them at defined points.
* Security: a random token per session, compared in constant time on every request. The first
  load carries it in the URL; the answer sets an HttpOnly, SameSite=Strict cookie and redirects to
  a URL without it. A request without a valid token gets 403 and is logged. Loopback only unless
  the operator asks otherwise (``session.wiring`` enforces that). The page holds no participant
  name and no credential; it loads nothing from elsewhere (uPlot is vendored in ``static/``).

Why Starlette + uvicorn: small (a few MB, ~0.2 s import, loaded only with ``--console``), SSE
fits a one-way live feed with automatic browser reconnection, and uvicorn runs in a non-main
thread without taking the signal handlers, so Ctrl-C still reaches the session.
"""
from __future__ import annotations

import asyncio
import collections
import hmac
import json
import secrets
import socket
import threading
import time
from pathlib import Path
from typing import Any, Callable

from nao_trainer.errors import ConfigError
from nao_trainer.ports import COMMAND_KINDS, CommandQueue

STATIC = Path(__file__).parent / "static"
STATIC_FILES = {"console.js": "text/javascript", "console.css": "text/css", "uPlot.iife.min.js": "text/javascript",
                "uPlot.min.css": "text/css"}
COOKIE = "nao_console"
HEADER = "x-console-token"
TICK_S = 0.5  # how often viewers get elapsed time and the live EEG
POLL_S = 0.1  # how often a viewer's stream looks for new events


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
            return self._seq, json.dumps(self.state, default=str, separators=(",", ":"))

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

    @property
    def viewers(self) -> int:
        with self._lock:
            return self._viewers

    def close(self) -> None:
        """The session is over: viewers' streams send what is left and end."""
        self.closed = True


def _sse(kind: str, data: Any) -> str:
    return f"event: {kind}\ndata: {json.dumps(data, default=str, separators=(',', ':'))}\n\n"


def make_app(hub: ConsoleHub, commands: CommandQueue, token: str, log: Callable[..., None]):
    """The Starlette application of one session's console."""
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import JSONResponse, PlainTextResponse, RedirectResponse, Response, StreamingResponse
    from starlette.routing import Route

    secret = token.encode()

    def authorised(request: Request, allow_query: bool = False) -> bool:
        offered = [request.cookies.get(COOKIE), request.headers.get(HEADER)]
        if allow_query:
            offered.append(request.query_params.get("token"))
        return any(v is not None and hmac.compare_digest(v.encode(), secret) for v in offered)

    def forbidden(request: Request) -> Response:
        log("console_forbidden", method=request.method, path=request.url.path,
            client=request.client.host if request.client else None)
        return PlainTextResponse("forbidden: open the link printed by nao-trainer run\n", status_code=403)

    async def page(request: Request) -> Response:
        if "token" in request.query_params:
            if not authorised(request, allow_query=True):
                return forbidden(request)
            # The token leaves the URL: from now on it travels in a cookie only this site sends.
            response = RedirectResponse("/", status_code=303)
            response.set_cookie(COOKIE, token, httponly=True, samesite="strict", path="/")
            return response
        if not authorised(request):
            return forbidden(request)
        return Response((STATIC / "console.html").read_text(encoding="utf-8"), media_type="text/html",
                        headers={"Cache-Control": "no-store", "Referrer-Policy": "no-referrer",
                                 "Content-Security-Policy": "default-src 'self'; style-src 'self' 'unsafe-inline'"})

    async def static(request: Request) -> Response:
        if not authorised(request):
            return forbidden(request)
        name = request.path_params["name"]
        if name not in STATIC_FILES:
            return PlainTextResponse("not found\n", status_code=404)
        return Response((STATIC / name).read_bytes(), media_type=STATIC_FILES[name])

    async def state(request: Request) -> Response:
        if not authorised(request):
            return forbidden(request)
        return JSONResponse(json.loads(json.dumps({**json.loads(hub.snapshot()[1]), "tick": hub.tick()}, default=str)))

    async def events(request: Request) -> Response:
        if not authorised(request):
            return forbidden(request)
        hub.viewer(+1)

        async def stream():
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

    async def command(request: Request) -> Response:
        if not authorised(request):
            return forbidden(request)
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            return JSONResponse({"error": "send JSON (Content-Type: application/json)"}, status_code=415)
        try:
            body = await request.json()
            kind, args = body["kind"], body.get("args") or {}
            if not isinstance(args, dict):
                raise TypeError("args must be an object")
            cmd = commands.submit(str(kind), args, source="console")
        except (ValueError, KeyError, TypeError) as exc:
            return JSONResponse({"error": str(exc), "kinds": list(COMMAND_KINDS)}, status_code=400)
        return JSONResponse({"id": cmd.id, "kind": cmd.kind, "queued_at": cmd.at}, status_code=202)

    async def not_allowed(request: Request) -> Response:
        if not authorised(request):
            return forbidden(request)
        return PlainTextResponse("commands are POST only\n", status_code=405)

    return Starlette(routes=[
        Route("/", page, methods=["GET"]),
        Route("/static/{name}", static, methods=["GET"]),
        Route("/state", state, methods=["GET"]),
        Route("/events", events, methods=["GET"]),
        Route("/command", command, methods=["POST"]),
        Route("/command", not_allowed, methods=["GET"]),
    ])


class Console:
    """The console's server, running in a daemon thread for the session's lifetime."""

    def __init__(self, hub: ConsoleHub, server: Any, thread: threading.Thread, host: str, port: int, token: str) -> None:
        self.hub, self._server, self._thread = hub, server, thread
        self.host, self.port, self.token = host, port, token

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    @property
    def link(self) -> str:
        """The URL to open once (it carries the token; the page then uses a cookie)."""
        return f"{self.url}?token={self.token}"

    @classmethod
    def start(cls, commands: CommandQueue, bind: str = "127.0.0.1", port: int = 0,
              log: Callable[..., None] | None = None, hub: ConsoleHub | None = None) -> "Console":
        """Serve the console on ``bind:port`` (0 = a free port); returns once it accepts connections."""
        import uvicorn

        hub = hub or ConsoleHub()
        token = secrets.token_urlsafe(24)
        try:
            family, kind, proto, _, addr = socket.getaddrinfo(bind, port, type=socket.SOCK_STREAM)[0]
            sock = socket.socket(family, kind, proto)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(addr)
        except OSError as exc:
            raise ConfigError(f"console: cannot listen on {bind}:{port} ({exc.strerror or exc}); "
                              "choose another --console-port (0 = any free port)") from None
        sock.listen(16)
        actual = sock.getsockname()[1]
        app = make_app(hub, commands, token, log or (lambda *a, **k: None))
        config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off",
                                timeout_graceful_shutdown=1)
        server = uvicorn.Server(config)
        thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, name="console", daemon=True)
        thread.start()
        deadline = time.monotonic() + 10
        while not server.started and thread.is_alive() and time.monotonic() < deadline:
            time.sleep(0.01)
        if not server.started:
            raise RuntimeError("the console's server did not start")
        return cls(hub, server, thread, bind, actual, token)

    def stop(self) -> None:
        """End the viewers' streams (after the final events reach them) and stop the server."""
        self.hub.close()
        deadline = time.monotonic() + 3 * POLL_S + 1.0
        while self.hub.viewers and time.monotonic() < deadline:
            time.sleep(0.02)
        self._server.should_exit = True
        self._thread.join(timeout=5)
