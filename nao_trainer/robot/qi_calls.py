"""Deadlines for qi calls and the reading of qi's errors.

qi reports every failure as a ``RuntimeError`` with a message; these helpers decide which
messages mean a lost link (the session may reconnect) and turn connect errors into a sentence an
operator can act on.
"""
from __future__ import annotations

from dataclasses import dataclass

from nao_trainer.robot.address import PASSWORD_ENV, USER_ENV

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


#: Longest single blocking wait on a qi future. ``future.wait`` blocks in C++, where Python cannot
#: deliver Ctrl-C/SIGTERM; waiting in slices lets an operator interrupt a long utterance at once.


def _explain(error: str, tls: bool = False) -> str:
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
