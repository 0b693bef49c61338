"""A NAO stand-in served over a real ``qi`` session, for development, CI and offline studies.

The stand-in offers the NAOqi services the project uses, under NAOqi's names and signatures, so
the client (``nao_trainer.robot.naoqi.NaoqiRobot``) talks to it exactly as it talks to a NAO:

* ``ALTextToSpeech``  say(text) / say(text, language), setLanguage, getLanguage, setParameter,
  getParameter, setVolume, getVolume, stopAll (cuts the speech in progress short)
* ``ALAnimatedSpeech`` say(text) / say(text, configuration)
* ``ALAudioPlayer``   playSine(frequency, gain, pan, duration), stopAll
* ``ALLeds``          fadeRGB(name, rgb, secs) / fadeRGB(name, r, g, b, secs), reset, on, off
* ``ALRobotPosture``  goToPosture(name, speed) -> bool, getPosture, getPostureList
* ``ALMotion``        wakeUp, rest, robotIsWakeUp
* ``ALMemory``        subscriber(key) (object with ``.signal``), raiseEvent, insertData, getData
* ``NaoTrainerStandIn`` (control, not NAOqi) press(button or letter), transcript(), clear(),
  set_speed(x), speed()

Speech and motion take time (``SECONDS_PER_CHARACTER`` per character, a beep its duration,
divided by the speed factor) so sessions keep realistic timing that tests can speed up. Every
call is recorded in a transcript: in memory and, when a path is given, appended to a JSON-lines
file flushed per line: ``{"t": s_since_start, "service": ..., "method": ..., "args": [...]}``.
"""
from __future__ import annotations

import ipaddress
import json
import os
import re
import selectors
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

os.environ.setdefault("QI_LOG_LEVEL", "silent")  # qi logs to fd 1 otherwise; must precede `import qi`
import qi  # noqa: E402

from nao_trainer.errors import ConfigError, RobotUnavailable  # noqa: E402
from nao_trainer.ports import BUTTON_LETTERS  # noqa: E402

#: Speaking time per character at speed 1.0 (a NAO speaks roughly 12-15 characters a second).
SECONDS_PER_CHARACTER = 0.06
#: Time a posture change takes at speed 1.0 and posture speed 1.0.
POSTURE_SECONDS = 1.5
#: Postures ALRobotPosture knows on a NAO.
POSTURES = ("Stand", "StandInit", "StandZero", "Crouch", "Sit", "SitRelax", "LyingBelly", "LyingBack")
#: ALAnimatedSpeech body language modes.
BODY_LANGUAGE_MODES = ("disabled", "random", "contextual")
#: How long a simulated finger stays on a head button (seconds, at speed 1.0).
PRESS_HOLD_S = 0.05
#: The first line ``nao-trainer mock-robot`` prints once it serves.
READY_PREFIX = "nao-trainer mock-robot: listening on "

_LETTER_BUTTONS = {letter: key for key, letter in BUTTON_LETTERS.items()}
_URL_RE = re.compile(r"^(tcp|tcps)://([^:/@\s]+|\[[0-9a-fA-F:]+\]):(\d{1,5})$")


# ------------------------------------------------------------------------------------------------
# Shared state of one stand-in: clock (speed) and transcript
# ------------------------------------------------------------------------------------------------


@dataclass
class _Recorder:
    """Speed factor and transcript shared by all services; thread-safe (qi calls come on many threads)."""

    speed: float = 1.0
    path: Path | None = None
    echo: TextIO | None = None  # a human-readable line per call (``mock-robot --echo``: stderr)
    entries: list[dict[str, Any]] = field(default_factory=list)
    _t0: float = field(default_factory=time.monotonic)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _stopping: threading.Event = field(default_factory=threading.Event)
    _channels: list["_Channel"] = field(default_factory=list)
    _file: TextIO | None = None

    def __post_init__(self) -> None:
        self.speed = _check_speed(self.speed)
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._file = self.path.open("a", encoding="utf-8")
            except OSError as exc:
                raise ConfigError(
                    f"cannot open the transcript file {self.path}: {exc.strerror}; choose a writable path"
                ) from exc

    def record(self, service: str, method: str, args: tuple | list) -> None:
        entry = {
            "t": round(time.monotonic() - self._t0, 6),
            "service": service,
            "method": method,
            "args": [_jsonable(a) for a in args],
        }
        with self._lock:
            self.entries.append(entry)
            if self._file is not None:
                self._file.write(json.dumps(entry, ensure_ascii=False) + "\n")
                self._file.flush()
            if self.echo is not None:
                args_text = ", ".join(json.dumps(a, ensure_ascii=False) for a in entry["args"])
                print(f"{entry['t']:9.3f}  {service}.{method}({args_text})", file=self.echo, flush=True)

    def wait(self, seconds: float) -> None:
        """Sleep ``seconds`` of robot time (scaled by the speed factor); cut short when the stand-in stops."""
        if seconds > 0:
            self._stopping.wait(seconds / self.speed)

    def snapshot(self) -> list[dict[str, Any]]:
        with self._lock:
            return [dict(e) for e in self.entries]

    def clear(self) -> None:
        with self._lock:
            self.entries.clear()

    def close(self) -> None:
        self._stopping.set()
        for channel in self._channels:
            channel.shut()
        with self._lock:
            if self._file is not None:
                self._file.flush()
                self._file.close()
                self._file = None


