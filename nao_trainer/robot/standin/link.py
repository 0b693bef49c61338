"""The network between a client and the stand-in: latency, a frozen link, and NAOqi 2.9's tcps login.

The stand-in's qi server listens on a private loopback port; clients reach it through this relay
(stdlib asyncio, one thread). The relay can

* delay every chunk by half the configured round trip in each direction (``latency_s``);
* **freeze**: stop moving bytes both ways for a while, with every connection left open, as a
  dropped Wi-Fi does (libqi notices such a link only after ~60 s; see docs/how-to/robot.md). Bytes sent
  meanwhile are delivered when the link comes back, as TCP would retransmit them;
* serve ``tcps://`` with a self-signed certificate and check the login of libqi's first message
  (``login.check_first_message``), refusing a wrong one as libqi's own server does.
"""
from __future__ import annotations

import asyncio
import ssl
import threading
import time
from typing import Callable

from nao_trainer.robot.standin.login import Login, read_message, refuse

_CHUNK = 65536


class Link:
    """A relay ``host:port`` -> ``127.0.0.1:target_port``; ``start()``, ``freeze(s)``, ``stop()``."""

    def __init__(self, target_port: int, host: str = "127.0.0.1", port: int = 0,
                 tls: ssl.SSLContext | None = None, login: Login | None = None) -> None:
        self.target_port = target_port
        self.host, self.port = host, port
        self._tls, self._login = tls, login
        self.latency_s = 0.0
        self._frozen_until = 0.0
        self._lock = threading.Lock()
        self.refused_logins = 0
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="standin-link", daemon=True)
        self._server: asyncio.AbstractServer | None = None

    def start(self) -> "Link":
        self._thread.start()
        self._server = asyncio.run_coroutine_threadsafe(
            asyncio.start_server(self._client, self.host, self.port, ssl=self._tls), self._loop).result(10)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    # -- faults --------------------------------------------------------------------------------

    def freeze(self, seconds: float) -> None:
        """Stop every byte, both ways and on new connections too, for ``seconds`` (wall clock)."""
        with self._lock:
            self._frozen_until = max(self._frozen_until, time.monotonic() + float(seconds))

    def thaw(self) -> None:
        with self._lock:
            self._frozen_until = 0.0

    def frozen(self) -> bool:
        with self._lock:
            return time.monotonic() < self._frozen_until

    def _frozen_for(self) -> float:
        with self._lock:
            return max(0.0, self._frozen_until - time.monotonic())

    # -- relay ---------------------------------------------------------------------------------

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            first = b""
            if self._login is not None:
                first = await read_message(reader)
                problem = self._login.check_first_message(first)
                if problem is not None:
                    self.refused_logins += 1
                    writer.write(refuse(first, problem))
                    await writer.drain()
                    writer.close()  # libqi's server disconnects right after the error (Server::sendAuthError)
                    return
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.target_port)
        except (ConnectionError, asyncio.IncompleteReadError, ssl.SSLError, OSError):
            writer.close()
            return
        if first:
            up_writer.write(first)
        try:
            await asyncio.gather(self._pump(reader, up_writer), self._pump(up_reader, writer), return_exceptions=True)
        except asyncio.CancelledError:  # stop(): end normally, or asyncio's stream callback prints a traceback
            pass

    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

        async def deliver() -> None:
            while True:
                due, data = await queue.get()
                if not data:
                    break
                await self._hold(due)
                writer.write(data)
                await writer.drain()

        sender = asyncio.ensure_future(deliver())
        try:
            while data := await reader.read(_CHUNK):
                queue.put_nowait((time.monotonic() + self.latency_s / 2, data))
            queue.put_nowait((0.0, b""))
            await sender
        except (ConnectionError, ssl.SSLError, asyncio.CancelledError):
            pass
        finally:
            sender.cancel()
            try:
                writer.close()
            except RuntimeError:
                pass

    async def _hold(self, due: float) -> None:
        """Wait until ``due`` and until the link is not frozen."""
        while True:
            wait = max(due - time.monotonic(), self._frozen_for())
            if wait <= 0:
                return
            await asyncio.sleep(min(wait, 0.05))

    def stop(self) -> None:
        if self._server is None:
            return

        async def close() -> None:
            assert self._server is not None
            self._server.close()
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            # Let them end before the loop stops: a task left cancelled mid-way printed "Exception in callback ...
            # CancelledError" and "_GatheringFuture exception was never retrieved" on the operator's terminal.
            await asyncio.gather(*tasks, return_exceptions=True)

        try:
            asyncio.run_coroutine_threadsafe(close(), self._loop).result(5)
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5)
            self._server = None


def after_call(action: Callable[[], None]) -> Callable[[], None]:
    """``action`` run on a helper thread a moment later, so the reply of the call that armed it goes out first."""
    def run() -> None:
        threading.Timer(0.02, action).start()
    return run
