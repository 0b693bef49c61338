"""The session record: a folder per session that a killed process still leaves readable.

Layout of ``<out>/<pseudonym>_<YYYYmmdd-HHMMSS>[_n]/``:

* ``turns.csv``: one row per turn (also interrupted ones), appended, flushed and fsynced before
  the next turn starts, so every completed turn survives a crash or a kill;
* ``events.jsonl``: every state-machine event, robot failure, pause and reconnection, one JSON
  object per line, flushed per line;
* ``session.json``: configuration snapshot and hash, versions, seed, robot URL (never
  credentials), start/end time and exit status; written at start, rewritten atomically at the end;
* ``checkpoint.json``: after every recorded turn, what ``run --resume`` needs to continue exactly
  there (engine state, random generator states, the policy's learning state), written atomically.

A folder is never reused: an existing name gets a ``_2``, ``_3``... suffix.
"""
from __future__ import annotations

import csv
import datetime as dt
import errno
import io
import json
import os
import platform
import stat
import sys
import threading
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from nao_trainer import registry
from nao_trainer.core import task
from nao_trainer.tasks.base import default_task
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import WRITE_CAUSES, write_text_atomic

#: The default task's turns.csv columns (the sequence task's), declared once by the task (``Task.columns``); a
#: recorder writes its task's ``columns``.
TURN_COLUMNS: tuple[str, ...] = registry.load("task", registry.default("task")).columns


def row_problem(row: dict[str, str], task_: Any = None) -> str | None:
    """Why a completed row of turns.csv (as read: strings) is not one a session of ``task_`` (the default task,
    the sequence task, when None) writes, or None: its level is one of the task's, its scores are the task's for its level and
    outcome (an edited score is refused), and the task's own fields agree (``Task.row_problem``, optional)."""
    task_ = task_ if task_ is not None else default_task()
    try:
        level, score, signed = int(row["level"]), int(row["score"]), int(row["signed_score"])
    except (TypeError, ValueError, KeyError):
        return "level, score and signed_score must be integers"
    if level not in task_.levels:
        return f"level {level} is not one of the task's levels {', '.join(map(str, task_.levels))}"
    success = row["success"] == "True"
    if score != task_.score(level, success) or signed != task_.signed_score(level, success):
        outcome = "a success" if success else "a failure"
        return (f"score {score} / signed_score {signed} are not those of {outcome} at level {level} "
                f"({task_.score(level, success)} / {task_.signed_score(level, success)})")
    own = getattr(task_, "row_problem", None)
    return own(row) if own is not None else None


def open_no_follow(path: Path, mode: str) -> Any:
    """``open(path, mode)`` ("a", "r+b") refusing a symbolic link (O_NOFOLLOW) or a file that is not regular:
    a session appends only to its own files, never through a link planted in its folder."""
    flags = {"a": os.O_WRONLY | os.O_APPEND, "r+b": os.O_RDWR}[mode] | getattr(os, "O_NOFOLLOW", 0) | os.O_NONBLOCK
    fd = os.open(path, flags)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(errno.EINVAL, "not a regular file", str(path))
        os.set_blocking(fd, True)
        return os.fdopen(fd, mode, **({"newline": "", "encoding": "utf-8"} if "b" not in mode else {}))
    except BaseException:
        os.close(fd)
        raise


#: session.json's format and version (``data/own.py`` reads them and refuses a newer version).
FORMAT = {"format": "nao-trainer/session", "format_version": 1}
CHECKPOINT = "checkpoint.json"
CHECKPOINT_FORMAT = "nao-trainer/session-checkpoint-1"
VERSIONED = ("nao-trainer", "qi", "numpy", "pylsl", "transitions", "PyYAML", "scikit-learn")


def now_iso() -> str:
    return dt.datetime.now(dt.timezone.utc).isoformat(timespec="milliseconds")


def versions() -> dict[str, str]:
    """Versions of Python and the libraries a session depends on (for session.json)."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for name in VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def _fsync(f) -> None:
    f.flush()
    os.fsync(f.fileno())


_OUTPUT_FIX = "point session.output (or --out) at a folder you can write to"

def os_error_in(exc: BaseException | None) -> OSError | None:
    """The failed file write behind ``exc`` (itself, its cause or its context: a library may wrap it), or None.

    Only an ``OSError`` naming a file, with an errno of ``WRITE_CAUSES``: a port in use or a refused
    connection is not a write failure."""
    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, OSError) and exc.errno in WRITE_CAUSES and exc.filename is not None:
            return exc
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return None


def write_failure(exc: OSError, folder: Path | None) -> DataError:
    """One line for a failed write: which file, the cause (full disk, read-only, too many open files) and the fix."""
    cause, fix = WRITE_CAUSES.get(exc.errno or 0, (exc.strerror or type(exc).__name__, "check the disk"))
    where = exc.filename or folder or "the session folder"
    kept = f"; the completed turns are on disk: continue with nao-trainer run --resume {folder}" if folder else ""
    if folder and not (Path(folder) / CHECKPOINT).exists():  # failed before the first turn was recorded
        kept = f"; no turn was recorded (the session folder {folder} holds nothing to resume)"
    elif folder and str(where).endswith(CHECKPOINT):  # the last turn's row is written, its checkpoint is not
        kept = (f"; the completed turns are kept in {Path(folder) / 'turns.csv'}, but the checkpoint lags behind "
                "them: start a new session to continue")
    return DataError(f"{where}: cannot write ({cause}); {fix}{kept}")


def _warn(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def ensure_output_dir(out: Path) -> Path:
    """Create ``out`` (with parents) and check it is a writable folder; ``ConfigError`` in one line if not."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"session.output: cannot create the folder {out} ({exc.strerror}); {_OUTPUT_FIX}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise ConfigError(f"session.output: the folder {out} is not writable; {_OUTPUT_FIX}")
    return out