class _Channel:
    """Something the robot does over time (speech, sound) that ``stopAll`` or shutdown cuts short."""

    def __init__(self, rec: _Recorder) -> None:
        self._rec = rec
        self._lock = threading.Lock()
        self._event = threading.Event()
        self._shut = False
        rec._channels.append(self)

    def run(self, seconds: float) -> bool:
        """Take ``seconds`` of robot time; False when interrupted."""
        with self._lock:
            if self._shut:
                return False
            event = self._event
        return seconds <= 0 or not event.wait(seconds / self._rec.speed)

    def interrupt(self) -> None:
        """End what runs now; later calls run normally."""
        with self._lock:
            self._event.set()
            self._event = threading.Event()

    def shut(self) -> None:
        with self._lock:
            self._shut = True
            self._event.set()


def _check_speed(speed: float) -> float:
    speed = float(speed)
    if not (speed > 0 and speed < 1e6):
        raise ConfigError(f"stand-in speed must be a positive factor (1 = real time), got {speed!r}")
    return speed


def _jsonable(value: Any) -> Any:
    """qi hands over tuples, dicts and numbers; keep the transcript plain JSON."""
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, float):
        return float(f"{value:.7g}")  # NAOqi floats are 32-bit: 0.2 arrives as 0.200000003
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    return repr(value)


# ------------------------------------------------------------------------------------------------
# NAOqi services
# ------------------------------------------------------------------------------------------------


@qi.multiThreaded()
class _TextToSpeech:
    """ALTextToSpeech: ``say`` blocks for a time proportional to the text."""

    def __init__(self, rec: _Recorder, speech: _Channel) -> None:
        self._rec = rec
        self._speech = speech
        self._lock = threading.Lock()
        self._language = "English"
        self._params: dict[str, float] = {"speed": 100.0, "pitchShift": 1.0, "volume": 1.0}
        self._volume = 1.0

    @qi.bind(qi.Void, qi.AnyArguments)
    def say(self, *args: Any) -> None:
        """``say(text)`` or ``say(text, language)`` (both NAOqi overloads)."""
        if len(args) not in (1, 2) or not all(isinstance(a, str) for a in args):
            raise RuntimeError("ALTextToSpeech::say expects (text) or (text, language)")
        self._rec.record("ALTextToSpeech", "say", list(args))
        self._speech.run(SECONDS_PER_CHARACTER * len(args[0]))

    @qi.bind(qi.Void, [qi.String])
    def setLanguage(self, language: str) -> None:
        self._rec.record("ALTextToSpeech", "setLanguage", [language])
        with self._lock:
            self._language = language

    @qi.bind(qi.String, [])
    def getLanguage(self) -> str:
        with self._lock:
            return self._language

    @qi.bind(qi.List(qi.String), [])
    def getAvailableLanguages(self) -> list[str]:
        return ["English", "French", "Greek"]

    @qi.bind(qi.Void, [qi.String, qi.Float])
    def setParameter(self, name: str, value: float) -> None:
        self._rec.record("ALTextToSpeech", "setParameter", [name, value])
        with self._lock:
            self._params[name] = float(value)

    @qi.bind(qi.Float, [qi.String])
    def getParameter(self, name: str) -> float:
        with self._lock:
            if name not in self._params:
                raise RuntimeError(f"ALTextToSpeech::getParameter: unknown parameter {name!r}")
            return self._params[name]

    @qi.bind(qi.Void, [qi.Float])
    def setVolume(self, volume: float) -> None:
        self._rec.record("ALTextToSpeech", "setVolume", [volume])
        with self._lock:
            self._volume = float(volume)

    @qi.bind(qi.Float, [])
    def getVolume(self) -> float:
        with self._lock:
            return self._volume

    @qi.bind(qi.Void, [])
    def stopAll(self) -> None:
        """Interrupt the speech in progress (animated speech too, as on a NAO)."""
        self._rec.record("ALTextToSpeech", "stopAll", [])
        self._speech.interrupt()


