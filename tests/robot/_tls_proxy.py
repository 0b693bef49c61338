"""A TLS front for a plain qi server, as NAOqi 2.9 listens (``tcps://``), on loopback.

The qi Python binding cannot listen on ``tcps://``, so tests put this proxy (stdlib asyncio + ssl,
a self-signed certificate made at test time) in front of the stand-in. It keeps what it saw: the
bytes on the wire (encrypted) and the decrypted bytes from the client, so a test can check both
that the login was sent and that it never crossed the wire in the clear.
"""
from __future__ import annotations

import asyncio
import ssl
import threading
from pathlib import Path

from nao_trainer.robot.standin.tls import self_signed_certificate  # the stand-in's own (one copy)


class TlsProxy:
    """``tcps://127.0.0.1:<port>`` -> ``tcp://127.0.0.1:<target_port>``; ``start()`` / ``stop()``."""

    def __init__(self, target_port: int, folder: Path) -> None:
        self.target_port = target_port
        cert, key = self_signed_certificate(folder)
        self._context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        self._context.load_cert_chain(cert, key)
        self.wire = bytearray()  # encrypted bytes from the client
        self.plain = bytearray()  # the same after decryption
        self.connections = 0
        self.handshakes = 0
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="tls-proxy", daemon=True)
        self.port = 0

    @property
    def url(self) -> str:
        return f"tcps://127.0.0.1:{self.port}"

    def start(self) -> "TlsProxy":
        self._thread.start()
        self._tls_server = asyncio.run_coroutine_threadsafe(
            asyncio.start_server(self._tls_client, "127.0.0.1", 0, ssl=self._context), self._loop).result(5)
        tls_port = self._tls_server.sockets[0].getsockname()[1]
        # A plain tap in front of the TLS server records the bytes as they cross the wire.
        self._tap = asyncio.run_coroutine_threadsafe(
            asyncio.start_server(lambda r, w: self._tap_client(r, w, tls_port), "127.0.0.1", 0), self._loop).result(5)
        self.port = self._tap.sockets[0].getsockname()[1]
        return self

    def stop(self) -> None:
        async def close() -> None:
            for server in (self._tap, self._tls_server):
                server.close()
            for task in [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]:
                task.cancel()

        asyncio.run_coroutine_threadsafe(close(), self._loop).result(5)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)

    async def _tap_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, tls_port: int) -> None:
        self.connections += 1
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", tls_port)
        await self._pump_both(reader, writer, up_reader, up_writer, self.wire)

    async def _tls_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.handshakes += 1
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.target_port)
        await self._pump_both(reader, writer, up_reader, up_writer, self.plain)

    async def _pump_both(self, reader, writer, up_reader, up_writer, log: bytearray) -> None:
        await asyncio.gather(self._pump(reader, up_writer, log), self._pump(up_reader, writer, None),
                             return_exceptions=True)

    @staticmethod
    async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, log: bytearray | None) -> None:
        try:
            while data := await reader.read(65536):
                if log is not None:
                    log.extend(data)
                writer.write(data)
                await writer.drain()
        except (ConnectionError, ssl.SSLError, asyncio.CancelledError):
            pass
        finally:
            try:
                writer.close()
            except RuntimeError:
                pass
