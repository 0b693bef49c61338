"""Keep Lab Streaming Layer discovery on this machine unless a study asks otherwise.

liblsl multicasts stream discovery beyond the machine by default. The project sets machine scope
before its first stream object: the Muse bridge (muselsl) runs on the same laptop.
``LSLAPICFG`` (a liblsl config file) wins when the environment sets it.

Machine scope finds streams through the known peer 127.0.0.1, asking each port of liblsl's port
range; multicast on the loopback interface often carries nothing (measured here). An outlet beyond
the range (liblsl's default: 32 ports) binds a random port and cannot be found, so the project's
config widens the range to ``PORT_RANGE`` (100 outlets on one machine were all found with it).
"""
from __future__ import annotations

import logging
import os
import tempfile

from nao_trainer.errors import ConfigError
from nao_trainer.files import write_text_atomic

log = logging.getLogger(__name__)

#: Ports liblsl may bind and that a machine-scope resolver asks (liblsl's default is 32).
PORT_RANGE = 128

MACHINE_SCOPE_CONFIG = """\
[multicast]
ResolveScope = machine
[ports]
IPv6 = disable
PortRange = %d
[lab]
KnownPeers = {127.0.0.1}
[log]
level = -3
""" % PORT_RANGE

SCOPES = ("machine", "link", "site", "organization", "global")
_configured: str | None = None


def configure_lsl(scope: str = "machine") -> str:
    """Set liblsl's discovery scope before any stream object exists; returns what applies.

    Call it before creating any StreamInfo, outlet or inlet. Calling it again is a no-op
    (liblsl reads its configuration once per process).
    """
    global _configured
    if scope not in SCOPES:
        raise ValueError(f"LSL scope must be one of {', '.join(SCOPES)}, got {scope!r}")
    if _configured is not None:
        if _configured not in (scope, "file:" + os.environ.get("LSLAPICFG", "")):
            log.warning("LSL scope %r requested, but %r already applies for this process", scope, _configured)
        return _configured
    cfg = os.environ.get("LSLAPICFG")
    if cfg:
        if not os.path.isfile(cfg):
            # liblsl would silently fall back to its default scope, which reaches beyond this machine
            raise ConfigError(f"LSLAPICFG={cfg}: no such file; liblsl would then discover streams beyond this "
                              "machine. Fix the path or unset LSLAPICFG (the project then uses machine scope)")
        if scope != "machine":
            log.warning("LSL scope %r requested, but the LSLAPICFG file %s decides the scope", scope, cfg)
        _configured = f"file:{cfg}"
        return _configured
    import pylsl

    text = MACHINE_SCOPE_CONFIG.replace("ResolveScope = machine", f"ResolveScope = {scope}")
    if scope != "machine":
        text = text.replace("KnownPeers = {127.0.0.1}\n", "")
    pylsl.set_config_content(text)
    _configured = scope
    return _configured


def config_file(scope: str = "machine") -> str:
    """A liblsl config file for another liblsl in this process or a child (e.g. LabRecorder's own copy).

    ``LSLAPICFG`` when the environment sets it; otherwise the project's config for ``scope``, written
    once to the temporary folder. Such a liblsl reads only a file, never ``pylsl.set_config_content``.
    """
    if scope not in SCOPES:
        raise ValueError(f"LSL scope must be one of {', '.join(SCOPES)}, got {scope!r}")
    cfg = os.environ.get("LSLAPICFG")
    if cfg:
        if not os.path.isfile(cfg):
            raise ConfigError(f"LSLAPICFG={cfg}: no such file; liblsl would then discover streams beyond this "
                              "machine. Fix the path or unset LSLAPICFG (the project then uses machine scope)")
        return cfg
    text = MACHINE_SCOPE_CONFIG.replace("ResolveScope = machine", f"ResolveScope = {scope}")
    if scope != "machine":
        text = text.replace("KnownPeers = {127.0.0.1}\n", "")
    path = os.path.join(tempfile.gettempdir(), f"nao-trainer-lsl-{scope}-{os.getuid()}.cfg")
    try:
        with open(path, encoding="utf-8") as fh:
            if fh.read() == text:
                return path
    except OSError:
        pass
    write_text_atomic(path, text)
    return path
