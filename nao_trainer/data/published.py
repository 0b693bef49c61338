"""Readers for the published sequence-learning dataset layout (Tsiakas et al., ``sequence-learning-dataset``).

A session folder ``<root>/user_<id>/session_<k>/`` holds ``logfile`` (one line per turn), ``state_EEG``
(the turn's MDP state and the names of its two recordings) and Muse recordings: raw
``robot_<turn>``/``user_<turn>``/``intro`` (every Muse message, raw ``eeg`` included) and/or
``EEG/bands_robot_<turn>``/``EEG/bands_user_<turn>`` (the same without ``eeg`` lines). Recording lines are
``prefix v1 v2 v3 v4`` (channels TP9, AF7, AF8, TP10; no timestamps). Format facts:
``../shared/data/sequence-learning/README.md``.

Every reader raises :class:`nao_trainer.errors.DataError` naming the file and line on malformed input.
Parsing goes through ``str.split`` and one numpy conversion per prefix, so a whole session reads fast.
"""
from __future__ import annotations

import ast
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nao_trainer.errors import DataError
from nao_trainer.files import read_text


#: Values per line for the Muse message prefixes of the published recordings. ``c`` (concentration)
#: has one value; the band files pad it to four (``c v 0 0 0``): only the first is kept.
PREFIX_WIDTHS: dict[str, int] = {
    "eeg": 4,
    **{p: 4 for p in ("a", "b", "d", "g", "t", "Aa", "Ab", "Ad", "Ag", "At", "as", "bs", "ds", "gs", "ts", "h")},
    "c": 1,
}
#: Relative band-power prefixes (10 Hz): alpha, beta, delta, gamma, theta.
RELATIVE_BANDS: tuple[str, ...] = ("a", "b", "d", "g", "t")

# ----------------------------------------------------------------------------------------------
# Session discovery
# ----------------------------------------------------------------------------------------------

_NUM = re.compile(r"(\d+)")


def _natural_key(text: str) -> list:
    return [int(p) if p.isdigit() else p for p in _NUM.split(text)]


def is_session_dir(path: Path) -> bool:
    """A folder with a ``logfile`` or ``state_EEG``: one session of the published layout."""
    return path.is_dir() and ((path / "logfile").is_file() or (path / "state_EEG").is_file())


def find_sessions(root: Path) -> list[Path]:
    """Session folders under ``root`` (itself a session, a dataset root, or a folder holding ``clean_data``).

    Sorted naturally by user then session (``user_2`` before ``user_10``). Raises DataError when none.
    """
    root = Path(root)
    if not root.exists():
        raise DataError(f"{root}: no such folder (give a session folder or a dataset root with user_<id>/session_<k>)")
    if is_session_dir(root):
        return [root]
    found: set[Path] = set()
    for pattern in ("user_*/session_*", "clean_data/user_*/session_*", "*/session_*"):
        found.update(p for p in root.glob(pattern) if is_session_dir(p))
    if not found:
        raise DataError(
            f"{root}: no sessions found (expected user_<id>/session_<k>/ folders with a logfile or state_EEG)"
        )
    return sorted(found, key=lambda p: (_natural_key(p.parent.name), _natural_key(p.name)))


def session_id(session_dir: Path) -> str:
    """The dataset's session id ``user_<id>/session_<k>`` (the ``ID`` column of the derived tables)."""
    p = Path(os.path.abspath(session_dir))  # "." works too; symlinks keep their names
    return f"{p.parent.name}/{p.name}"


# ----------------------------------------------------------------------------------------------
# logfile and state_EEG
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LogRow:
    """One turn of ``logfile``. ``rf`` is the feedback spoken before this turn's sequence."""

    turn: int
    length: int
    rf: int
    score: int
    success: int
    reaction_time: float
    completion_time: float
    sequence: tuple[str, ...]
    response: tuple[str, ...]


@dataclass(frozen=True)
class StateRow:
    """One turn of ``state_EEG``: the MDP state (length, rf, previous_score) and its recordings' names."""

    length: int
    rf: int
    previous_score: int
    robot_file: str
    user_file: str


_LOG_LINE = re.compile(r"^\s*((?:\S+\s+){6}\S+)\s*(\[.*?\])\s*(\[.*?\])\s*$")


#: Largest published file read (bytes): a raw recording is a few MB; a larger file is refused before reading.
MAX_FILE_BYTES = 256_000_000


def _read_text(path: Path) -> str:
    return read_text(path, DataError, max_bytes=MAX_FILE_BYTES)


#: Largest whole number a logfile / state_EEG field may hold (turns, lengths, scores are small).
MAX_FIELD = 1_000_000
#: A recording name in state_EEG: a file name inside the session folder (``robot_3``), never a path.
_RECORDING_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}")


