"""``eeg/raw.csv`` of a session written by ``run``: the raw EEG samples, read in blocks.

A session writes ~90 bytes a sample (256 Hz: ~85 MB an hour); a file above :data:`MAX_RAW_BYTES`
(about 6 hours) is refused before it is read, and the rest is converted :data:`_RAW_BLOCK` lines at a
time, so memory stays near the samples' own size (a 1 GB file once took ~3 GB).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nao_trainer.errors import DataError

MAX_RAW_BYTES = 512_000_000
_RAW_BLOCK = 65_536  # raw.csv lines converted at once


def read_raw(path: Path, n_channels: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``eeg/raw.csv``: (samples ``(n, n_channels)``, stamps ``(n,)``, notes); a torn last line is dropped.

    Read in blocks of lines (memory near the samples' own size); above :data:`MAX_RAW_BYTES` refused.
    A row whose width is not ``1 + n_channels`` (stream.json's ``scalp_channels``) is a DataError.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror})") from None
    if size > MAX_RAW_BYTES:
        raise DataError(f"{path}: {size / 1e6:.0f} MB is more raw EEG than nao-trainer reads ({MAX_RAW_BYTES / 1e6:.0f} "
                        "MB, about 6 hours at 256 Hz): not written by a session, or corrupt")
    notes: list[str] = []
    blocks: list[np.ndarray] = []
    block: list[str] = []
    start = 2  # file line of block[0]
    prev: str | None = None
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            fh.readline()  # header
            for k, line in enumerate(fh, 2):
                if prev is not None:
                    block.append(prev)
                    if len(block) >= _RAW_BLOCK:
                        blocks.append(_raw_block(path, block, start, n_channels))
                        block, start = [], k
                prev = line
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not a text file ({exc.reason}; UTF-8 expected)") from None
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror})") from None
    if prev is not None:
        if prev.endswith("\n") and prev.count(",") == n_channels:
            block.append(prev)
        elif prev.strip():
            notes.append(f"{path.name}: torn last line dropped")
    if block:
        blocks.append(_raw_block(path, block, start, n_channels))
    if not blocks:
        return np.empty((0, n_channels)), np.empty(0), notes
    arr = np.concatenate(blocks) if len(blocks) > 1 else blocks[0]
    return arr[:, 1:], arr[:, 0], notes


def _raw_block(path: Path, lines: list[str], start: int, n_channels: int) -> np.ndarray:
    """Lines of raw.csv as a float array ``(n, 1 + n_channels)``; DataError naming the first bad line."""
    body = [ln for ln in lines if ln.strip()]
    try:
        arr = np.array([ln.split(",") for ln in body], dtype=float)
        if body and arr.ndim == 2 and arr.shape[1] == n_channels + 1:
            return arr
    except ValueError:
        pass
    if not body:
        return np.empty((0, n_channels + 1))
    bad = next((i for i, ln in enumerate(lines) if ln.strip() and (len(ln.split(",")) != n_channels + 1
                                                                    or not _numbers(ln))), 0)
    got = len(lines[bad].split(","))
    what = (f"{got - 1} channels where stream.json's scalp_channels names {n_channels}" if got != n_channels + 1
            else f"a value that is not a number ({lines[bad].strip()[:60]!r})")
    raise DataError(f"{path}:{start + bad}: expected the stamp and {n_channels} channel values, got {what}")


def _numbers(line: str) -> bool:
    try:
        [float(v) for v in line.split(",")]
        return True
    except ValueError:
        return False
