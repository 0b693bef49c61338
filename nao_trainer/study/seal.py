"""The study key: seals the allocation (concealment) and the registry's contents (tamper evidence).

At ``study init`` a random key is drawn (``os.urandom`` through ``cryptography``'s Fernet) and written to
the key store, **outside** the study folder: ``$NAO_TRAINER_KEYS/<study id>.key`` (default
``~/.local/share/nao-trainer/keys``), mode 0600. The study folder holds only ciphertext:

* each allocation slot's arm, encrypted and padded to one length (the ciphertext's size must not tell a
  short arm name from a long one);
* an HMAC of the whole registry, so an edit with the ``sqlite3`` shell (a participant removed, the
  allocation position moved back) is refused like an edited file.

``study next`` unseals one participant's arm to configure the session, and shows it nowhere while the
protocol is blinded; ``study unblind`` (the statistician, logged) reveals them all.
"""
from __future__ import annotations

import hashlib
import hmac
import json
import os
from pathlib import Path
from typing import Any

from nao_trainer.errors import ConfigError, DataError

KEY_ENV = "NAO_TRAINER_KEYS"
_PAD = 64  # arm names are at most this long once padded (protocol names are short labels)


def _fernet():
    try:
        from cryptography import fernet
    except ImportError:
        raise ConfigError("the study registry seals its allocation with the cryptography package: "
                          "pip install -e '.[study]'") from None
    return fernet


def key_dir() -> Path:
    given = os.environ.get(KEY_ENV)
    return Path(given).expanduser() if given else Path.home() / ".local" / "share" / "nao-trainer" / "keys"


def key_path(study_id: str) -> Path:
    return key_dir() / f"{study_id}.key"


def new_key(study_id: str) -> bytes:
    """Draw and store the key of a new study (never overwrites one)."""
    key = _fernet().Fernet.generate_key()
    path = key_path(study_id)
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(key)
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot store the study key ({exc.strerror}); free space or set {KEY_ENV} "
                          "to a writable folder outside the study folder") from None
    return key


def load_key(study_id: str, root: Path) -> bytes:
    path = key_path(study_id)
    try:
        key = path.read_bytes().strip()
    except OSError:
        raise DataError(f"{root}: the study key {path} is missing; this study was created on another machine or "
                        f"account: copy its key there (or set {KEY_ENV} to the folder holding it)") from None
    if len(key) != 44:
        raise DataError(f"{path}: not a study key (corrupt); restore it from its backup")
    return key


def seal(key: bytes, text: str) -> str:
    raw = text.encode()
    if len(raw) > _PAD:
        raise ConfigError(f"{text!r}: longer than {_PAD} bytes, cannot be sealed")
    return _fernet().Fernet(key).encrypt(raw.ljust(_PAD, b"\0")).decode()


def unseal(key: bytes, token: str, where: Path) -> str:
    fernet = _fernet()
    try:
        return fernet.Fernet(key).decrypt(token.encode()).rstrip(b"\0").decode()
    except (fernet.InvalidToken, ValueError, TypeError):
        raise DataError(f"{where}: a sealed allocation slot does not open with this study's key: edited or "
                        "corrupt; restore the study folder from a backup") from None


def mac(key: bytes, content: Any) -> str:
    """HMAC-SHA256 of a JSON-able value (canonical form)."""
    text = json.dumps(content, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hmac.new(key, text.encode(), hashlib.sha256).hexdigest()
