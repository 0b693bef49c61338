"""The stand-in as an object in this process (:class:`StandIn`) and as a process (``serve``, ``spawn_standin``)."""
from __future__ import annotations

import ipaddress
import os
import re
import selectors
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable, TextIO

os.environ.setdefault("QI_LOG_LEVEL", "silent")  # qi logs to fd 1 otherwise; must precede `import qi`
import qi  # noqa: E402

from nao_trainer.errors import ConfigError, RobotUnavailable  # noqa: E402
from nao_trainer.robot.standin.body import Body  # noqa: E402
from nao_trainer.robot.standin.recorder import Recorder, check_speed  # noqa: E402
from nao_trainer.robot.standin.control import Control, build_services  # noqa: E402
from nao_trainer.robot.standin.link import Link  # noqa: E402
from nao_trainer.robot.standin.login import Login  # noqa: E402
from nao_trainer.robot.standin.services import Memory  # noqa: E402
from nao_trainer.robot.standin.tls import server_context

#: The first line ``nao-trainer mock-robot`` prints once it serves.
READY_PREFIX = "nao-trainer mock-robot: listening on "

_URL_RE = re.compile(r"^(tcp|tcps)://([^:/@\s]+|\[[0-9a-fA-F:]+\]):(\d{1,5})$")