@qi.multiThreaded()
class _AnimatedSpeech:
    """ALAnimatedSpeech: ``say(text)`` and ``say(text, configuration)`` (a NAOqi overload)."""

    def __init__(self, rec: _Recorder, speech: _Channel) -> None:
        self._rec = rec
        self._speech = speech

    @qi.bind(qi.Void, qi.AnyArguments)
    def say(self, *args: Any) -> None:
        if len(args) not in (1, 2) or not isinstance(args[0], str):
            raise RuntimeError("ALAnimatedSpeech::say expects (text) or (text, configuration)")
        if len(args) == 2:
            config = args[1]
            if not isinstance(config, dict):
                raise RuntimeError("ALAnimatedSpeech::say: configuration must be a map, e.g. {'bodyLanguageMode': 'contextual'}")
            mode = config.get("bodyLanguageMode", "contextual")
            if mode not in BODY_LANGUAGE_MODES:
                raise RuntimeError(
                    f"ALAnimatedSpeech::say: bodyLanguageMode must be one of {', '.join(BODY_LANGUAGE_MODES)}, got {mode!r}"
                )
        self._rec.record("ALAnimatedSpeech", "say", list(args))
        self._speech.run(SECONDS_PER_CHARACTER * len(_strip_annotations(args[0])))


def _strip_annotations(text: str) -> str:
    """Animated speech tags like ``^start(animations/...)`` or ``\\pau=300\\`` are not spoken."""
    return re.sub(r"\^\w+\([^)]*\)|\\\w+=\w+\\", "", text)


@qi.multiThreaded()
class _AudioPlayer:
    """ALAudioPlayer: ``playSine`` blocks for the beep's duration."""

    def __init__(self, rec: _Recorder) -> None:
        self._rec = rec
        self._sound = _Channel(rec)

    @qi.bind(qi.Void, [qi.Int32, qi.Int32, qi.Int32, qi.Float])
    def playSine(self, frequency: int, gain: int, pan: int, duration: float) -> None:
        if not 0 <= gain <= 100:
            raise RuntimeError(f"ALAudioPlayer::playSine: gain must be 0..100 percent, got {gain}")
        if not -1 <= pan <= 1:
            raise RuntimeError(f"ALAudioPlayer::playSine: pan must be -1, 0 or 1, got {pan}")
        self._rec.record("ALAudioPlayer", "playSine", [frequency, gain, pan, duration])
        self._sound.run(duration)

    @qi.bind(qi.Void, [])
    def stopAll(self) -> None:
        self._rec.record("ALAudioPlayer", "stopAll", [])
        self._sound.interrupt()


@qi.multiThreaded()
class _Leds:
    """ALLeds: ``fadeRGB(name, 0xRRGGBB, secs)`` and ``fadeRGB(name, r, g, b, secs)`` block for ``secs``."""

    def __init__(self, rec: _Recorder) -> None:
        self._rec = rec

    @qi.bind(qi.Void, qi.AnyArguments)
    def fadeRGB(self, *args: Any) -> None:
        if len(args) == 3:
            name, rgb, secs = args
            if not isinstance(rgb, int) or not 0 <= rgb <= 0xFFFFFF:
                raise RuntimeError(f"ALLeds::fadeRGB: rgb must be an int 0xRRGGBB, got {rgb!r}")
        elif len(args) == 5:
            name, *colour, secs = args
            if not all(isinstance(c, (int, float)) and 0.0 <= c <= 1.0 for c in colour):
                raise RuntimeError(f"ALLeds::fadeRGB: r, g, b must be floats in 0..1, got {colour!r}")
        else:
            raise RuntimeError("ALLeds::fadeRGB expects (name, rgb, secs) or (name, r, g, b, secs)")
        if not isinstance(name, str):
            raise RuntimeError(f"ALLeds::fadeRGB: LED name must be a string, got {name!r}")
        self._rec.record("ALLeds", "fadeRGB", list(args))
        self._rec.wait(float(secs))

    @qi.bind(qi.Void, [qi.String])
    def reset(self, name: str) -> None:
        self._rec.record("ALLeds", "reset", [name])

    @qi.bind(qi.Void, [qi.String])
    def on(self, name: str) -> None:
        self._rec.record("ALLeds", "on", [name])

    @qi.bind(qi.Void, [qi.String])
    def off(self, name: str) -> None:
        self._rec.record("ALLeds", "off", [name])


