"""Resuming an interrupted session (``run --resume``): what a session folder must hold to be continued.

``prepare_resume`` reads the folder's session.json and checkpoint.json, rebuilds the configuration the
session started with (refusing a changed one) and the rows already on disk; ``session.wiring`` then
reopens the folder and the engine continues after the last completed turn.
"""
from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nao_trainer import __version__
from nao_trainer.errors import DataError
from nao_trainer.files import read_json
from nao_trainer.ports import Policy
from nao_trainer.session.checkpoint import checkpoint_problem
from nao_trainer.session.config import StudyConfig, load_config
from nao_trainer.session.record import CHECKPOINT, CHECKPOINT_FORMAT, SessionRecorder, read_turns, row_problem

#: session.json statuses of a session that ended as planned: ``--resume`` refuses them.
FINISHED = ("completed", "stopped", "time limit")


@dataclass
class Resumption:
    """What ``prepare_resume`` found in an interrupted session folder."""

    folder: Path
    seed: int
    checkpoint: dict[str, Any]
    rows: list[dict[str, Any]]  # completed rows already on disk, typed like the session's own
    missing_row: dict[str, Any] | None  # the checkpoint's row when a kill came between the two writes

    def check_policy(self, policy: Policy) -> None:
        """Restore the checkpoint's policy state once, before anything is written: a state the policy
        cannot take (a tampered checkpoint) is refused here, with the session's status untouched."""
        try:
            policy.restore(self.checkpoint.get("policy"))
        except Exception as exc:  # noqa: BLE001 - whatever a tampered state breaks, the answer is a refusal
            detail = str(exc).splitlines()[0][:200] if str(exc) else ""
            raise DataError(f"{self.folder / CHECKPOINT}: the policy's state cannot be restored "
                            f"({type(exc).__name__}: {detail}); start a new session instead") from None

    def recover_row(self, recorder: SessionRecorder) -> None:
        if self.missing_row is not None:
            recorder.turn(self.missing_row)
            recorder.event("row_recovered", turn=self.missing_row["turn"], source=CHECKPOINT)
            self.rows.append(self.missing_row)


def prepare_resume(folder: Path) -> tuple[StudyConfig, Resumption]:
    """The configuration and state to continue ``folder``; ``DataError`` in one line when it cannot be resumed.

    Nothing is written here: a refused folder keeps its status (a tampered checkpoint is not an error
    of the session). The checkpoint is checked against the rows on disk (``checkpoint_problem``).
    """
    folder = Path(folder).resolve()
    fix = "start a new session instead"
    if not (folder / "session.json").is_file():
        raise DataError(f"{folder}: not a session folder (no session.json); give the folder a session wrote")
    _refuse_foreign_entries(folder, fix)
    info = read_json(folder / "session.json", DataError)
    if not isinstance(info, dict):
        raise DataError(f"{folder}/session.json: not a session record (a JSON object expected); {fix}")
    status = info.get("status")
    if status in FINISHED:
        raise DataError(f"{folder}: the session is complete (status {status!r}); nothing to resume, {fix}")
    if info.get("nao_trainer") != __version__:
        raise DataError(f"{folder}: written by nao-trainer {info.get('nao_trainer')}, this is {__version__}; "
                        f"resume it with that version or {fix}")
    checkpoint = read_json(folder / CHECKPOINT, DataError,
                           "no completed turn to resume from (no checkpoint)", fix)
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        found = checkpoint.get("format") if isinstance(checkpoint, dict) else checkpoint
        raise DataError(f"{folder / CHECKPOINT}: unknown format {found!r}; {fix}")
    seed = info.get("seed")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise DataError(f"{folder}/session.json: seed must be an integer >= 0, got {seed!r}; {fix}")
    config = _config_of(folder, info, fix)
    task = config.task.build_task()
    rows = _rows_on_disk(folder, fix, task)
    last = max((int(r["turn"]) for r in rows), default=0)
    learns = config.policy.persists  # a policy that keeps a participant state (its declaration says so)
    problem = checkpoint_problem(checkpoint, config.session.turns, learns, last, task.columns)
    if problem:
        raise DataError(f"{folder / CHECKPOINT}: {problem}; {fix}")
    _check_against_checkpoint(folder, rows, checkpoint, last, fix)
    for row in rows:
        del row["_raw"], row["_line"]
    if checkpoint["completed"] >= config.session.turns:
        raise DataError(f"{folder}: all {config.session.turns} turns are recorded; nothing to resume, {fix}")
    missing = checkpoint["row"] if last < checkpoint["completed"] else None
    return config, Resumption(folder, seed, checkpoint, rows, missing)


