"""A self-signed certificate made on the spot, for a console reachable from other machines.

The token and the cookie must not cross a lab network in clear. A certificate authority is not
available in a lab, so the console makes a self-signed certificate (EC P-256, valid 2 days, the
addresses and names it was started for as subjectAltName) with the ``openssl`` command, and prints
its SHA-256 fingerprint: the supervisor compares it with what the browser shows before accepting
it. The key is written to a private temporary folder, loaded by the server and deleted at once.
"""
from __future__ import annotations

import hashlib
import ipaddress
import shutil
import ssl
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

from nao_trainer.errors import ConfigError


@dataclass(frozen=True)
class Certificate:
    """A certificate and its key as files (in ``folder``, removed by ``remove``), and its fingerprint."""

    folder: Path
    certfile: Path
    keyfile: Path
    fingerprint: str  # SHA-256 of the DER certificate, "AB:CD:..." as browsers show it

    def remove(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def fingerprint(pem: str) -> str:
    digest = hashlib.sha256(ssl.PEM_cert_to_DER_cert(pem)).hexdigest().upper()
    return ":".join(digest[i:i + 2] for i in range(0, len(digest), 2))


def _san(names: Iterable[str]) -> str:
    out = []
    for name in dict.fromkeys(n.strip("[]") for n in names if n):
        try:
            out.append(f"IP:{ipaddress.ip_address(name)}")
        except ValueError:
            out.append(f"DNS:{name}")
    return ",".join(out)


def make_certificate(names: Iterable[str], openssl: str | None = None) -> Certificate:
    """A new self-signed certificate for ``names`` (addresses and host names); ConfigError without openssl."""
    openssl = openssl or shutil.which("openssl")
    fix = "install openssl (apt-get install openssl), or accept clear text with --console-insecure"
    if openssl is None:
        raise ConfigError(f"console: serving beyond this machine needs TLS, made with the openssl command, "
                          f"which is not installed; {fix}")
    folder = Path(tempfile.mkdtemp(prefix="nao-console-tls-"))  # mode 0700
    cert, key = folder / "cert.pem", folder / "key.pem"
    cmd = [openssl, "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
           "-days", "2", "-subj", "/CN=nao-trainer console", "-addext", f"subjectAltName={_san(names)}",
           "-keyout", str(key), "-out", str(cert)]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as exc:
        shutil.rmtree(folder, ignore_errors=True)
        raise ConfigError(f"console: making a TLS certificate failed ({exc}); {fix}") from None
    if done.returncode != 0 or not cert.exists():
        shutil.rmtree(folder, ignore_errors=True)
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise ConfigError(f"console: openssl could not make a TLS certificate ({last}); {fix}")
    return Certificate(folder, cert, key, fingerprint(cert.read_text()))