@qi.multiThreaded()
class _RobotPosture:
    """ALRobotPosture: ``goToPosture`` takes time inversely proportional to the speed argument."""

    def __init__(self, rec: _Recorder) -> None:
        self._rec = rec
        self._lock = threading.Lock()
        self._posture = "Crouch"

    @qi.bind(qi.Bool, [qi.String, qi.Float])
    def goToPosture(self, name: str, speed: float) -> bool:
        self._rec.record("ALRobotPosture", "goToPosture", [name, speed])
        if name not in POSTURES:
            raise RuntimeError(f"ALRobotPosture::goToPosture: unknown posture {name!r} (known: {', '.join(POSTURES)})")
        if not 0.0 < speed <= 1.0:
            raise RuntimeError(f"ALRobotPosture::goToPosture: speed must be in (0, 1], got {speed}")
        self._rec.wait(POSTURE_SECONDS / speed)
        with self._lock:
            self._posture = name
        return True

    @qi.bind(qi.String, [])
    def getPosture(self) -> str:
        with self._lock:
            return self._posture

    @qi.bind(qi.List(qi.String), [])
    def getPostureList(self) -> list[str]:
        return list(POSTURES)

    def _set(self, name: str) -> None:
        with self._lock:
            self._posture = name


@qi.multiThreaded()
class _Motion:
    """ALMotion (subset): ``wakeUp`` stiffens and stands, ``rest`` crouches and relaxes."""

    def __init__(self, rec: _Recorder, posture: _RobotPosture) -> None:
        self._rec = rec
        self._posture = posture
        self._awake = False
        self._lock = threading.Lock()

    @qi.bind(qi.Void, [])
    def wakeUp(self) -> None:
        self._rec.record("ALMotion", "wakeUp", [])
        self._rec.wait(POSTURE_SECONDS)
        self._posture._set("Stand")
        with self._lock:
            self._awake = True

    @qi.bind(qi.Void, [])
    def rest(self) -> None:
        self._rec.record("ALMotion", "rest", [])
        self._rec.wait(POSTURE_SECONDS)
        self._posture._set("Crouch")
        with self._lock:
            self._awake = False

    @qi.bind(qi.Bool, [])
    def robotIsWakeUp(self) -> bool:
        with self._lock:
            return self._awake


class _MemorySubscriber:
    """What ``ALMemory.subscriber(key)`` returns: an object whose ``signal`` fires on each new value."""

    def __init__(self) -> None:
        self.signal = qi.Signal("m")


@qi.multiThreaded()
class _Memory:
    """ALMemory (subset): key-value data and events; subscribers of a key get every raised value."""

    def __init__(self, rec: _Recorder) -> None:
        self._rec = rec
        self._lock = threading.Lock()
        self._data: dict[str, Any] = {key: 0.0 for key in BUTTON_LETTERS}
        self._subscribers: dict[str, list[_MemorySubscriber]] = {}

    @qi.bind(qi.Object, [qi.String])
    def subscriber(self, key: str) -> _MemorySubscriber:
        self._rec.record("ALMemory", "subscriber", [key])
        sub = _MemorySubscriber()
        with self._lock:
            self._subscribers.setdefault(key, []).append(sub)
        return sub

    @qi.bind(qi.Void, [qi.String, qi.Dynamic])
    def raiseEvent(self, key: str, value: Any) -> None:
        self._rec.record("ALMemory", "raiseEvent", [key, value])
        self._emit(key, value)

    @qi.bind(qi.Void, [qi.String, qi.Dynamic])
    def insertData(self, key: str, value: Any) -> None:
        self._rec.record("ALMemory", "insertData", [key, value])
        self._emit(key, value)

    @qi.bind(qi.Dynamic, [qi.String])
    def getData(self, key: str) -> Any:
        with self._lock:
            if key not in self._data:
                raise RuntimeError(f"ALMemory::getData: there is no data for key {key!r}")
            return self._data[key]

    @qi.bind(qi.List(qi.String), [])
    def getDataListName(self) -> list[str]:
        with self._lock:
            return sorted(self._data)

    def _emit(self, key: str, value: Any) -> None:
        # Like NAOqi, inserting a value also notifies the key's subscribers.
        with self._lock:
            self._data[key] = value
            subscribers = list(self._subscribers.get(key, ()))
        for sub in subscribers:
            sub.signal(value)

    def _forget_subscribers(self) -> None:
        with self._lock:
            self._subscribers.clear()


