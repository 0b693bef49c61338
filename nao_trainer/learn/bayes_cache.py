"""Solved Bayes-adaptive plans cached on disk, keyed by prior, objective, horizon and commit turns.

``core.bayes.solve`` takes a few seconds for a 25-turn session with four levels; the table it
produces (one byte per decision state, 10.5 MB for 25 turns) is stored compressed (0.2-1.1 MB:
most states share their neighbours' action) as ``$XDG_CACHE_HOME/nao-trainer/bayes/<fingerprint>.npz``
(or in the folder given), written atomically. A file whose stored fingerprint, shape or inputs do
not match is ignored and replaced (a cache that cannot be read or written only costs time, with a
warning).

The cache is bounded: a live ``bayes`` policy solves a table for every prior and every participant's
carried counts, and ``evaluate --loo-bayes`` one per held-out user, so a lab laptop would otherwise
fill its disk over a study. A table used is touched; after each write the least recently used
tables go until the folder holds at most ``MAX_BYTES``.
"""
from __future__ import annotations

import os
import sys
import zipfile
import zlib
from pathlib import Path

import numpy as np

from nao_trainer.core import bayes

#: The cache folder's size bound (bytes): 240 to 1,200 compressed 25-turn tables (0.2-1.1 MB each).
MAX_BYTES = 256 * 2**20


def default_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "nao-trainer" / "bayes"


def _load(path: Path, key: str, p: np.ndarray, w: np.ndarray, coef: np.ndarray, horizon: int, commit: int,
          terminal: np.ndarray | None = None) -> bayes.Plan | None:
    try:
        with np.load(path, allow_pickle=False) as f:
            if str(f["fingerprint"]) != key:
                return None
            action = f["action"]
            value = float(f["value"])
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:  # e.g. torn, disk full
        print(f"nao-trainer: warning: ignoring unreadable plan cache {path}: {exc}", file=sys.stderr)
        return None
    if action.shape != (int(bayes.layer_sizes(horizon, p.shape[1])[:-1].sum()),) or action.dtype != np.int8:
        return None
    if np.any(action < 0) or np.any(action >= p.shape[1]):
        return None
    return bayes.Plan(p, w / w.sum(), coef, horizon, commit, action, value, key, terminal)


def solve_cached(p: np.ndarray, weights: np.ndarray, coef: np.ndarray, horizon: int, commit: int = 0,
                 folder: Path | None = None, terminal: np.ndarray | None = None) -> bayes.Plan:
    """``core.bayes.solve``, reusing (and filling) the on-disk cache."""
    p = np.asarray(p, dtype=float)
    w = np.asarray(weights, dtype=float)
    coef = np.asarray(coef, dtype=float)
    terminal = None if terminal is None else np.asarray(terminal, dtype=float)
    key = bayes.fingerprint(p, w, coef, horizon, commit, terminal)
    folder = Path(folder) if folder is not None else default_dir()
    path = folder / f"{key[:32]}.npz"
    if path.exists():
        plan = _load(path, key, p, w, coef, horizon, commit, terminal)
        if plan is not None:
            _touch(path)
            return plan
    plan = bayes.solve(p, w, coef, horizon, commit, terminal=terminal)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}.npz")
        np.savez_compressed(tmp, action=plan.action, value=np.float64(plan.value), fingerprint=np.str_(key))
        os.replace(tmp, path)
    except OSError as exc:
        print(f"nao-trainer: warning: cannot write plan cache {path}: {exc.strerror}", file=sys.stderr)
        return plan
    prune(folder, MAX_BYTES, keep=path)
    return plan


def _touch(path: Path) -> None:
    try:
        os.utime(path)
    except OSError:  # a read-only cache still serves its tables
        pass


def prune(folder: Path, max_bytes: int, keep: Path | None = None) -> list[Path]:
    """Remove the least recently used tables (``*.npz``) of ``folder`` until it holds at most
    ``max_bytes``; ``keep`` (the table just written) and tables being written (``.*``) stay. Two
    processes pruning at once may remove more than needed: a cache, solved again when needed.
    Returns the files removed."""
    entries = []
    for f in Path(folder).glob("*.npz"):
        if f.name.startswith("."):  # another process's table being written
            continue
        try:
            st = f.stat()
        except OSError:  # removed meanwhile by another process
            continue
        entries.append((st.st_mtime, f.name, st.st_size, f))
    total = sum(e[2] for e in entries)
    removed = []
    for _, _, size, f in sorted(entries):
        if total <= max_bytes:
            break
        if f == keep:
            continue
        try:
            f.unlink()
        except OSError:
            continue
        total -= size
        removed.append(f)
    return removed
