"""A watchdog on the link to the robot while the session only waits (an answer window).

libqi notices a silent link loss (Wi-Fi gone, no TCP reset) only after about 60 s: 30 s idle, then
10 probes 3 s apart (libqi ``src/messaging/tcpmessagesocket.cpp``, ``QI_TCP_PING_TIMEOUT``), and
``Session.isConnected()`` stays true meanwhile. An answer window lasts 12.5-20 s and sends nothing,
so without a probe of our own a dropped link would be scored as the participant's timeout. The
watchdog makes one cheap call every ``interval_s`` with a short deadline; the first that does not
answer in time marks the link lost (the session then replays the turn).
"""
from __future__ import annotations

import threading
from typing import Callable

from nao_trainer.ports import RobotCallFailed, RobotConnectionLost


class LinkWatchdog:
    """``with LinkWatchdog(ping, 1.0, 2.0) as watch: ...``; afterwards ``watch.lost`` says why, or None.

    ``ping(deadline_s)`` makes one call and raises ``RobotConnectionLost`` when it gets no answer in
    time. Leaving the ``with`` waits for a ping in flight (at most its deadline), so a freeze that
    began just before the end of the window is still seen.
    """

    def __init__(self, ping: Callable[[float], float], interval_s: float = 1.0, deadline_s: float = 2.0) -> None:
        if interval_s <= 0 or deadline_s <= 0:
            raise ValueError(f"watchdog interval and deadline must be > 0, got {interval_s!r}, {deadline_s!r}")
        self._ping = ping
        self.interval_s, self.deadline_s = float(interval_s), float(deadline_s)
        self.lost: str | None = None
        self.pings = 0
        self.rtts: list[float] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> "LinkWatchdog":
        self._thread = threading.Thread(target=self._run, name="robot-link-watchdog", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(self.deadline_s + 1.0)

    def _run(self) -> None:
        while True:
            try:
                self.rtts.append(self._ping(self.deadline_s))
                self.pings += 1
            except RobotConnectionLost as exc:
                self.lost = str(exc)
                return
            except RobotCallFailed:  # the robot answered (with an error): the link is alive
                self.pings += 1
            if self._stop.wait(self.interval_s):
                return
