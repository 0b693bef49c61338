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