def _as_int(text: str, path: Path, lineno: int, what: str) -> int:
    try:
        value = float(text)
    except ValueError:
        raise DataError(f"{path} line {lineno}: {what} must be a number, got {text[:40]!r}") from None
    if not np.isfinite(value) or abs(value) > MAX_FIELD:
        raise DataError(f"{path} line {lineno}: {what} must be a whole number within +-{MAX_FIELD}, got {text[:40]!r}")
    if value != int(value):
        raise DataError(f"{path} line {lineno}: {what} must be a whole number, got {text!r}")
    return int(value)


def _as_float(text: str, path: Path, lineno: int, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise DataError(f"{path} line {lineno}: {what} must be a number, got {text[:40]!r}") from None
    if not np.isfinite(value):
        raise DataError(f"{path} line {lineno}: {what} must be a finite number, got {text[:40]!r}")
    return value


def _letters(text: str, path: Path, lineno: int, what: str) -> tuple[str, ...]:
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        raise DataError(f"{path} line {lineno}: {what} must be a Python list of letters, got {text!r}") from None
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise DataError(f"{path} line {lineno}: {what} must be a list of letters, got {text!r}")
    return tuple(value)


def read_logfile(path: Path) -> list[LogRow]:
    """Parse a ``logfile``: ``turn length rf score success reaction_time completion_time [seq] [response]``."""
    path = Path(path)
    rows: list[LogRow] = []
    for lineno, line in enumerate(_read_text(path).splitlines(), 1):
        if not line.strip():
            continue
        m = _LOG_LINE.match(line)
        if not m:
            raise DataError(
                f"{path} line {lineno}: expected 7 numbers and two lists "
                f"(turn length rf score success reaction_time completion_time [sequence] [response]), got {line!r}"
            )
        f = m.group(1).split()
        names = ("turn", "length", "rf", "score", "success")
        ints = [_as_int(v, path, lineno, n) for v, n in zip(f[:5], names)]
        rows.append(
            LogRow(
                *ints,
                reaction_time=_as_float(f[5], path, lineno, "reaction_time"),
                completion_time=_as_float(f[6], path, lineno, "completion_time"),
                sequence=_letters(m.group(2), path, lineno, "sequence"),
                response=_letters(m.group(3), path, lineno, "response"),
            )
        )
    return rows


def read_state_eeg(path: Path) -> list[StateRow]:
    """Parse ``state_EEG``: ``length rf previous_score robot_<turn> user_<turn>`` per turn."""
    path = Path(path)
    rows: list[StateRow] = []
    for lineno, line in enumerate(_read_text(path).splitlines(), 1):
        f = line.split()
        if not f:
            continue
        if len(f) != 5:
            raise DataError(
                f"{path} line {lineno}: expected 5 fields (length rf previous_score robot_N user_N), got {len(f)}"
            )
        nums = [_as_int(v, path, lineno, n) for v, n in zip(f[:3], ("length", "rf", "previous_score"))]
        for name in f[3:]:  # opened inside the session folder: a path leaving it is refused, never followed
            if not _RECORDING_NAME.fullmatch(name) or ".." in name:
                raise DataError(f"{path} line {lineno}: recording name {name[:60]!r} must be a file name in the "
                                "session folder (like robot_3), not a path")
        rows.append(StateRow(*nums, robot_file=f[3], user_file=f[4]))
    return rows


# ----------------------------------------------------------------------------------------------
# Muse recordings
# ----------------------------------------------------------------------------------------------


@dataclass
class Recording:
    """One Muse recording: per message prefix, the values in file order.

    ``data["eeg"]`` is ``(n, 4)`` raw microvolts (~220 Hz), ``data["a"]`` etc. ``(n, 4)`` relative band
    powers (10 Hz), ``data["h"]`` ``(n, 4)`` contact (1 good, 2 ok, 4 bad), ``data["c"]`` ``(n,)``.
    """

    path: Path
    data: dict[str, np.ndarray] = field(default_factory=dict)

    def __getitem__(self, prefix: str) -> np.ndarray:
        try:
            return self.data[prefix]
        except KeyError:
            raise DataError(f"{self.path}: no '{prefix}' lines") from None

    def __contains__(self, prefix: str) -> bool:
        return prefix in self.data and len(self.data[prefix]) > 0

    @property
    def has_raw_eeg(self) -> bool:
        return "eeg" in self

    def bands(self, prefixes: tuple[str, ...] = ("t", "a", "b")) -> np.ndarray:
        """Relative band powers ``(n, len(prefixes), 4)`` aligned sample by sample.

        The published files sometimes hold one line more of some prefixes than of others: the rows
        are cut to the shortest prefix (the dataset README documents that off-by-one).
        """
        arrays = [self[p] for p in prefixes]
        n = min(len(a) for a in arrays)
        return np.stack([a[:n] for a in arrays], axis=1)


def _bad_line(path: Path, lines: list[str], prefix: str, width: int | None) -> DataError:
    """Find the first malformed line of ``prefix`` (the slow path, only taken on error)."""
    for lineno, line in enumerate(lines, 1):
        f = line.split()
        if not f or f[0] != prefix:
            continue
        values = f[1:]
        if width is not None and len(values) != width and not (prefix == "c" and values):
            return DataError(
                f"{path} line {lineno}: expected {width} values after '{prefix}', got {len(values)}"
                + (" (the file looks truncated)" if lineno == len(lines) else "")
            )
        for v in values[:1] if prefix == "c" else values:
            try:
                float(v)
            except ValueError:
                return DataError(f"{path} line {lineno}: '{prefix}' value {v!r} is not a number")
    return DataError(f"{path}: '{prefix}' lines have inconsistent value counts")


def _check_last_line(path: Path, text: str) -> None:
    """A truncated file ends inside a line: check the last line even when its prefix is not parsed."""
    lines = text.rstrip("\n").split("\n")
    f = lines[-1].split()
    if not f:
        return
    width = PREFIX_WIDTHS.get(f[0])
    if width is not None and len(f) - 1 != width and not (f[0] == "c" and len(f) > 1):
        raise _bad_line(path, lines, f[0], width)


def read_recording(path: Path, prefixes: "tuple[str, ...] | None" = None) -> Recording:
    """Read a Muse recording (raw ``robot_N``/``user_N``/``intro`` or ``EEG/bands_*``).

    ``prefixes`` restricts parsing to those message types (faster when only bands are needed); lines
    of other prefixes are then not validated, except the last line (a truncated file still fails).
    Known prefixes must have their documented number of values (:data:`PREFIX_WIDTHS`); other prefixes
    are kept when every line has the same count. A malformed or truncated line raises DataError naming
    the file and line, e.g. ``robot_7 line 212: expected 4 values after 'b', got 3``.
    """
    path = Path(path)
    text = _read_text(path)
    wanted = None if prefixes is None else set(prefixes)
    groups: dict[str, list[str]] = {}
    for line in text.splitlines():
        parts = line.split(None, 1)  # any whitespace, CRLF included
        if not parts or (wanted is not None and parts[0] not in wanted):
            continue
        groups.setdefault(parts[0], []).append(parts[1] if len(parts) > 1 else "")
    if wanted is not None:
        _check_last_line(path, text)
    rec = Recording(path)
    for prefix, rests in groups.items():
        width = PREFIX_WIDTHS.get(prefix)
        if prefix == "c":
            tokens = [r.split(None, 1)[0] if r.strip() else "" for r in rests]
            n, w = len(tokens), 1
        else:
            tokens = " ".join(rests).split()
            n = len(rests)
            w = width if width is not None else (len(tokens) // n if n else 0)
        if len(tokens) != n * w or (width is None and len(rests[0].split()) != w):
            raise _bad_line(path, text.splitlines(), prefix, width if width is not None else w)
        try:
            arr = np.array(tokens, dtype=float)
        except ValueError:
            raise _bad_line(path, text.splitlines(), prefix, width) from None
        rec.data[prefix] = arr if prefix == "c" else arr.reshape(n, w)
    if prefixes is not None:
        for p in prefixes:
            rec.data.setdefault(p, np.empty((0,) if p == "c" else (0, PREFIX_WIDTHS.get(p, 4))))
    return rec


# ----------------------------------------------------------------------------------------------
# Derived tables
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TurnTable:
    """A derived per-turn table (``index_1.csv``, ``normalized_1.csv``...): ids and numeric columns."""

    ids: list[str]
    columns: dict[str, np.ndarray]

    def session(self, sid: str) -> dict[str, np.ndarray]:
        """The rows of one session, in file (turn) order."""
        mask = np.array([i == sid for i in self.ids])
        return {k: v[mask] for k, v in self.columns.items()}


def read_turn_table(path: Path) -> TurnTable:
    """Read a space-separated derived table with a header whose first column is ``ID``."""
    path = Path(path)
    lines = [ln for ln in _read_text(path).splitlines() if ln.strip()]
    if not lines:
        raise DataError(f"{path}: empty table")
    header = lines[0].split()
    if header[0] != "ID":
        raise DataError(f"{path} line 1: expected a header starting with 'ID', got {lines[0]!r}")
    ids: list[str] = []
    values: list[list[str]] = []
    for lineno, line in enumerate(lines[1:], 2):
        f = line.split()
        if len(f) != len(header):
            raise DataError(f"{path} line {lineno}: expected {len(header)} columns, got {len(f)}")
        ids.append(f[0])
        values.append(f[1:])
    try:
        arr = np.array(values, dtype=float).reshape(len(values), len(header) - 1)
    except ValueError:
        raise DataError(f"{path}: non-numeric value in a numeric column") from None
    return TurnTable(ids, {name: arr[:, j] for j, name in enumerate(header[1:])})
