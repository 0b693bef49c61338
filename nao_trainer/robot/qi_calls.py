"""Deadlines for qi calls, connecting a qi session, and the reading of qi's errors.

qi reports every failure as a ``RuntimeError`` with a message; these helpers decide which
messages mean a lost link (the session may reconnect) and turn connect errors into a sentence an
operator can act on.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("QI_LOG_LEVEL", "silent")  # qi logs to fd 1 otherwise; must precede `import qi`
import qi  # noqa: E402

from nao_trainer.errors import RobotUnavailable  # noqa: E402
from nao_trainer.robot.address import (PASSWORD_ENV, USER_ENV, Credentials, AuthenticatorFactory,  # noqa: E402
                                       redact_url)

STANDIN_HINT = "(no robot at hand? start `nao-trainer mock-robot` and use tcp://127.0.0.1:9559)"

# qi reports every failure as RuntimeError; these messages mean the link to the robot is gone.
_LOST_MARKERS = (
    "session closed",
    "socket is not connected",
    "not connected",
    "connection refused",
    "connection reset",
    "broken pipe",
    "disconnected",
    "socket was closed",
    "socket closed",
    "network is unreachable",
    "no route to host",
)


@dataclass(frozen=True)
class CallTimeouts:
    """Deadlines for remote calls (seconds); speech gets extra time per character of text."""

    default_s: float = 10.0
    say_base_s: float = 15.0
    say_per_char_s: float = 0.25
    posture_s: float = 60.0
    subscribe_s: float = 5.0

    def say(self, text: str) -> float:
        return self.say_base_s + self.say_per_char_s * len(text)


def is_connection_lost(error: BaseException | str) -> bool:
    """Whether a qi error message means the link to the robot is gone."""
    text = str(error).lower()
    return any(marker in text for marker in _LOST_MARKERS)


def explain_error(error: str, tls: bool = False) -> str:
    """A short, user-facing reading of a qi connect error (``tls``: a NAOqi 2.9 ``tcps://`` login was sent)."""
    text = error.lower()
    if tls and ("auth" in text or "disconnected" in text):
        # qi 3.1.5 (libqi 4.0.5) clients do not enforce authentication, so a server's "Authentication
        # failed" reply is not reported as such: the server then closes the link, seen as "disconnected".
        return (f"the robot closed the connection at login ({error.strip()}): NAOqi 2.9 refused the user or "
                f"password - check {USER_ENV} / {PASSWORD_ENV}")
    if "refused" in text:
        return "connection refused - is the robot on, is the address right, is NAOqi running on that port?"
    if "auth" in text:
        return f"authentication failed - check {USER_ENV} / {PASSWORD_ENV} (NAOqi 2.9)"
    if "unreachable" in text or "no route" in text or "timed out" in text:
        return "network unreachable - is the laptop on the robot's network?"
    if "resolve" in text or "host not found" in text or "name" in text:
        return "unknown host name - check the address"
    return f"{error.strip()} - is the robot on and the address right?"


#: Longest single blocking wait on a qi future. ``future.wait`` blocks in C++, where Python cannot
#: deliver Ctrl-C/SIGTERM; waiting in slices lets an operator interrupt a long utterance at once.
_WAIT_SLICE_S = 0.1


def wait_future(future: Any, timeout_s: float) -> bool:
    """Wait for a qi future; True when it finished within ``timeout_s`` (interruptible by signals)."""
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        state = future.wait(max(1, int(min(remaining, _WAIT_SLICE_S) * 1000)))
        if state != qi.FutureState.Running:
            return True
        if remaining <= _WAIT_SLICE_S:
            return False


def new_session(creds: Credentials | None) -> Any:
    session = qi.Session()
    if creds is not None:
        session.setClientAuthenticatorFactory(AuthenticatorFactory(creds))
    return session


def connect_session(session: Any, url: str, deadline_s: float) -> None:
    """Connect ``session`` to ``url`` within ``deadline_s``; close it and raise RobotUnavailable otherwise.

    ``Session.connect`` has no timeout of its own against a port that accepts TCP but never
    speaks qi, hence the future and the close on deadline.
    """
    where = redact_url(url)
    future = session.connect(url, _async=True)
    if not wait_future(future, deadline_s):
        session.close()
        raise RobotUnavailable(
            f"no answer from the robot at {where} within {deadline_s:g} s (something listens there but does not "
            f"speak NAOqi): is the address right and NAOqi running? {STANDIN_HINT}"
        )
    if future.hasError():
        error = future.error()
        session.close()
        raise RobotUnavailable(f"cannot reach the robot at {where}: {explain_error(error, url.startswith('tcps://'))} "
                               f"{STANDIN_HINT}")


