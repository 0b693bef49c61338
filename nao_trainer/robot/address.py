"""Robot addresses and NAOqi 2.9 credentials: parsed and checked without importing ``qi``.

The configuration validates ``robot.url`` with these functions, and ``check`` and the qi client
resolve the host before connecting, so a mistyped name is reported as such, not as a login failure.
Credentials come only from the environment and never appear in a printed address.
"""
from __future__ import annotations

import os
import re
import socket
import threading
from dataclasses import dataclass
from typing import Any

from nao_trainer.errors import ConfigError, RobotUnavailable

#: Environment variables holding NAOqi 2.9 credentials (never read from files, never logged).
USER_ENV, PASSWORD_ENV = "NAO_USER", "NAO_PASSWORD"


DEFAULT_PORTS = {"tcp": 9559, "tcps": 9503}


_URL_RE = re.compile(r"^(?P<scheme>[a-zA-Z][a-zA-Z0-9+.-]*)://(?:(?P<userinfo>[^@/]*)@)?(?P<host>\[[^\]]+\]|[^:/]+)(?::(?P<port>\d+))?/?$")


def redact_url(url: str) -> str:
    """``url`` with any user-info (``user:password@``) replaced by ``***@``; safe to print or log.

    A host never holds ``@``, so everything up to the *last* ``@`` is hidden, with or without a
    scheme: a password holding ``/`` or ``@`` must not leak either.
    """
    text = url.strip()
    if "@" not in text:
        return text
    scheme, sep, rest = text.partition("://")
    prefix = f"{scheme}{sep}" if sep and "@" not in scheme else ""
    return f"{prefix}***@{text.rsplit('@', 1)[1]}"


def parse_url(url: str) -> tuple[str | None, str | None]:
    """``(qi URL, None)`` for a robot address, ``(None, problem)`` otherwise: the one rule for addresses.

    ``IP`` -> ``tcp://IP:9559``; ``tcps://IP`` -> ``tcps://IP:9503``; IPv6 hosts in brackets. The
    problem is a phrase that follows the address or key it is about ("has port 0, out of range ...").
    """
    text = url.strip()
    if "@" in text:  # user-info, whatever it holds (a password may contain "/" or "@")
        return None, (f"contains credentials: remove them from the address and set {USER_ENV} and {PASSWORD_ENV} "
                      "in the environment instead")
    if "://" not in text:
        text = f"tcp://{text}"
    m = _URL_RE.match(text)
    if not m:
        return None, "is not of the form tcp://HOST:9559 (NAOqi <= 2.8) or tcps://HOST:9503 (NAOqi 2.9)"
    if m.group("userinfo") is not None:
        return None, (f"contains credentials: remove them from the address and set {USER_ENV} and {PASSWORD_ENV} "
                      "in the environment instead")
    scheme = m.group("scheme").lower()
    if scheme not in DEFAULT_PORTS:
        return None, f"has scheme {scheme!r}, not supported: use tcp://HOST:9559 (NAOqi <= 2.8) or tcps://HOST:9503 (NAOqi 2.9)"
    port = int(m.group("port")) if m.group("port") else DEFAULT_PORTS[scheme]
    if not 0 < port < 65536:
        return None, f"has port {port}, out of range 1..65535 (NAOqi listens on 9559, or 9503 for tcps)"
    return f"{scheme}://{m.group('host')}:{port}", None


def normalize_url(url: str) -> str:
    """The qi URL of a robot address (see ``parse_url``); ConfigError naming the problem otherwise."""
    qi_url, problem = parse_url(url)
    if problem:
        raise ConfigError(f"robot address {redact_url(url)!r} {problem}")
    return qi_url


@dataclass(frozen=True)
class Credentials:
    """A NAOqi 2.9 user and password; ``repr`` never shows the password."""

    user: str
    password: str

    def __repr__(self) -> str:
        return f"Credentials(user={self.user!r}, password='***')"

    __str__ = __repr__


def credentials_from_env(environ: dict[str, str] | None = None) -> Credentials | None:
    """The robot credentials from ``NAO_USER`` / ``NAO_PASSWORD``; None when neither is set."""
    env = os.environ if environ is None else environ
    user, password = env.get(USER_ENV, ""), env.get(PASSWORD_ENV, "")
    if not user and not password:
        return None
    if not user or not password:
        missing = USER_ENV if not user else PASSWORD_ENV
        raise ConfigError(f"{missing} is not set: NAOqi 2.9 needs both {USER_ENV} and {PASSWORD_ENV} in the environment")
    return Credentials(user, password)


class _Authenticator:
    """libqi client authenticator: sends the user and token once, when the robot asks."""

    def __init__(self, creds: Credentials) -> None:
        self._creds = creds

    def initialAuthData(self) -> dict[str, str]:
        return {"user": self._creds.user, "token": self._creds.password}

    def _processAuth(self, data: Any) -> dict[str, str]:  # noqa: N802 - libqi's name
        return {}


class AuthenticatorFactory:
    def __init__(self, creds: Credentials) -> None:
        self._creds = creds

    def newAuthenticator(self) -> _Authenticator:  # noqa: N802 - libqi's name
        return _Authenticator(self._creds)


def url_host(url: str) -> str:
    """The host part of a normalised qi URL, without IPv6 brackets."""
    m = _URL_RE.match(url)
    return m.group("host").strip("[]") if m else url


def resolve_host(url: str, deadline_s: float) -> None:
    """Raise RobotUnavailable when the URL's host name cannot be resolved.

    libqi reports an unknown host in ways that read like a login failure; resolving first names
    the real problem. ``getaddrinfo`` has no timeout of its own, so it runs in a thread bounded by
    the connect deadline (a slow resolver then falls through to the connect, which has its own).
    """
    host = url_host(url)
    outcome: list[BaseException | None] = []

    def resolve() -> None:
        try:
            socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
            outcome.append(None)
        except (OSError, UnicodeError) as exc:
            outcome.append(exc)

    worker = threading.Thread(target=resolve, name="resolve-robot-host", daemon=True)
    worker.start()
    worker.join(deadline_s)
    if outcome and isinstance(outcome[0], (socket.gaierror, UnicodeError)):
        raise RobotUnavailable(
            f"the robot's host name {host!r} cannot be resolved: check the spelling of --robot (or robot.url), "
            "or use the robot's IP address (press its chest button to hear it)"
        )