def check_listen_url(url: str, allow_remote: bool = False) -> str:
    """Validate a ``tcp://HOST:PORT`` or ``tcps://HOST:PORT`` listen address; only loopback unless ``allow_remote``."""
    m = _URL_RE.match(url.strip())
    if not m:
        raise ConfigError(f"listen address {url!r} is not of the form tcp://127.0.0.1:PORT (port 0 picks a free one)")
    host, port = m.group(2).strip("[]"), int(m.group(3))
    if port > 65535:
        raise ConfigError(f"listen address {url!r}: port {port} is out of range 0..65535")
    if not allow_remote and not _is_loopback(host):
        raise ConfigError(
            f"listen address {url!r} is not a loopback address: the stand-in serves this machine only "
            "(use tcp://127.0.0.1:PORT, or pass --allow-remote to serve other machines on purpose)"
        )
    return url.strip()


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class StandIn:
    """A NAO stand-in served over its own ``qi.Session`` in this process.

    Use ``StandIn.start()``; clients connect to ``.url`` as to a NAO. ``press`` touches a head
    button, ``transcript`` lists what the robot was asked to do, ``stop`` closes everything.
    """

    def __init__(
        self, session: Any, url: str, recorder: Recorder, memory: Memory, control: Control, service_ids: list[int],
        link: Link,
    ) -> None:
        self._session = session
        self._service_ids = service_ids
        self.url = url
        self._rec = recorder
        self._memory = memory
        self._control = control
        #: The control service (``NaoTrainerStandIn``): fall, heat, battery_low, act_after, refuse_life, ...
        self.control = control
        self.link = link
        control.link = link
        self._stopped = False

    @classmethod
    def start(
        cls,
        url: str = "tcp://127.0.0.1:0",
        speed: float = 1.0,
        transcript_path: str | os.PathLike | None = None,
        allow_remote: bool = False,
        echo: TextIO | None = None,
        login: Login | None = None,
        model: str = "nao",
        without: tuple[str, ...] = (),
        profile: Any = None,
    ) -> "StandIn":
        """Serve the stand-in on ``url`` (port 0 picks a free port; ``.url`` tells which).

        Clients reach the qi server (on a private loopback port) through a ``Link`` that can add
        latency and freeze. ``tcps://`` (NAOqi 2.9) needs ``login``: the only user and password
        accepted. ``echo``: a stream that gets one readable line per call (the robot's actions, live).
        ``model``: the robot the stand-in plays ("nao", "pepper"); ``without``: NAOqi services it lacks;
        ``profile``: a conformance profile (``robot.profile.Profile``) whose answers it gives instead of its guesses.
        """
        url = check_listen_url(url, allow_remote)
        scheme, _, rest = url.partition("://")
        host, port = rest.rsplit(":", 1)
        if scheme == "tcps" and login is None:
            raise ConfigError(f"listen address {url}: a tcps:// stand-in checks a login: give the user and password "
                              "it accepts (mock-robot takes them from NAO_USER and NAO_PASSWORD)")
        rec = Recorder(speed=speed, path=Path(transcript_path) if transcript_path else None, echo=echo)
        session = qi.Session()
        try:
            link = _start_link(scheme, host.strip("[]"), int(port), login)
        except OSError as exc:
            rec.close()
            session.close()
            reason = "the port is already in use (another mock-robot or NAOqi?)" if exc.errno == 98 else exc.strerror
            raise RobotUnavailable(f"the stand-in cannot listen on {url}: {reason}; pick another port or use port 0") from None
        try:
            session.listenStandalone("tcp://127.0.0.1:0")
        except RuntimeError as exc:
            rec.close()
            link.stop()
            session.close()
            if "already in use" in str(exc):
                reason = "the port is already in use (another mock-robot or NAOqi?)"
            else:  # qi's message spans lines and cites boost sources: keep its gist
                reason = re.sub(r"\s*\[system:.*", "", " ".join(str(exc).split()))
            raise RobotUnavailable(
                f"the stand-in cannot listen on {url}: {reason}; pick another port or use port 0"
            ) from None
        body = Body(model=model)
        if profile is not None:
            profile.apply(body)
            without = tuple(without) + tuple(profile.without)
        services, memory, control = build_services(rec, body, tuple(without))
        if profile is not None:
            profile.apply_services(services)
        ids = [session.registerService(name, obj) for name, obj in services.items()]
        link.target_port = int(_bound_url(session, "tcp://127.0.0.1:0").rsplit(":", 1)[1])
        return cls(session, f"{scheme}://{host}:{link.port}", rec, memory, control, ids, link)

    @property
    def speed(self) -> float:
        return self._rec.speed

    def set_speed(self, speed: float) -> None:
        self._rec.speed = check_speed(speed)

    def press(self, button: str) -> str:
        """Touch and release a head button given as letter A/B/C or ALMemory key; returns the key."""
        try:
            return self._control.press(button)
        except RuntimeError as exc:
            raise ValueError(str(exc)) from None

    def hold(self, button: str, seconds: float) -> str:
        """A hand on the head for ``seconds`` of robot time (see ``Control.hold``); returns what it caused."""
        return self._control.hold(button, seconds)

    def hold_after(self, call: str, button: str, seconds: float) -> None:
        """A hand held ``seconds`` (robot time) once the next ``call`` has returned (``Control.hold_after``)."""
        self._control.hold_after(call, button, seconds)

    def chest(self, clicks: int) -> str:
        """Clicks of the chest button (``Control.chest``: a double click removes the stiffness, or switches
        Autonomous Life off and on after ``control.set_chest_double("life")``)."""
        return self._control.chest(clicks)

    def chest_after(self, call: str, clicks: int) -> None:
        """``chest(clicks)`` once the next ``call`` has returned."""
        self._control.chest_after(call, clicks)

    def body(self) -> dict[str, Any]:
        """Autonomous Life state, motors, posture, sleep, volume, mute, battery."""
        return self._control.body()

    def set_latency(self, round_trip_s: float = 0.0, beep_s: float = 0.0) -> None:
        """Network round trip of every call (wall s) and the beep's audio latency (robot s)."""
        self._control.set_latency(round_trip_s, beep_s)

    def freeze(self, seconds: float) -> None:
        """The link goes silent (connections stay open, no byte moves) for ``seconds`` of wall time."""
        self.link.freeze(seconds)

    def freeze_after(self, call: str, seconds: float) -> None:
        """Freeze the link for ``seconds`` once the next ``call`` ("ALAudioPlayer.playSine") has returned."""
        self._control.freeze_after(call, seconds)

    def freeze_at(self, call: str, seconds: float) -> None:
        """Freeze the link for ``seconds`` as the next ``call`` finishes, before its reply is sent."""
        self._control.freeze_at(call, seconds)

    def transcript(self) -> list[dict[str, Any]]:
        """Every call the stand-in received so far: ``{"t", "service", "method", "args"}``."""
        return self._rec.snapshot()

    def clear(self) -> None:
        self._rec.clear()

    def stop(self) -> None:
        """Close the qi session (drops clients) and flush the transcript file. Idempotent."""
        if self._stopped:
            return
        self._stopped = True
        self._rec.interrupt()  # pending say/playSine/... return at once
        self._memory.forget_subscribers()
        try:
            # Unregister before closing: a server session closed with its services registered
            # aborts the process at exit about one time in ten (measured 5/40 vs 0/100).
            for service_id in self._service_ids:
                try:
                    self._session.unregisterService(service_id)
                except RuntimeError:
                    pass
            self._session.close()
        finally:
            self.link.stop()
            self._rec.close()

    def __enter__(self) -> "StandIn":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _start_link(scheme: str, host: str, port: int, login: Login | None) -> Link:
    tls = None
    if scheme == "tcps":
        folder = Path(tempfile.mkdtemp(prefix="nao-standin-tls-"))
        try:
            tls = server_context(folder)  # the key is loaded: it need not stay on disk
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    return Link(0, host, port, tls=tls, login=login if scheme == "tcps" else None).start()


