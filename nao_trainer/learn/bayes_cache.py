"""Solved Bayes-adaptive plans cached on disk, keyed by prior, objective, horizon and commit turns.

``core.bayes.solve`` takes a few seconds for a 25-turn session with four levels; the table it
produces (one byte per decision state, 10.5 MB for 25 turns) is stored compressed (0.2-1.1 MB:
most states share their neighbours' action) as ``$XDG_CACHE_HOME/nao-trainer/bayes/<fingerprint>.npz``
(or in the folder given), written atomically (a failed write leaves no temporary file). A file is
used only when it is the plan of its key: its fingerprint (the inputs), its digest (the table and
value, so a torn or edited file is refused) and ``core.bayes.plan_problem`` (a sample of states
solved again from the table: its value, no better first level at the start and after one turn, the
posterior-best level at every last-turn state it reaches; about 0.2 s for 25 turns), so a crafted
table with the right fingerprint is refused too. Files are opened without blocking and without
following links, and only regular files are read (a FIFO in a table's place would hang a session).
Anything else is ignored with a warning and solved again (a cache that cannot be read or written
only costs time). A horizon whose solve would not fit in the memory available is refused before
anything is read or allocated (``core.bayes.PlanTooLarge``).

The cache is bounded: a live ``bayes`` policy solves a table for every prior and every participant's
carried counts, and ``evaluate --loo-bayes`` one per held-out user, so a lab laptop would otherwise
fill its disk over a study. A table used is touched; after each write the least recently used
tables go until the folder holds at most ``MAX_BYTES``.
"""
from __future__ import annotations

import hashlib
import io
import os
import stat
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


def memory_limit() -> int:
    """The memory a solve may take (bytes): what this machine has available now (``MemAvailable``),
    else half its physical memory."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // 2
    except (OSError, ValueError):  # pragma: no cover - not POSIX
        return 8 * 2**30


def digest(key: str, action: np.ndarray, value: float) -> str:
    """SHA-256 binding a table to its key and value (a torn or edited file no longer matches)."""
    h = hashlib.sha256(key.encode())
    h.update(np.ascontiguousarray(action, dtype=np.int8).tobytes())
    h.update(np.float64(value).astype("<f8").tobytes())
    return h.hexdigest()


def _open_regular(path: Path) -> "io.BufferedReader | None":
    """``path`` opened for reading without blocking and without following a link; None when it is not a
    regular file (a FIFO put in a table's place must not hang the session)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            return None
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def _load(path: Path, key: str, p: np.ndarray, w: np.ndarray, coef: np.ndarray, horizon: int, commit: int,
          terminal: np.ndarray | None = None) -> bayes.Plan | None:
    """The stored plan of ``key``, or None (with a warning when the file is there but not that plan)."""
    def ignore(why: str) -> None:
        print(f"nao-trainer: warning: ignoring plan cache {path}: {why}; solving again", file=sys.stderr)

    try:
        fh = _open_regular(path)
        if fh is None:
            ignore("not a regular file")
            return None
        with fh, np.load(fh, allow_pickle=False) as f:
            if str(f["fingerprint"]) != key:
                return None
            action = f["action"]
            value = float(f["value"])
            stored = str(f["digest"]) if "digest" in f.files else ""
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:  # e.g. torn, disk full
        print(f"nao-trainer: warning: ignoring unreadable plan cache {path}: {exc}", file=sys.stderr)
        return None
    if action.shape != (int(bayes.layer_sizes(horizon, p.shape[1])[:-1].sum()),) or action.dtype != np.int8:
        ignore("its table has the wrong shape")
        return None
    if np.any(action < 0) or np.any(action >= p.shape[1]):
        ignore("its table names levels that do not exist")
        return None
    if stored != digest(key, action, value):
        ignore("its digest does not match its table (torn, edited or written by an older nao-trainer)")
        return None
    plan = bayes.Plan(p, w / w.sum(), coef, horizon, commit, action, value, key, terminal)
    problem = bayes.plan_problem(plan)
    if problem is not None:
        ignore(f"it is not the plan of its inputs ({problem})")
        return None
    return plan


def solve_cached(p: np.ndarray, weights: np.ndarray, coef: np.ndarray, horizon: int, commit: int = 0,
                 folder: Path | None = None, max_bytes: int | None = None,
                 terminal: np.ndarray | None = None) -> bayes.Plan:
    """``core.bayes.solve``, reusing (and filling) the on-disk cache. ``max_bytes``: the memory a solve
    may take (default ``memory_limit()``); a larger one raises ``core.bayes.PlanTooLarge`` before
    anything is allocated."""
    p = np.asarray(p, dtype=float)
    w = np.asarray(weights, dtype=float)
    coef = np.asarray(coef, dtype=float)
    terminal = None if terminal is None else np.asarray(terminal, dtype=float)
    key = bayes.fingerprint(p, w, coef, horizon, commit, terminal)
    limit = memory_limit() if max_bytes is None else int(max_bytes)
    if bayes.solve_bytes(horizon, p.shape[1]) > limit:  # refused before reading a (huge) table or solving
        raise bayes.PlanTooLarge(horizon, p.shape[1], bayes.solve_bytes(horizon, p.shape[1]), limit)
    folder = Path(folder) if folder is not None else default_dir()
    path = folder / f"{key[:32]}.npz"
    if os.path.lexists(path):
        plan = _load(path, key, p, w, coef, horizon, commit, terminal)
        if plan is not None:
            _touch(path)
            return plan
    plan = bayes.solve(p, w, coef, horizon, commit, max_bytes=limit, terminal=terminal)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        _write(path, key, plan)
    except OSError as exc:
        print(f"nao-trainer: warning: cannot write plan cache {path}: {exc.strerror or exc}", file=sys.stderr)
        return plan
    prune(folder, MAX_BYTES, keep=path)
    return plan


def _write(path: Path, key: str, plan: bayes.Plan) -> None:
    """Write the table beside ``path`` and rename it over; the temporary file never outlives a failure."""
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}.npz")
    try:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, action=plan.action, value=np.float64(plan.value), fingerprint=np.str_(key),
                                digest=np.str_(digest(key, plan.action, plan.value)))
        if os.path.lexists(path) and not os.path.isfile(path):  # a FIFO or folder in the table's place
            if os.path.isdir(path) and not os.path.islink(path):
                raise OSError(f"a folder is in the place of the table: {path}")
            os.unlink(path)
        os.replace(tmp, path)
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass


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