def create_session_dir(out: Path, pseudonym: str, when: dt.datetime | None = None) -> Path:
    """A new, empty folder ``<out>/<pseudonym>_<stamp>[_n]``; never an existing one.

    A folder that cannot be created is a one-line ``ConfigError`` naming it.
    """
    stamp = (when or dt.datetime.now()).strftime("%Y%m%d-%H%M%S")
    ensure_output_dir(out)
    for n in range(1, 1000):
        path = out / (f"{pseudonym}_{stamp}" + (f"_{n}" if n > 1 else ""))
        try:
            path.mkdir()  # atomic: fails if another process took the name
            return path
        except FileExistsError:
            continue
        except OSError as exc:
            raise ConfigError(f"session.output: cannot create the session folder {path} ({exc.strerror}); "
                              f"{_OUTPUT_FIX}") from None
    raise FileExistsError(f"{out}: too many sessions named {pseudonym}_{stamp}")


@dataclass
class SessionRecorder:
    """Writes one session folder. Events logged before ``open`` are kept and written by it."""

    out: Path
    pseudonym: str
    path: Path | None = None
    _pending: list[dict[str, Any]] = field(default_factory=list)
    _info: dict[str, Any] = field(default_factory=dict)
    _turns = None
    _writer = None
    _events = None
    rows: int = 0
    columns: tuple[str, ...] = TURN_COLUMNS  # the task's turns.csv columns (``tasks.base.Task.columns``)
    events_failed: OSError | None = None  # the first failed write of events.jsonl (later events are dropped)
    events_written: int = 0  # events written to events.jsonl by this process
    #: Where the warning of a failed events.jsonl write goes, at once (the terminal, also with --quiet).
    warn: Any = field(default=None, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock)  # events come from the console's thread too

    def open(self, info: dict[str, Any]) -> Path:
        """Create the folder and its files; ``info`` is the initial content of session.json."""
        self.path = create_session_dir(Path(self.out), self.pseudonym)
        self._info = dict(FORMAT, **info, status="running", started=now_iso())
        self._write_json()
        self._turns = open(self.path / "turns.csv", "w", newline="", encoding="utf-8")
        self._writer = csv.DictWriter(self._turns, fieldnames=self.columns, extrasaction="raise")
        self._writer.writeheader()
        _fsync(self._turns)
        self._events = open(self.path / "events.jsonl", "w", encoding="utf-8")
        for ev in self._pending:
            self._write_event(ev)
        self._pending.clear()
        return self.path

    def reopen(self, path: Path, resumption: dict[str, Any]) -> Path:
        """Continue an existing session folder (``run --resume``): files are appended to, never rewritten."""
        self.path = Path(path)
        self._info = json.loads((self.path / "session.json").read_text(encoding="utf-8"))
        self._info.setdefault("resumptions", []).append(dict(resumption, at=now_iso()))
        self._info.update(status="running")
        for key in ("ended", "exit_code", "error"):
            self._info.pop(key, None)
        torn = drop_torn_tail(self.path)  # a row cut by a kill: never append onto half a line
        torn_events = drop_torn_tail(self.path, "events.jsonl")  # an event cut by a kill or a full disk
        self.rows = sum(1 for _ in read_turns(self.path))
        self._write_json()
        self._turns = open_no_follow(self.path / "turns.csv", "a")
        self._writer = csv.DictWriter(self._turns, fieldnames=self.columns, extrasaction="raise")
        self._events = open_no_follow(self.path / "events.jsonl", "a")
        for ev in self._pending:
            self._write_event(ev)
        self._pending.clear()
        if torn:
            self.event("torn_row_dropped", bytes=torn, file="turns.csv")
        if torn_events:
            self.event("torn_event_dropped", bytes=torn_events, file="events.jsonl")
        return self.path

    def checkpoint(self, data: dict[str, Any]) -> None:
        """Write ``checkpoint.json`` atomically (the state after the last recorded turn)."""
        if self.path is not None:
            write_text_atomic(self.path / CHECKPOINT, json.dumps({"format": CHECKPOINT_FORMAT, **data}, default=str) + "\n")

    @property
    def is_open(self) -> bool:
        return self._turns is not None

    def event(self, name: str, **data: Any) -> None:
        """Log one event (kept in memory until the folder exists)."""
        ev = {"t": now_iso(), "mono": round(time.monotonic(), 4), "event": name, **data}
        if self._events is None:
            if self._turns is None and self.path is not None:
                return  # closed: nothing more is written
            self._pending.append(ev)
        else:
            self._write_event(ev)

    def _write_event(self, ev: dict[str, Any]) -> None:
        line = json.dumps(ev, default=str) + "\n"
        with self._lock:
            if self._events is not None and self.events_failed is None:
                try:
                    self._events.write(line)
                    self._events.flush()
                    self.events_written += 1
                except OSError as exc:  # the log must not end a session the turns can still be written in
                    self.events_failed = exc
                    (self.warn or _warn)(f"nao-trainer: warning: {self.events_lost()}")

    def events_lost(self) -> str:
        """One line on a failed events.jsonl write (empty when none failed): which file, why, how to fix, what is kept."""
        exc = self.events_failed
        if exc is None:
            return ""
        cause, fix = WRITE_CAUSES.get(exc.errno or 0, (exc.strerror or type(exc).__name__, "check the disk"))
        where = self.path / "events.jsonl" if self.path is not None else "events.jsonl"
        return (f"{where}: cannot write ({cause}): the events after the first {self.events_written} are lost, the "
                f"turns are kept in turns.csv; {fix}")

    def turn(self, row: dict[str, Any]) -> None:
        """Append one turn row and make it durable before returning."""
        clean = {k: ("" if row.get(k) is None else row.get(k)) for k in self.columns}
        unknown = set(row) - set(self.columns)
        if unknown:
            raise KeyError(f"unknown turns.csv columns: {sorted(unknown)}")
        try:
            self._writer.writerow(clean)
            _fsync(self._turns)
        except OSError as exc:  # name the file: the session's report says which write failed
            raise OSError(exc.errno, exc.strerror, str(self.path / "turns.csv")) from exc
        self.rows += 1

    def _write_json(self) -> None:
        write_text_atomic(self.path / "session.json", json.dumps(self._info, indent=2, default=str) + "\n")

    def _write_json_in_place(self) -> None:
        """session.json rewritten in the blocks it has (no new file): the last resort on a full disk."""
        with open(self.path / "session.json", "r+", encoding="utf-8") as f:
            f.write(json.dumps(self._info, indent=2, default=str) + "\n")
            f.truncate()
            f.flush()
            os.fsync(f.fileno())

    def close(self, status: str, exit_code: int, **info: Any) -> None:
        """Final session.json (atomic rewrite) and close every file. Safe to call twice; never raises
        ``OSError``: a session that failed to write already says why, and the clean-up must finish."""
        if self.path is None:
            return
        if self._turns is not None:
            self._info.update(info, status=status, exit_code=exit_code, ended=now_iso(), turns_recorded=self.rows)
            if self.events_failed is not None:
                self._info["events_lost"] = self.events_lost()
            for write in (self._write_json, self._write_json_in_place):
                try:
                    write()
                    break
                except OSError:
                    continue
            with self._lock:
                for f in (self._turns, self._events):
                    try:
                        f.close()
                    except OSError:
                        pass  # its buffer could not be flushed: the rows written before are fsynced
                self._turns = self._events = None


