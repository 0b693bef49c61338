"""Shared state of one stand-in: the speed factor (robot time) and the transcript of every call."""
from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, TextIO

from nao_trainer.errors import ConfigError



@dataclass
class Recorder:
    """Speed factor and transcript shared by all services; thread-safe (qi calls come on many threads)."""

    speed: float = 1.0
    path: Path | None = None
    echo: TextIO | None = None  # a human-readable line per call (``mock-robot --echo``: stderr)
    entries: list[dict[str, Any]] = field(default_factory=list)
    _t0: float = field(default_factory=time.monotonic)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _stopping: threading.Event = field(default_factory=threading.Event)
    _channels: list["Channel"] = field(default_factory=list)
    _file: TextIO | None = None
    _armed: dict[str, list[Callable[[], None]]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.speed = check_speed(self.speed)
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

    def arm(self, call: str, action: Callable[[], None]) -> None:
        """Run ``action`` once, when the next ``call`` has finished: "ALAudioPlayer.playSine",
        "ALTextToSpeech.say", "ALAnimatedSpeech.say" or "speech" (either say); "A>B" is the first B
        after the next A (e.g. "ALAudioPlayer.playSine>speech": the first utterance after a beep)."""
        first, _, then = call.partition(">")
        if then:
            self.arm(first, lambda: self.arm(then, action))
            return
        with self._lock:
            self._armed.setdefault(call, []).append(action)

    def finished(self, call: str) -> None:
        """A call that tests may hook (``arm``) has finished: run what was armed on it."""
        with self._lock:
            actions = self._armed.pop(call, [])
        for action in actions:
            action()

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

    def interrupt(self) -> None:
        """Cut every pending ``wait`` and channel (say, playSine, ...) short: the stand-in stops."""
        self._stopping.set()
        for channel in self._channels:
            channel.shut()

    def close(self) -> None:
        self.interrupt()
        with self._lock:
            if self._file is not None:
                self._file.flush()
                self._file.close()
                self._file = None


class Channel:
    """Something the robot does over time (speech, sound) that ``stopAll`` or shutdown cuts short."""

    def __init__(self, rec: Recorder) -> None:
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


def check_speed(speed: float) -> float:
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