def button_key(button: str) -> str:
    """The ALMemory key of a head button given as a letter (A/B/C), a key or a short name (front/middle/rear)."""
    text = button.strip()
    if text.upper() in _LETTER_BUTTONS:
        return _LETTER_BUTTONS[text.upper()]
    for key in BUTTON_LETTERS:
        if text.lower() in (key.lower(), key.lower().removesuffix("tactiltouched")):
            return key
    raise ValueError(
        f"unknown head button {button!r}: use a letter ({', '.join(_LETTER_BUTTONS)}), "
        f"a key ({', '.join(BUTTON_LETTERS)}) or front/middle/rear"
    )


@qi.multiThreaded()
class _Control:
    """NaoTrainerStandIn: what tests and simulated participants use to act on the stand-in."""

    def __init__(self, rec: _Recorder, memory: _Memory) -> None:
        self._rec = rec
        self._memory = memory

    @qi.bind(qi.String, [qi.String])
    def press(self, button: str) -> str:
        """Touch then release a head button; returns the ALMemory key pressed."""
        try:
            key = button_key(button)
        except ValueError as exc:
            raise RuntimeError(str(exc)) from None
        self._rec.record("NaoTrainerStandIn", "press", [key])
        self._memory._emit(key, 1.0)
        self._rec.wait(PRESS_HOLD_S)
        self._memory._emit(key, 0.0)
        return key

    @qi.bind(qi.List(qi.Map(qi.String, qi.Dynamic)), [])
    def transcript(self) -> list[dict[str, Any]]:
        return self._rec.snapshot()

    @qi.bind(qi.Void, [])
    def clear(self) -> None:
        self._rec.clear()

    @qi.bind(qi.Void, [qi.Float])
    def set_speed(self, speed: float) -> None:
        try:
            self._rec.speed = _check_speed(speed)
        except ConfigError as exc:
            raise RuntimeError(str(exc)) from None

    @qi.bind(qi.Float, [])
    def speed(self) -> float:
        return self._rec.speed


# ------------------------------------------------------------------------------------------------
# The stand-in as an object (in-process) and as a process
# ------------------------------------------------------------------------------------------------


