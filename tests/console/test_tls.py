"""The console's self-signed certificate (issue 18 item 7)."""
from __future__ import annotations

import shutil
import ssl

import pytest

from nao_trainer.console.tls import fingerprint, make_certificate
from nao_trainer.errors import ConfigError


@pytest.mark.skipif(shutil.which("openssl") is None, reason="no openssl command: the console's TLS was not tested")
def test_a_certificate_names_the_console_addresses_and_its_fingerprint_is_what_browsers_show():
    cert = make_certificate(["127.0.0.1", "::1", "localhost", "lab-pc", "192.0.2.7"])
    try:
        pem = cert.certfile.read_text()
        info = ssl._ssl._test_decode_cert(str(cert.certfile))  # the standard library's own certificate parser
        assert set(info["subjectAltName"]) >= {("IP Address", "127.0.0.1"), ("IP Address", "192.0.2.7"),
                                                ("DNS", "localhost"), ("DNS", "lab-pc")}
        assert cert.fingerprint == fingerprint(pem) and len(cert.fingerprint) == 95
        assert (cert.folder.stat().st_mode & 0o077) == 0  # the key's folder is private
    finally:
        cert.remove()
    assert not cert.folder.exists()


def test_without_openssl_the_console_refuses_in_one_line_with_the_fix(tmp_path):
    with pytest.raises(ConfigError, match="--console-insecure") as err:
        make_certificate(["127.0.0.1"], openssl=str(tmp_path / "no-openssl"))
    assert "\n" not in str(err.value)


def test_a_certificate_the_server_cannot_load_is_one_line_and_frees_the_port(monkeypatch, capfd):
    # A server that fails in its thread once printed the thread's traceback and raised a bare RuntimeError.
    import socket

    from nao_trainer.console import server, tls
    from nao_trainer.ports import CommandQueue

    def unloadable(names, openssl=None):
        folder = tls.Path(tls.tempfile.mkdtemp(prefix="nao-console-tls-"))
        (folder / "cert.pem").write_text("not a certificate\n")
        (folder / "key.pem").write_text("not a key\n")
        return tls.Certificate(folder, folder / "cert.pem", folder / "key.pem", "AB:CD")

    monkeypatch.setattr(tls, "make_certificate", unloadable)
    with pytest.raises(ConfigError, match=r"^console: the server on 127\.0\.0\.1:\d+ did not start \(SSLError") as err:
        server.Console.start(CommandQueue(), "127.0.0.1", 0, tls=True)
    assert "\n" not in str(err.value) and "Traceback" not in capfd.readouterr().err
    port = int(str(err.value).split(":")[2].split()[0])
    with socket.socket() as s:  # the listening socket was closed: its port can be bound again
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
