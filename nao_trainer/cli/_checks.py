"""Checks the commands make before long work, so a missing library or an unusable folder fails first."""
from __future__ import annotations

import importlib.util
from pathlib import Path

from nao_trainer.errors import ConfigError, DataError


def require_matplotlib(wanted: bool, flag: str = "--no-plots") -> None:
    """ConfigError with the install hint when figures are ``wanted`` and matplotlib is missing."""
    if wanted and importlib.util.find_spec("matplotlib") is None:
        raise ConfigError(f"figures need matplotlib: pip install 'nao-trainer[plots]', or add {flag}")


def make_output_dir(path: str | Path) -> Path:
    """Create the ``--out`` folder (and its parents); DataError naming it when that is not possible."""
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"{path}: cannot create the output folder ({exc.strerror}); choose another --out") from None
    return Path(path)
