"""NAOqi 2.9's login, checked the way libqi's server checks it, for the stand-in's ``tcps://`` front.

A libqi client opens the link with an authentication call (service 0 "Server", action 8
"Authenticate") whose argument is a capability map holding ``auth_user`` and ``auth_token``
(libqi ``src/messaging/authprovider.cpp``: user data carries the ``auth_`` prefix on the wire).
A server that refuses answers that call with an error message (type 3) holding the string
``"Authentication failed: <reason> [<major>.<minor>]"`` and closes the socket
(``Server::authenticateSocket`` and ``sendAuthError`` in ``src/messaging/server.cpp``); the
client then fails its connect with ``"Authentication failed: " + that string``
(``src/messaging/servicedirectoryclient.cpp``). The wire format (little-endian header of 28 bytes
after the magic ``42 de ad 42``; strings and dynamic values as ``uint32`` length + bytes) is
libqi's ``src/messaging/message.hpp`` and was checked against bytes a qi 3.1.5 client sends.
"""
from __future__ import annotations

import asyncio
import hmac
import struct
from dataclasses import dataclass

MAGIC = b"\x42\xde\xad\x42"
HEADER = struct.Struct("<4sIIHBBIII")  # magic, id, size, version, type, flags, service, object, action
TYPE_CALL, TYPE_ERROR = 1, 3
SERVICE_SERVER, ACTION_AUTHENTICATE = 0, 8
#: The reason the stand-in gives (a NAO's own wording is not documented) and libqi's auth version.
REASON, AUTH_VERSION = "invalid user or password", "1.0"
_FIXED = {"b": 1, "c": 1, "C": 1, "w": 2, "W": 2, "i": 4, "I": 4, "f": 4, "l": 8, "L": 8, "d": 8}


@dataclass(frozen=True)
class Login:
    """The user and password the stand-in's tcps front accepts (``repr`` hides the password)."""

    user: str
    password: str

    def __repr__(self) -> str:
        return f"Login(user={self.user!r}, password='***')"

    def check_first_message(self, message: bytes) -> str | None:
        """None when ``message`` is an authentication call with this login, else why it is refused."""
        try:
            magic, _, _, _, kind, _, service, _, action = HEADER.unpack_from(message)
            if magic != MAGIC or kind != TYPE_CALL or (service, action) != (SERVICE_SERVER, ACTION_AUTHENTICATE):
                return "expected an authentication message first"
            caps = _read_map(message, HEADER.size)
        except (struct.error, ValueError, UnicodeDecodeError):
            return "malformed authentication message"
        user, token = caps.get("auth_user"), caps.get("auth_token")
        if not isinstance(user, str) or not isinstance(token, str):
            return "missing credentials"
        ok_user = hmac.compare_digest(user.encode(), self.user.encode())
        ok_token = hmac.compare_digest(token.encode(), self.password.encode())
        return None if ok_user and ok_token else REASON


async def read_message(reader: asyncio.StreamReader) -> bytes:
    """One whole qi message (header and payload) from ``reader``."""
    header = await reader.readexactly(HEADER.size)
    size = struct.unpack_from("<I", header, 8)[0]
    if size > 1 << 20:
        raise ValueError("first message too large for an authentication")
    return header + await reader.readexactly(size)


def refuse(request: bytes, reason: str) -> bytes:
    """The error reply libqi's server sends to a refused authentication call."""
    _, msg_id, _, version, *_ = HEADER.unpack_from(request) if len(request) >= HEADER.size else (0,) * 9
    text = f"Authentication failed: {reason} [{AUTH_VERSION}]".encode()
    payload = _string(b"s") + _string(text)  # a dynamic value: its signature, then the string
    return HEADER.pack(MAGIC, msg_id or 0, len(payload), version or 0, TYPE_ERROR, 0, SERVICE_SERVER, 0,
                       ACTION_AUTHENTICATE) + payload


def _string(data: bytes) -> bytes:
    return struct.pack("<I", len(data)) + data


def _read_string(buf: bytes, at: int) -> tuple[bytes, int]:
    (n,) = struct.unpack_from("<I", buf, at)
    end = at + 4 + n
    if end > len(buf):
        raise ValueError("string beyond the message")
    return buf[at + 4:end], end


def _read_map(buf: bytes, at: int) -> dict[str, object]:
    """A capability map ``{string: dynamic}``; values other than strings are skipped (kept as None)."""
    (count,) = struct.unpack_from("<I", buf, at)
    at += 4
    out: dict[str, object] = {}
    for _ in range(count):
        key, at = _read_string(buf, at)
        value, at = _read_dynamic(buf, at)
        out[key.decode()] = value
    return out


def _read_dynamic(buf: bytes, at: int) -> tuple[object, int]:
    signature, at = _read_string(buf, at)
    return _read_value(buf, at, signature.decode())


def _read_value(buf: bytes, at: int, signature: str) -> tuple[object, int]:
    if signature in _FIXED:
        return None, at + _FIXED[signature]
    if signature in ("s", "r"):
        data, at = _read_string(buf, at)
        return data.decode() if signature == "s" else None, at
    if signature == "m":
        return _read_dynamic(buf, at)
    if signature == "v":
        return None, at
    raise ValueError(f"unexpected signature {signature!r} in an authentication message")