def _bound_url(session: Any, requested: str) -> str:
    """The URL clients should use: the requested one, with port 0 replaced by the chosen port."""
    endpoints = [e for e in session.endpoints() if e.startswith("tcp://")]
    if not requested.endswith(":0"):
        return requested
    host = requested.rsplit(":", 1)[0]
    for endpoint in endpoints:
        if endpoint.rsplit(":", 1)[0] == host:
            return endpoint
    return endpoints[0]


def serve(
    url: str,
    speed: float = 1.0,
    transcript_path: str | os.PathLike | None = None,
    allow_remote: bool = False,
    out: TextIO | None = None,
    echo: TextIO | None = None,
    login: Login | None = None,
    latency_s: float = 0.0,
    beep_latency_s: float = 0.0,
    freeze_s: float = 10.0,
    model: str = "nao",
    profile: Any = None,
    on_ready: Callable[["StandIn"], Callable[[], None] | None] | None = None,
) -> int:
    """Run the stand-in until SIGINT/SIGTERM (``nao-trainer mock-robot``); prints the ready line.

    SIGUSR1 freezes the link for ``freeze_s`` seconds (the process stays alive, nothing moves).
    ``on_ready(standin)`` runs once it serves (the terminal's head-button keys) and may return a closer.
    """
    out = out or sys.stdout
    stop = threading.Event()
    handlers = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    standin: StandIn | None = None
    handlers[signal.SIGUSR1] = signal.signal(signal.SIGUSR1, lambda *_: standin.freeze(freeze_s) if standin else None)
    try:
        standin = StandIn.start(url, speed=speed, transcript_path=transcript_path, allow_remote=allow_remote, echo=echo,
                                login=login, model=model, profile=profile)
        standin.set_latency(latency_s, beep_latency_s)
        try:
            print(f"{READY_PREFIX}{standin.url}", file=out, flush=True)
            closer = on_ready(standin) if on_ready is not None else None
            try:
                while not stop.wait(0.2):
                    pass
            finally:
                if closer is not None:
                    closer()
        finally:
            standin.stop()
    finally:
        for sig, previous in handlers.items():
            signal.signal(sig, previous)
    return 0


def spawn_standin(
    port: int | None = None,
    speed: float = 1.0,
    transcript_path: str | os.PathLike | None = None,
    timeout_s: float = 15.0,
) -> tuple[subprocess.Popen, str]:
    """Start ``nao-trainer mock-robot`` as a child process on 127.0.0.1; returns (process, url).

    For tests and tools that must kill the robot and bring it back on the same port. The caller
    ends it with ``proc.send_signal(SIGINT)`` / ``proc.kill()`` and ``proc.wait()``.
    """
    listen = f"tcp://127.0.0.1:{0 if port is None else int(port)}"
    cmd = [sys.executable, "-m", "nao_trainer", "mock-robot", "--listen", listen, "--speed", repr(float(speed))]
    if transcript_path is not None:
        cmd += ["--transcript", os.fspath(transcript_path)]
    env = dict(os.environ, QI_LOG_LEVEL="silent", PYTHONUNBUFFERED="1")
    # stderr goes to an unnamed temporary file, not a pipe: nobody reads it while the child runs,
    # and a full pipe would block the stand-in.
    with tempfile.TemporaryFile("w+") as errors:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=errors, env=env, text=True)
        try:
            line = _read_line(proc, timeout_s)
        except BaseException:
            proc.kill()
            proc.wait()
            raise
        if not line.startswith(READY_PREFIX):
            proc.kill()
            proc.wait()
            errors.seek(0)
            last = (errors.read().strip().splitlines() or [line.strip() or "no output"])[-1]
            raise RobotUnavailable(f"the stand-in on {listen} did not start: {last}")
    return proc, line[len(READY_PREFIX):].strip()


def _read_line(proc: subprocess.Popen, timeout_s: float) -> str:
    """First stdout line of ``proc`` within ``timeout_s`` ('' when it exited first)."""
    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout_s):
            raise RobotUnavailable(f"the stand-in did not report ready within {timeout_s:g} s")
    return proc.stdout.readline()
