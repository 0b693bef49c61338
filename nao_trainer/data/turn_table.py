"""The tidy turn table: its columns, the CSV it is stored as, and which sessions a table keeps.

One row per turn, the columns of :data:`COLUMNS` in that order (the schema: ``docs/reference/data.md``).
``nao_trainer.data.dataset`` fills it from recorded sessions; ``write_table`` / ``read_table``
store it as CSV (floats as ``repr``, exact on reading back; NaN as empty) with a JSON sidecar of
provenance; :class:`SessionFilter` keeps the sessions of some studies and inputs.
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.errors import DataError, UserError
from nao_trainer.files import cannot_write, read_text, write_text_atomic

#: Columns that label a session (what study, who answered) rather than describe a turn: not fingerprinted.
LABELS = ("study", "input")
#: Column name -> kind (str, int, float). The CSV's header is exactly these names in this order.
COLUMNS: dict[str, type] = {
    "session": str,
    "pseudonym": str,
    "study": str,
    "input": str,
    "turn": int,
    "state": int,
    "length": int,
    "level": int,
    "feedback": int,
    "previous_score": int,
    "action": int,
    "sequence": str,
    "response": str,
    "success": int,
    "score": int,
    "signed_score": int,
    "reaction_time": float,
    "completion_time": float,
    "engagement_index": float,
    "engagement": float,
    "eeg_quality": float,
    "contact": float,
    "eeg_note": str,
}


@dataclass
class TurnTable:
    """Column arrays of the tidy turn table (see :data:`COLUMNS`)."""

    columns: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.columns["session"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    @property
    def sessions(self) -> list[str]:
        return list(dict.fromkeys(self.columns["session"].tolist()))

    @classmethod
    def from_rows(cls, rows: list[dict[str, Any]]) -> "TurnTable":
        cols = {}
        for name, kind in COLUMNS.items():
            values = [r[name] for r in rows]
            cols[name] = np.array(values, dtype=float if kind is float else (np.int64 if kind is int else str))
        return cls(cols)

    def mix(self) -> str:
        """``sessions by study/input: demo/simulated 3, paper-2018/tactile 2``: what the table mixes."""
        counts: dict[str, int] = {}
        seen: set[str] = set()
        for sid, study, kind in zip(self["session"], self["study"], self["input"]):
            if sid not in seen:
                seen.add(sid)
                key = f"{study or '?'}/{kind}"
                counts[key] = counts.get(key, 0) + 1
        return "sessions by study/input: " + ", ".join(f"{k} {n}" for k, n in sorted(counts.items()))

    def to_csv(self, columns: "tuple[str, ...] | None" = None) -> str:
        """CSV text (floats as ``repr``, so reading back is exact; NaN as empty) of ``columns`` (default all)."""
        names = tuple(COLUMNS) if columns is None else columns
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(names)
        cols = [self.columns[n] for n in names]
        kinds = [COLUMNS[n] for n in names]
        for i in range(len(self)):
            w.writerow(["" if k is float and not np.isfinite(c[i]) else (repr(float(c[i])) if k is float else c[i])
                        for c, k in zip(cols, kinds)])
        return buf.getvalue()

    def fingerprint(self) -> str:
        """SHA-256 of the CSV text of the turn data: identifies the data a model was fitted from.

        The session labels ``study`` and ``input`` (importer v3) are left out, so a model fitted from the
        same turns before they existed keeps its fingerprint (sim/models)."""
        return hashlib.sha256(self.to_csv(tuple(c for c in COLUMNS if c not in LABELS)).encode()).hexdigest()


def write_table(table: TurnTable, path: Path, provenance: dict[str, Any]) -> Path:
    """Write the CSV and a JSON sidecar ``<path>.json`` with provenance; returns the CSV path."""
    path = Path(path)
    text = table.to_csv()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        for target, content in ((path, text), (path.with_name(path.name + ".json"),
                                               json.dumps(provenance, indent=1) + "\n")):
            write_text_atomic(target, content)
    except OSError as exc:
        where = exc.filename or path
        raise UserError(cannot_write(where, "the turn table", exc, "choose another --out")) from None
    return path


def read_table(path: Path) -> TurnTable:
    """Read a turn table CSV written by :func:`write_table`; DataError naming file:line on problems."""
    path = Path(path)
    text = read_text(path, DataError)
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header != list(COLUMNS):
        missing = [c for c in COLUMNS if c not in (header or [])]
        what = f"missing columns: {', '.join(missing)}" if missing else "columns in another order"
        raise DataError(f"{path}:1: not a nao-trainer turn table ({what}); create it with `nao-trainer import`")
    rows = []
    for lineno, rec in enumerate(reader, 2):
        if len(rec) != len(COLUMNS):
            raise DataError(f"{path}:{lineno}: expected {len(COLUMNS)} fields, got {len(rec)}")
        row: dict[str, Any] = {}
        for (name, kind), value in zip(COLUMNS.items(), rec):
            try:
                row[name] = (float(value) if value else float("nan")) if kind is float else kind(value)
            except ValueError:
                raise DataError(f"{path}:{lineno}: column {name!r} must be {kind.__name__}, got {value!r}") from None
        rows.append(row)
    table = TurnTable.from_rows(rows)
    bad = ~np.isin(table["state"], np.arange(mdp.N_TURN_STATES))
    if bad.any():
        raise DataError(f"{path}:{int(np.flatnonzero(bad)[0]) + 2}: state must be in 0..107")
    return table



@dataclass(frozen=True)
class SessionFilter:
    """Which sessions a table keeps, by the study they belong to and who answered (``input``).

    Empty tuples keep every value; ``exclude_simulated`` drops sessions whose participant was simulated.
    """

    studies: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    exclude_simulated: bool = False

    def keeps(self, study: str, input_kind: str) -> bool:
        return ((not self.studies or study in self.studies) and (not self.inputs or input_kind in self.inputs)
                and not (self.exclude_simulated and input_kind == "simulated"))

    def apply(self, table: TurnTable) -> tuple[TurnTable, list[str]]:
        """The rows of the sessions kept, and one line per session left out."""
        keep = np.array([self.keeps(s, i) for s, i in zip(table["study"], table["input"])], dtype=bool)
        dropped = list(dict.fromkeys(
            f"{sid}: left out by the filter (study {str(st)!r}, input {str(inp)!r})"
            for sid, st, inp, k in zip(table["session"], table["study"], table["input"], keep) if not k))
        return TurnTable({k: v[keep] for k, v in table.columns.items()}), dropped

    def __str__(self) -> str:
        parts = ([f"study {' or '.join(self.studies)}"] if self.studies else []) + (
            [f"input {' or '.join(self.inputs)}"] if self.inputs else []) + (
            ["simulated participants left out"] if self.exclude_simulated else [])
        return ", ".join(parts) or "no filter"

    def describe(self) -> dict[str, Any]:
        return {"studies": list(self.studies), "inputs": list(self.inputs), "exclude_simulated": self.exclude_simulated}


def simulated_sessions(table: TurnTable) -> list[str]:
    """The sessions of ``table`` whose participant was simulated (``input`` simulated)."""
    return list(dict.fromkeys(s for s, i in zip(table["session"], table["input"]) if i == "simulated"))

