"""A throwaway PostgreSQL cluster for the tests: initdb in a temporary folder, the server listening on a
Unix socket in that folder only (no TCP), password authentication (scram) for every role. Run as an
unprivileged user when the tests run as root (the server refuses root). ``None`` when the server
binaries are absent (the tests skip with a notice; ``.ci/run`` installs the ``postgresql`` package)."""
from __future__ import annotations

import glob
import os
import secrets
import shutil
import subprocess
from pathlib import Path


def find_bin() -> Path | None:
    for cand in sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=lambda d: int(Path(d).parent.name)
                       if Path(d).parent.name.isdigit() else 0, reverse=True):
        if all(os.access(Path(cand) / b, os.X_OK) for b in ("initdb", "pg_ctl", "postgres")):
            return Path(cand)
    found = shutil.which("pg_ctl")
    return Path(found).parent if found and shutil.which("initdb") else None


class Cluster:
    def __init__(self, base: Path):
        self.bin = find_bin()
        self.base = base
        self.data = base / "data"
        self.socket_dir = base
        self.password = secrets.token_urlsafe(16)
        self.prefix: list[str] = []
        if os.geteuid() == 0:  # postgres refuses to run as root
            self.prefix = ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups"]

    def _run(self, *args: str) -> None:
        done = subprocess.run([*self.prefix, *args], capture_output=True, text=True, timeout=60)
        if done.returncode:
            raise RuntimeError(f"{args[0]} failed ({done.returncode}): {done.stderr.strip()}")

    def start(self) -> None:
        os.chmod(self.base, 0o755)
        if self.prefix:
            shutil.chown(self.base, "nobody")
        pwfile = self.base / "pw"
        pwfile.write_text(self.password + "\n")
        if self.prefix:
            shutil.chown(pwfile, "nobody")
        self._run(str(self.bin / "initdb"), "-D", str(self.data), "-U", "postgres", "-A", "scram-sha-256",
                  f"--pwfile={pwfile}", "--no-sync", "-E", "UTF8", "--locale=C")
        pwfile.unlink()
        self._run(str(self.bin / "pg_ctl"), "-D", str(self.data), "-l", str(self.base / "server.log"), "-w",
                  "-o", f"-k {self.socket_dir} -c listen_addresses= -F -c max_connections=60", "start")

    def stop(self) -> None:
        subprocess.run([*self.prefix, str(self.bin / "pg_ctl"), "-D", str(self.data), "-m", "immediate", "stop"],
                       capture_output=True, timeout=60)

    def url(self, db: str = "postgres", user: str = "postgres") -> str:
        return f"postgresql://{user}@/{db}?host={self.socket_dir}"


class Relay:
    """A Unix-socket relay in front of a cluster (a site's network path to the server): ``cut()`` drops every
    connection through it and refuses new ones (the network gone), ``restore()`` brings it back. The
    server itself keeps running: other connections (the administrator's) are not affected."""

    def __init__(self, cluster: Cluster, folder: Path, port: int = 5432):
        import threading

        self.folder = folder
        self.path = folder / f".s.PGSQL.{port}"
        self.target = str(cluster.socket_dir / f".s.PGSQL.{port}")
        self._lock = threading.Lock()
        self._open: list = []
        self._server = None

    def url(self, db: str, user: str | None = None) -> str:
        return f"postgresql://{user + '@' if user else ''}/{db}?host={self.folder}"

    def start(self) -> "Relay":
        import socket
        import threading

        self.folder.mkdir(parents=True, exist_ok=True)
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        server.bind(str(self.path))
        server.listen(16)
        self._server = server
        threading.Thread(target=self._accept, args=(server,), daemon=True).start()
        return self

    def _accept(self, server) -> None:
        import socket
        import threading

        while True:
            try:
                client, _ = server.accept()
            except OSError:
                return
            upstream = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            upstream.connect(self.target)
            with self._lock:
                self._open += [client, upstream]
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(src, dst) -> None:
        import socket

        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def cut(self) -> None:
        import socket

        if self._server is not None:
            self._server.close()
            self._server = None
        self.path.unlink(missing_ok=True)
        with self._lock:
            for s in self._open:
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                s.close()
            self._open.clear()

    def restore(self) -> None:
        self.start()