def read_turns(path: Path, complete_only: bool = False) -> list[dict[str, str]]:
    """The rows of a session's turns.csv (a helper for tests and analysis); ``complete_only``: without
    a torn last line (a row a kill cut short)."""
    with open(Path(path) / "turns.csv", newline="", encoding="utf-8") as f:
        text = f.read()
    if complete_only:
        text = text[:_complete_length(text)]
    return list(csv.DictReader(io.StringIO(text, newline="")))


def _complete_length(text: str) -> int:
    """Length of ``text`` up to its last line end (a complete file ends with one: csv writes ``\r\n``)."""
    return 0 if "\n" not in text else text.rindex("\n") + 1


def drop_torn_tail(folder: Path, name: str = "turns.csv") -> int:
    """Cut a torn last line off ``folder/name`` (fsynced); returns the bytes dropped (0: none)."""
    path = Path(folder) / name
    data = path.read_bytes()
    keep = 0 if b"\n" not in data else data.rindex(b"\n") + 1
    if keep == len(data):
        return 0
    with open_no_follow(path, "r+b") as f:
        f.truncate(keep)
        f.flush()
        os.fsync(f.fileno())
    return len(data) - keep


def read_events(path: Path) -> list[dict[str, Any]]:
    with open(Path(path) / "events.jsonl", encoding="utf-8") as f:
        return [json.loads(line) for line in f if line.strip()]
