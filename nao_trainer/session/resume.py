"""Resuming an interrupted session (``run --resume``): what a session folder must hold to be continued.

``prepare_resume`` reads the folder's session.json and checkpoint.json, rebuilds the configuration the
session started with (refusing a changed one) and the rows already on disk; ``session.wiring`` then
reopens the folder and the engine continues after the last completed turn.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nao_trainer import __version__
from nao_trainer.errors import DataError
from nao_trainer.files import read_json
from nao_trainer.session.config import StudyConfig, load_config
from nao_trainer.session.record import CHECKPOINT, CHECKPOINT_FORMAT, SessionRecorder, read_turns

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

    def recover_row(self, recorder: SessionRecorder) -> None:
        if self.missing_row is not None:
            recorder.turn(self.missing_row)
            recorder.event("row_recovered", turn=self.missing_row["turn"], source=CHECKPOINT)
            self.rows.append(self.missing_row)


def prepare_resume(folder: Path) -> tuple[StudyConfig, Resumption]:
    """The configuration and state to continue ``folder``; ``DataError`` in one line when it cannot be resumed."""
    folder = Path(folder).resolve()
    fix = "start a new session instead"
    if not (folder / "session.json").is_file():
        raise DataError(f"{folder}: not a session folder (no session.json); give the folder a session wrote")
    info = read_json(folder / "session.json", DataError)
    status = info.get("status")
    if status in FINISHED:
        raise DataError(f"{folder}: the session is complete (status {status!r}); nothing to resume, {fix}")
    if info.get("nao_trainer") != __version__:
        raise DataError(f"{folder}: written by nao-trainer {info.get('nao_trainer')}, this is {__version__}; "
                        f"resume it with that version or {fix}")
    checkpoint = read_json(folder / CHECKPOINT, DataError,
                           "no completed turn to resume from (no checkpoint)", fix)
    if checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise DataError(f"{folder / CHECKPOINT}: unknown format {checkpoint.get('format')!r}; {fix}")
    snap = info.get("config") or {}
    sources = snap.get("sources") or []
    if not sources:
        raise DataError(f"{folder}/session.json: no configuration snapshot; {fix}")
    config = load_config(sources[-1], snap.get("overrides") or {}, default=sources[0])
    if config.text_sha256 != snap.get("sha256") or config.values != snap.get("values"):
        changed = ", ".join(sources)
        raise DataError(f"{folder}: the configuration changed since the session started (hash of {changed} "
                        f"and the session's flags differs from session.json); restore those files or {fix}")
    if int(checkpoint["completed"]) >= config.session.turns:
        raise DataError(f"{folder}: all {config.session.turns} turns are recorded; nothing to resume, {fix}")
    rows = [_typed_row(r) for r in read_turns(folder) if r["success"] in ("True", "False")]
    last = max((int(r["turn"]) for r in rows), default=0)
    missing = checkpoint["row"] if last < int(checkpoint["completed"]) else None
    return config, Resumption(folder, int(info["seed"]), checkpoint, rows, missing)


def _typed_row(row: dict[str, str]) -> dict[str, Any]:
    """A turns.csv row read back with the types the session's own rows have (for its summary)."""
    def num(v: str, kind: type) -> Any:
        return None if v in ("", None) else kind(v)

    out: dict[str, Any] = dict(row)
    out.update(turn=int(row["turn"]), level=int(row["level"]), feedback=int(row["feedback"]),
               success=row["success"] == "True", score=num(row["score"], int), engagement=num(row["engagement"], float))
    return out
