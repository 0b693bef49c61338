"""The live monitor's files in ``<session>/eeg/``: append-only CSVs flushed as written, and ``stream.json``.

``events.csv``, ``windows.csv``, ``phases.csv``, ``gaps.csv`` and ``raw.csv`` are written through
:class:`SessionFiles` by the monitor's reader thread and by the session; nothing is lost on a crash.
"""
from __future__ import annotations

import csv
import threading
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.files import write_json_atomic


class CsvLog:
    """An append-only CSV file that is flushed after every write (nothing lost on a crash)."""

    def __init__(self, path: Path, header: list[str]) -> None:
        self.path = path
        new = not path.exists()
        self._fh = open(path, "a", newline="", encoding="utf-8")
        self._w = csv.writer(self._fh)
        if new:
            self._w.writerow(header)
            self._fh.flush()

    def write(self, rows: list[list[Any]], flush: bool = True) -> None:
        try:
            self._w.writerows(rows)
            if flush:
                self._fh.flush()
        except OSError as exc:  # name the file: a full disk fails in write(), which names none
            raise OSError(exc.errno, exc.strerror, str(self.path)) from exc

    def raw_file(self):
        return self._fh

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.flush()
            self._fh.close()


def fmt(v: float | None) -> str:
    """Full precision (``repr``): the offline re-analysis (``data/own.py``) checks its values against these."""
    return "" if v is None or not np.isfinite(v) else repr(float(v))


class SessionFiles:
    """The monitor's files in ``<session>/eeg/`` (no files when there is no session folder)."""

    def __init__(self, session_dir: Path | None) -> None:
        self.dir = None if session_dir is None else Path(session_dir) / "eeg"
        self._logs: dict[str, CsvLog] = {}
        self.closed = False
        self.lock = threading.Lock()  # the reader thread and the session both write
        if self.dir is not None:
            self.dir.mkdir(parents=True, exist_ok=True)

    def log(self, name: str, header: list[str]) -> CsvLog | None:
        if self.dir is None or self.closed:  # after close(): nothing more is written
            return None
        with self.lock:
            if name not in self._logs:
                self._logs[name] = CsvLog(self.dir / name, header)
            return self._logs[name]

    def write(self, name: str, header: list[str], rows: list[list[Any]], flush: bool = True) -> None:
        log_ = self.log(name, header)
        if log_ is not None:
            with self.lock:
                if not self.closed:
                    log_.write(rows, flush)

    def write_json(self, name: str, data: dict) -> None:
        if self.dir is not None:
            write_json_atomic(self.dir / name, data)

    def close(self) -> None:
        with self.lock:
            self.closed = True
            for log_ in self._logs.values():
                log_.close()


EVENTS_HEADER = ["lsl_time", "event", "detail"]
WINDOWS_HEADER = ["turn", "phase", "t_end", "index_raw", "index_smoothed", "engagement", "clean_fraction", "reason"]
PHASES_HEADER = ["turn", "phase", "t_begin", "t_end", "engagement", "engagement_index", "eeg_quality",
                 "n_windows", "lost_s", "reason", "last_sample", "monitor_started"]
#: One row per run of the engagement estimator (a monitor attaching a stream): its first sample and the
#: monitor it belongs to (a resumed session appends a new monitor), so an offline replay restarts both alike.
SEGMENTS_HEADER = ["first_sample", "monitor_started"]
GAPS_HEADER = ["start", "end", "duration_s", "kind"]