def _refuse_foreign_entries(folder: Path, fix: str) -> None:
    """A session folder holds only the files and folders its session wrote: a symbolic link (turns.csv
    pointing elsewhere would be appended to) or a FIFO, socket or device is refused before anything is read."""
    try:
        entries = sorted(os.scandir(folder), key=lambda e: e.name)
    except OSError as exc:
        raise DataError(f"{folder}: cannot list the session folder ({exc.strerror}); {fix}") from None
    for entry in entries:
        if entry.is_symlink():
            raise DataError(f"{folder / entry.name}: a symbolic link in the session folder (a session writes only "
                            f"its own files, never through a link); replace it with the file itself or {fix}")
        if not (entry.is_file(follow_symlinks=False) or entry.is_dir(follow_symlinks=False)):
            raise DataError(f"{folder / entry.name}: not a regular file (a FIFO, socket or device) in the session "
                            f"folder; remove it or {fix}")


def _check_against_checkpoint(folder: Path, rows: list[dict[str, Any]], cp: dict[str, Any], last: int, fix: str) -> None:
    """The whole table agrees with the checkpoint: its completed rows sum to the checkpoint's total (with the
    checkpoint's own row when a kill came before it reached turns.csv), and the last row is the checkpoint's."""
    where = f"{folder}/turns.csv"
    counted = list(rows) + ([cp["row"]] if last < cp["completed"] else [])
    total = sum(int(r["score"]) for r in counted)
    if total != cp["total"]:
        raise DataError(f"{where}: the completed rows score {total} in all, the checkpoint {cp['total']}: a row was "
                        f"edited, added or removed; restore the file or {fix}")
    if last == cp["completed"]:
        on_disk = rows[-1]["_raw"]
        for key, value in cp["row"].items():
            want = "" if value is None else str(value)
            if on_disk.get(key) != want:
                raise DataError(f"{where}: line {rows[-1]['_line']} (turn {last}): {key} is {on_disk.get(key)!r}, the "
                                f"checkpoint recorded {want!r}; restore the file or {fix}")


def _config_of(folder: Path, info: dict[str, Any], fix: str) -> StudyConfig:
    """The configuration the session started with; refused when its files or flags changed since."""
    snap = info.get("config")
    snap = snap if isinstance(snap, dict) else {}
    sources = snap.get("sources")
    overrides = snap.get("overrides") or {}
    if not sources or not isinstance(sources, list) or not all(isinstance(x, str) for x in sources) \
            or not isinstance(overrides, dict):
        raise DataError(f"{folder}/session.json: no configuration snapshot; {fix}")
    config = load_config(sources[-1], overrides, default=sources[0])
    if config.text_sha256 != snap.get("sha256") or config.values != snap.get("values"):
        changed = ", ".join(sources)
        raise DataError(f"{folder}: the configuration changed since the session started (hash of {changed} "
                        f"and the session's flags differs from session.json); restore those files or {fix}")
    return config


def _rows_on_disk(folder: Path, fix: str, task: Any = None) -> list[dict[str, Any]]:
    """The completed rows of turns.csv (a torn last line left out), typed; ``DataError`` when unreadable."""
    if not (folder / "turns.csv").is_file():
        raise DataError(f"{folder}: turns.csv is missing, the rows the checkpoint continues; {fix}")
    where = f"{folder}/turns.csv"
    try:
        raw = read_turns(folder, complete_only=True)
        for n, r in enumerate(raw, start=2):  # line numbers: the header is line 1
            if None in r or None in r.values() or not r["turn"].isdigit():
                raise ValueError(f"line {n} is not a turn row")
        done = [(n, r) for n, r in enumerate(raw, start=2) if r["success"] in ("True", "False")]
        for n, r in done:  # every completed row as a session writes it (an edited score is refused)
            problem = row_problem(r, task)
            if problem:
                raise DataError(f"{where}: line {n} (turn {r['turn']}): {problem}; restore the file or {fix}")
        rows = [dict(_typed_row(r), _raw=r, _line=n) for n, r in done]
    except (ValueError, TypeError, KeyError, csv.Error, UnicodeDecodeError) as exc:
        raise DataError(f"{where}: not the session's rows ({type(exc).__name__}: {exc}); {fix}") from None
    seen: dict[int, int] = {}
    for expected, row in enumerate(rows, start=1):  # one completed row per turn, numbered 1, 2, 3, ...
        if row["turn"] in seen:
            raise DataError(f"{where}: line {row['_line']}: turn {row['turn']} is recorded twice (first on line "
                            f"{seen[row['turn']]}); restore the file or {fix}")
        if row["turn"] != expected:
            raise DataError(f"{where}: line {row['_line']}: turn {row['turn']} where turn {expected} belongs (the "
                            f"completed turns must be numbered 1, 2, 3, ...); restore the file or {fix}")
        seen[row["turn"]] = row["_line"]
    return rows  # with "_raw" (as read) and "_line": ``_check_against_checkpoint`` names them, then drops them


def _typed_row(row: dict[str, str]) -> dict[str, Any]:
    """A turns.csv row read back with the types the session's own rows have (for its summary)."""
    def num(v: str, kind: type) -> Any:
        return None if v in ("", None) else kind(v)

    out: dict[str, Any] = dict(row)
    out.update(turn=int(row["turn"]), level=int(row["level"]), feedback=int(row["feedback"]),
               success=row["success"] == "True", score=num(row["score"], int), engagement=num(row["engagement"], float))
    return out
