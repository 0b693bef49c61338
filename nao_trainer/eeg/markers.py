"""Session events as an LSL marker stream, so EEG and events land in one synchronised recording.

The outlet is named and typed ``Markers`` (what LabRecorder and ``muselsl record`` look for), has one
string channel at an irregular rate and a source_id stable for one session folder, so recorders reconnect after a
restart (a resumption goes on in its folder) and never to another session's markers.
Events are stamped with ``pylsl.local_clock()`` at the moment they are pushed. Names follow
``session_start``, ``turn_3_start``, ``turn_3_listening_start``, ``turn_3_listening_end``, ...
"""
from __future__ import annotations

import re
import socket
import threading

from nao_trainer.eeg.lsl_scope import configure_lsl

_SAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def marker_source_id(pseudonym: str | None = None, session: str | None = None) -> str:
    """``nao-trainer-markers-<pseudonym or host>[-<session folder>]``.

    With the session folder's name, two sessions of one pseudonym on one machine never share it: liblsl's
    inlets recover a lost stream by its source_id, and a session's recorder whose inlet had found the other
    session's outlet went over to its own when that one ended, with both sessions' markers in one file (seen
    with two test suites side by side).
    """
    who = pseudonym or socket.gethostname() or "host"
    sid = f"nao-trainer-markers-{_SAFE.sub('-', who)}"
    return f"{sid}-{_SAFE.sub('-', session)}" if session else sid


def event_name(event: str, turn: int | None = None) -> str:
    """``event`` prefixed with ``turn_<n>_`` when a turn is given.

    ``event_name("listening_start", 3)`` is ``turn_3_listening_start``; ``event_name("turn_start", 3)``
    is ``turn_3_start``.
    """
    event = _SAFE.sub("_", event.strip()) or "event"
    if turn is None:
        return event
    if event.startswith("turn_"):  # mark("turn_start", 3) -> "turn_3_start", not "turn_3_turn_start"
        event = event[len("turn_"):]
    return f"turn_{int(turn)}_{event}"


class MarkerOutlet:
    """One ``Markers`` outlet. ``push`` is thread-safe and returns the LSL time it stamped."""

    def __init__(self, source_id: str | None = None, name: str = "Markers", scope: str = "machine") -> None:
        configure_lsl(scope)
        import pylsl

        self._pylsl = pylsl
        self.source_id = source_id or marker_source_id()
        info = pylsl.StreamInfo(name, "Markers", 1, pylsl.IRREGULAR_RATE, pylsl.cf_string, self.source_id)
        info.desc().append_child_value("manufacturer", "nao-trainer")
        self._outlet = pylsl.StreamOutlet(info)
        self._lock = threading.Lock()

    def push(self, event: str, turn: int | None = None) -> float:
        """Publish one event now; returns its LSL timestamp (0.0 when the outlet is closed)."""
        name = event_name(event, turn)
        with self._lock:
            if self._outlet is None:
                return 0.0
            stamp = self._pylsl.local_clock()
            self._outlet.push_sample([name], stamp)
        return stamp

    def has_consumers(self) -> bool:
        with self._lock:
            return bool(self._outlet is not None and self._outlet.have_consumers())

    def close(self) -> None:
        """Destroy the outlet (recorders see the stream end)."""
        with self._lock:
            self._outlet = None

    def __enter__(self) -> "MarkerOutlet":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