def check_listen_url(url: str, allow_remote: bool = False) -> str:
    """Validate a ``tcp://HOST:PORT`` listen address; only loopback unless ``allow_remote``."""
    m = _URL_RE.match(url.strip())
    if not m:
        raise ConfigError(f"listen address {url!r} is not of the form tcp://127.0.0.1:PORT (port 0 picks a free one)")
    scheme, host, port = m.group(1), m.group(2).strip("[]"), int(m.group(3))
    if scheme != "tcp":
        raise ConfigError(f"listen address {url!r}: the stand-in serves plain tcp:// only (no certificates)")
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
        self, session: Any, url: str, recorder: _Recorder, memory: _Memory, control: _Control, service_ids: list[int]
    ) -> None:
        self._session = session
        self._service_ids = service_ids
        self.url = url
        self._rec = recorder
        self._memory = memory
        self._control = control
        self._stopped = False

    @classmethod
    def start(
        cls,
        url: str = "tcp://127.0.0.1:0",
        speed: float = 1.0,
        transcript_path: str | os.PathLike | None = None,
        allow_remote: bool = False,
        echo: TextIO | None = None,
    ) -> "StandIn":
        """Serve the stand-in on ``url`` (port 0 picks a free port; ``.url`` tells which).

        ``echo``: a stream that gets one readable line per call (the robot's actions, live).
        """
        url = check_listen_url(url, allow_remote)
        rec = _Recorder(speed=speed, path=Path(transcript_path) if transcript_path else None, echo=echo)
        session = qi.Session()
        try:
            session.listenStandalone(url)
        except RuntimeError as exc:
            rec.close()
            session.close()
            if "already in use" in str(exc):
                reason = "the port is already in use (another mock-robot or NAOqi?)"
            else:  # qi's message spans lines and cites boost sources: keep its gist
                reason = re.sub(r"\s*\[system:.*", "", " ".join(str(exc).split()))
            raise RobotUnavailable(
                f"the stand-in cannot listen on {url}: {reason}; pick another port or use port 0"
            ) from None
        memory = _Memory(rec)
        posture = _RobotPosture(rec)
        control = _Control(rec, memory)
        speech = _Channel(rec)
        services = {
            "ALTextToSpeech": _TextToSpeech(rec, speech),
            "ALAnimatedSpeech": _AnimatedSpeech(rec, speech),
            "ALAudioPlayer": _AudioPlayer(rec),
            "ALLeds": _Leds(rec),
            "ALRobotPosture": posture,
            "ALMotion": _Motion(rec, posture),
            "ALMemory": memory,
            "NaoTrainerStandIn": control,
        }
        ids = [session.registerService(name, obj) for name, obj in services.items()]
        bound = _bound_url(session, url)
        return cls(session, bound, rec, memory, control, ids)

    @property
    def speed(self) -> float:
        return self._rec.speed

    def set_speed(self, speed: float) -> None:
        self._rec.speed = _check_speed(speed)

    def press(self, button: str) -> str:
        """Touch and release a head button given as letter A/B/C or ALMemory key; returns the key."""
        try:
            return self._control.press(button)
        except RuntimeError as exc:
            raise ValueError(str(exc)) from None

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
        self._rec._stopping.set()  # pending say/playSine/... return at once
        for channel in self._rec._channels:
            channel.shut()
        self._memory._forget_subscribers()
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
            self._rec.close()

    def __enter__(self) -> "StandIn":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class StandInClient:
    """The stand-in's control service seen from another process (a simulated participant, a test).

    ``StandInClient.connect(url)`` then ``press("A")``, ``transcript()``, ``clear()``,
    ``set_speed(x)``; ``close()`` when done.
    """

    def __init__(self, session: Any, url: str, control: Any) -> None:
        self._session = session
        self.url = url
        self._control = control

    @classmethod
    def connect(cls, url: str, deadline_s: float = 5.0) -> "StandInClient":
        """Connect within ``deadline_s`` (lookup of the control service included) or raise RobotUnavailable."""
        deadline = time.monotonic() + deadline_s
        session = qi.Session()

        def wait(future: Any) -> bool:
            left_ms = max(1, int((deadline - time.monotonic()) * 1000))
            return future.wait(left_ms) != qi.FutureState.Running

        connecting = session.connect(url, _async=True)
        if not wait(connecting):
            session.close()
            raise RobotUnavailable(f"no answer from the stand-in at {url} within {deadline_s:g} s: is it a `nao-trainer mock-robot`?")
        if connecting.hasError():
            error = " ".join(connecting.error().split())
            session.close()
            raise RobotUnavailable(f"cannot reach the stand-in at {url} ({error}): is `nao-trainer mock-robot` running there?")
        lookup = session.service("NaoTrainerStandIn", _async=True)
        if not wait(lookup) or lookup.hasError():
            reason = "no answer" if lookup.isRunning() else " ".join(lookup.error().split())
            session.close()
            raise RobotUnavailable(
                f"{url} offers no NaoTrainerStandIn control service ({reason}): it is not a `nao-trainer mock-robot`"
            )
        return cls(session, url, lookup.value())

    def press(self, button: str) -> str:
        """Touch and release a head button (letter A/B/C or ALMemory key); returns the key."""
        try:
            return self._control.press(button)
        except RuntimeError as exc:
            if "unknown head button" in str(exc):
                raise ValueError(str(exc).strip().splitlines()[0]) from None
            raise

    def transcript(self) -> list[dict[str, Any]]:
        return [dict(e) for e in self._control.transcript()]

    def clear(self) -> None:
        self._control.clear()

    def set_speed(self, speed: float) -> None:
        self._control.set_speed(_check_speed(speed))

    def speed(self) -> float:
        return float(self._control.speed())

    def close(self) -> None:
        self._session.close()

    def __enter__(self) -> "StandInClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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
) -> int:
    """Run the stand-in until SIGINT/SIGTERM (``nao-trainer mock-robot``); prints the ready line."""
    out = out or sys.stdout
    stop = threading.Event()
    handlers = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        standin = StandIn.start(url, speed=speed, transcript_path=transcript_path, allow_remote=allow_remote, echo=echo)
        try:
            print(f"{READY_PREFIX}{standin.url}", file=out, flush=True)
            while not stop.wait(0.2):
                pass
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
