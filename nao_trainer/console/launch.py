"""Opening a session's console as the operator asked: TLS beyond loopback, the link and the warnings printed.

Beyond loopback (an address outside 127.0.0.0/8 and ::1) the console is served over HTTPS with a
self-signed certificate made now, and its fingerprint is printed for the supervisor to compare with
the browser's; plain HTTP there only with ``insecure`` (the operator's explicit choice), with a
warning that the token crosses the network in clear. ``force_tls``: HTTPS on loopback too.
"""
from __future__ import annotations

from typing import Callable, TextIO

from nao_trainer.console.guard import is_loopback
from nao_trainer.console.server import Console
from nao_trainer.ports import CommandQueue


def open_console(commands: CommandQueue, bind: str, port: int, log: Callable[..., None], progress: TextIO | None,
                 insecure: bool = False, force_tls: bool = False) -> Console:
    """Start the console on ``bind:port``, log where it is (never the token) and print its link."""
    local = is_loopback(bind)
    tls = force_tls or (not local and not insecure)
    console = Console.start(commands, bind, port, log, tls=tls)
    log("console", url=console.url, bind=bind, tls=tls, fingerprint=console.fingerprint)
    if progress:
        if not local:
            clear = "" if tls else " in clear text (--console-insecure): the token can be read on the network, and"
            print(f"warning: the console listens on {bind}:{clear} anyone who can reach this address and has the "
                  "link can steer the session", file=progress, flush=True)
        if console.fingerprint:
            print(f"console certificate (self-signed) SHA-256 fingerprint: {console.fingerprint} - check that the "
                  "browser shows this before accepting it", file=progress, flush=True)
        where = "on this machine" if local else "on this machine or another one of this network"
        print(f"console: {console.link} (open it in a browser {where})", file=progress, flush=True)
    return console
