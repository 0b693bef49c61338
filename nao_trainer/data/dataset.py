"""Import recorded sessions into one tidy turn table (one row per turn).

Two layouts import into the same columns and encodings (the schema: ``docs/reference/data.md``):

* the published layout: every ``user_<id>/session_<k>/`` under a root, read with
  ``nao_trainer.data.published`` (logfile, state_EEG, recordings) and
  ``nao_trainer.data.engagement.session_engagement`` (per-turn engagement); logfile and state_EEG
  must agree; the MDP columns (state index, the action that produced the turn) are derived;
* the folders ``nao-trainer run`` writes (``<pseudonym>_<stamp>/`` with session.json), read with
  ``nao_trainer.data.own``: success 0/1 and the action index from turns.csv, engagement recomputed
  from the session's raw EEG. Interrupted or invalid turns stay in turns.csv but are left out of
  the table, each with the reason (:attr:`ImportResult.excluded`).

A session that cannot be read is reported in one line and skipped; the others import.

Columns (:data:`nao_trainer.data.turn_table.COLUMNS`; the table, its CSV and the session filter
live in ``data/turn_table.py``): ``session pseudonym study input turn state length level feedback previous_score action
sequence response success score signed_score reaction_time completion_time engagement_index
engagement eeg_quality contact eeg_note``. ``action`` is the core.mdp action that produced the turn (a
level action from START on turn 1; RF1/RF2 when the turn followed robot feedback). ``score`` is
equation (1) (+level / -1), ``signed_score`` the data's +level / -level. Engagement columns are NaN
when the turn has no usable EEG and ``eeg_note`` says why; ``eeg_quality`` is the fraction of
usable EEG samples of the turn and ``contact`` the fraction of the listening recording's ``h``
samples with all four electrodes in good or ok contact.

Cache: each session's rows are stored in ``<cache_dir>/<user>__<session>.json`` keyed by the
importer version, the package version, the offline engagement settings, the compatibility mode and
the names, sizes and modification times of all the session's files; a re-import reads only the cache for unchanged sessions.
"""
from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import nao_trainer
from nao_trainer.core import mdp
from nao_trainer.core.task import LENGTHS, level_of, score, signed_score
from nao_trainer.data import engagement as offline
from nao_trainer.data import own, published
from nao_trainer.data.turn_table import SessionFilter, TurnTable, simulated_sessions
from nao_trainer.errors import DataError
from nao_trainer.files import write_text_atomic

IMPORTER_VERSION = 4  # 2: pseudonym column; sessions written by `run`; 3: engagement scaled over the task; 4: study and input columns
#: ``study`` / ``input`` of a published session: the authors' study; a person answered (how is not recorded).
PUBLISHED = "published"
COMPAT_MODES = (None, "authors2018")


@dataclass(frozen=True)
class SkippedSession:
    """A session that was not imported, with the one-line reason."""

    session: str
    reason: str

    def __str__(self) -> str:
        return f"{self.session}: skipped: {self.reason}"


# ------------------------------------------------------------------------------------------------
# One session
# ------------------------------------------------------------------------------------------------


def _letters(seq: tuple[str, ...]) -> str:
    return "".join(s.upper() for s in seq)


def produced_by(length: int, feedback: int, turn_index: int) -> int:
    """The core.mdp action that led to a turn: RF1/RF2 after feedback, else the level action."""
    if feedback == 1 and turn_index > 0:
        return mdp.ENCOURAGE
    if feedback == 2 and turn_index > 0:
        return mdp.CHALLENGE
    return level_of(length) - 1


def _check_turns(log: list[published.LogRow], states: list[published.StateRow]) -> None:
    """Raise DataError when logfile and state_EEG disagree or turns are missing."""
    if not log:
        raise DataError("logfile has no turns")
    numbers = [r.turn for r in log]
    if numbers != list(range(1, len(log) + 1)):
        gap = next(i + 1 for i, n in enumerate(numbers) if n != i + 1)
        raise DataError(f"logfile turn numbers are not 1..{len(log)} (turn {gap} is {numbers[gap - 1]})")
    if len(states) < len(log):
        raise DataError(f"state_EEG has {len(states)} turns, fewer than the logfile's {len(log)}")
    for i, (r, s) in enumerate(zip(log, states)):
        where = f"turn {i + 1}"
        if r.length not in LENGTHS:
            raise DataError(f"logfile {where}: length must be one of {LENGTHS}, got {r.length}")
        if r.success not in (1, -1):
            raise DataError(f"logfile {where}: success must be 1 or -1, got {r.success}")
        if r.rf not in (0, 1, 2):
            raise DataError(f"logfile {where}: robot feedback (rf) must be 0, 1 or 2, got {r.rf}")
        if (s.length, s.rf) != (r.length, r.rf):
            raise DataError(f"{where}: state_EEG says length {s.length} rf {s.rf}, logfile {r.length} {r.rf}")
        expected_prev = 0 if i == 0 else signed_score(level_of(log[i - 1].length), log[i - 1].success == 1)
        if s.previous_score != expected_prev:
            raise DataError(
                f"state_EEG {where}: previous_score {s.previous_score}, the logfile implies {expected_prev}"
            )
        if r.rf > 0 and i > 0 and r.length != log[i - 1].length:
            raise DataError(f"{where}: feedback turn changes length ({log[i - 1].length} -> {r.length})")


def _engagement(session_dir: Path, n: int, compat: str | None) -> list[tuple[float, float, float, float, str]]:
    """Per turn: (engagement_index, engagement, quality, contact, note) from ``data.engagement``."""
    nan = float("nan")
    eng = offline.session_engagement(session_dir, compat=compat)
    out = []
    for t in eng.turns[:n]:
        out.append((
            nan if t.engagement_index is None else float(t.engagement_index),
            nan if t.engagement is None else float(t.engagement),
            float(t.quality),
            nan if t.contact is None else float(t.contact),
            t.reason,
        ))
    out += [(nan, nan, 0.0, nan, "no EEG turn")] * (n - len(out))
    return out


def import_session(session_dir: Path, compat: str | None = None) -> list[dict[str, Any]]:
    """The turn rows of one session; DataError (message without the session id) when unreadable."""
    session_dir = Path(session_dir)
    sid = published.session_id(session_dir)
    log = published.read_logfile(session_dir / "logfile")
    states = published.read_state_eeg(session_dir / "state_EEG")
    _check_turns(log, states)
    eeg = _engagement(session_dir, len(log), compat)
    rows = []
    for i, (r, s) in enumerate(zip(log, states)):
        index, normed, quality, contact, note = eeg[i]
        lv = level_of(r.length)
        ok = r.success == 1
        rows.append({
            "session": sid, "pseudonym": Path(sid).parent.name, "study": PUBLISHED, "input": PUBLISHED, "turn": r.turn, "state": mdp.encode(s.length, s.rf, s.previous_score),
            "length": r.length, "level": lv, "feedback": r.rf, "previous_score": s.previous_score,
            "action": produced_by(r.length, r.rf, i), "sequence": _letters(r.sequence),
            "response": _letters(r.response), "success": int(ok), "score": score(lv, ok),
            "signed_score": signed_score(lv, ok), "reaction_time": float(r.reaction_time),
            "completion_time": float(r.completion_time), "engagement_index": index,
            "engagement": normed, "eeg_quality": quality, "contact": contact, "eeg_note": note,
        })
    return rows


# ------------------------------------------------------------------------------------------------
# Cache and whole dataset
# ------------------------------------------------------------------------------------------------


def engagement_definition() -> str:
    """What the cached engagement columns depend on besides the files: the package version and the
    offline engagement settings (``data.engagement.OfflineSettings``). A change invalidates the cache."""
    return f"nao-trainer {nao_trainer.__version__}|{offline.OfflineSettings()!r}"


def _session_key(session_dir: Path, compat: str | None) -> str:
    h = hashlib.sha256(f"v{IMPORTER_VERSION}|{compat}|{engagement_definition()}".encode())
    with os.scandir(session_dir) as it:
        entries = sorted(it, key=lambda e: e.name)
    for e in entries:
        if e.is_dir():
            with os.scandir(e.path) as sub:
                for f in sorted(sub, key=lambda x: x.name):
                    st = f.stat()
                    h.update(f"{e.name}/{f.name}|{st.st_size}|{st.st_mtime_ns}\n".encode())
        else:
            st = e.stat()
            h.update(f"{e.name}|{st.st_size}|{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def _cache_file(cache_dir: Path, sid: str) -> Path:
    return cache_dir / (sid.replace("/", "__") + ".json")


def _json_safe(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in r.items()} for r in rows]


def _from_json(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: (float("nan") if v is None else v) for k, v in r.items()} for r in rows]


@dataclass
class ImportResult:
    table: TurnTable
    problems: list[SkippedSession]
    cached: int = 0
    provenance: dict[str, Any] = field(default_factory=dict)
    excluded: list[Any] = field(default_factory=list)  # data.own.Excluded: turns kept out of the table
    notes: list[str] = field(default_factory=list)  # read as far as valid (a torn last line), mixed layouts

    def excluded_summary(self) -> str:
        """``3 turns left out (interrupted: 2, invalid: 1)``, or "" when none."""
        if not self.excluded:
            return ""
        kinds: dict[str, int] = {}
        for e in self.excluded:
            kind = "invalid" if e.reason.startswith("invalid") else (
                "interrupted" if e.reason.startswith("interrupted") else "no outcome")
            kinds[kind] = kinds.get(kind, 0) + 1
        detail = ", ".join(f"{k}: {n}" for k, n in kinds.items())
        return f"{len(self.excluded)} turns left out of the table, kept in their turns.csv ({detail})"


@dataclass(frozen=True)
class Discovered:
    """The sessions under a root, by layout."""

    published: list[Path]
    own: list[Path]

    @property
    def all(self) -> list[tuple[str, Path]]:
        return [("published", p) for p in self.published] + [("own", p) for p in self.own]

    def mixed_note(self, root: Path) -> str:
        if not (self.published and self.own):
            return ""
        return (f"{root} holds both layouts ({len(self.published)} published, {len(self.own)} written by `run`): "
                "both are imported, but their engagement comes from different signals (Muse band lines vs raw EEG)")


def discover(root: Path) -> Discovered:
    """Session folders of both layouts under ``root`` (or ``root`` itself); DataError when none."""
    root = Path(root)
    if not root.exists():
        raise DataError(f"{root}: no such folder (give a session folder, a study folder or a dataset root)")
    try:
        pub = published.find_sessions(root)
    except DataError:
        pub = []
    mine = [p for p in own.find_own_sessions(root) if p not in pub]
    if not pub and not mine:
        raise DataError(f"{root}: no sessions found (expected session folders written by `nao-trainer run` "
                        "(with session.json), or user_<id>/session_<k>/ folders with a logfile or state_EEG)")
    return Discovered(pub, mine)


def session_name(layout: str, path: Path) -> str:
    return published.session_id(path) if layout == "published" else own.session_id(path)


def import_own_session(session_dir: Path) -> tuple[list[dict[str, Any]], list[Any], list[str]]:
    """(rows, excluded turns, notes) of one session written by ``run``; DataError when unreadable."""
    sess = own.read_session(session_dir)
    if not getattr(own.session_task(sess), "published_data", False):
        raise DataError(f"task {sess.task!r}: not imported: the turn table, the user models fitted on it and their "
                        "reproductions are the published data's (the sequence task: lengths 3-9, letters); its "
                        f"turns would mix with those (a {sess.task} session is read by study analyse and export)")
    eng = own.own_session_engagement(session_dir)
    rows, excluded = own.table_rows(sess, {t.turn: t for t in eng.turns})
    notes = list(sess.notes)
    if not (Path(session_dir) / "eeg").is_dir():
        notes.append("no eeg/ folder: no engagement")
    return rows, excluded, notes


def import_dataset(root: Path, compat: str | None = None, cache_dir: Path | None = None,
                   progress: Callable[[str], None] | None = None,
                   select: SessionFilter | None = None) -> ImportResult:
    """Import every session under ``root``; unreadable sessions become :class:`SkippedSession` lines.

    ``select`` keeps only the sessions of some studies / inputs (the others are noted, not problems).
    Raises DataError when no session folder exists or none could be imported (or kept).
    """
    if compat not in COMPAT_MODES:
        known = ", ".join(str(c) for c in COMPAT_MODES[1:])
        raise DataError(f"unknown compatibility mode {compat!r}: use one of {known} (or none)")
    root = Path(root)
    say = progress or (lambda _m: None)
    found = discover(root)
    sessions = found.all
    if cache_dir is not None:
        try:
            Path(cache_dir).mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # a cache that cannot be made only costs time
            print(f"nao-trainer: warning: import cache {cache_dir} unusable ({exc.strerror}); reading without it",
                  file=sys.stderr)
            cache_dir = None
    rows: list[dict[str, Any]] = []
    problems: list[SkippedSession] = []
    excluded: list[own.Excluded] = []
    notes: list[str] = [n for n in (found.mixed_note(root),) if n]
    cached = 0
    for k, (layout, sdir) in enumerate(sessions, 1):
        sid = session_name(layout, sdir)
        if layout == "own" and compat is not None:
            problems.append(SkippedSession(sid, f"--compat {compat} applies to the published layout only "
                                                "(sessions written by `run` have raw EEG, not Muse band lines)"))
            continue
        key = _session_key(sdir, compat) if cache_dir is not None else ""
        if cache_dir is not None:
            hit = _read_cache(_cache_file(Path(cache_dir), sid), key)
            if hit is not None:
                srows, sexcl, snotes = hit
                rows.extend(srows)
                excluded.extend(own.Excluded(**e) for e in sexcl)
                notes.extend(f"{sid}: {n}" for n in snotes)
                cached += 1
                continue
        say(f"import {k}/{len(sessions)} {sid}")
        try:
            if layout == "published":
                srows, sexcl, snotes = import_session(sdir, compat), [], []
            else:
                srows, sexcl, snotes = import_own_session(sdir)
        except DataError as exc:
            problems.append(SkippedSession(sid, str(exc)))
            continue
        except Exception as exc:  # noqa: BLE001 - one odd session must not stop the import
            problems.append(SkippedSession(sid, f"unexpected {type(exc).__name__}: {exc}".replace("\n", " ")))
            continue
        if not srows:
            why = f"no completed turn ({len(sexcl)} left out)" if sexcl else "no turns"
            problems.append(SkippedSession(sid, why))
            excluded.extend(sexcl)
            continue
        rows.extend(srows)
        excluded.extend(sexcl)
        notes.extend(f"{sid}: {n}" for n in snotes)
        if cache_dir is not None:
            _write_cache(_cache_file(Path(cache_dir), sid), key, srows, sexcl, snotes)
    if not rows:
        detail = f" ({problems[0]})" if problems else ""
        raise DataError(f"{root}: none of {len(sessions)} sessions could be imported{detail}")
    table = TurnTable.from_rows(rows)
    if select is not None:
        table, dropped = select.apply(table)
        notes.extend(dropped)
        if not len(table):
            raise DataError(f"{root}: the filter ({select}) left none of the {len(sessions)} sessions; "
                            "check --study / --input (`nao-trainer study` lists each session's study and input)")
    provenance = {
        "format": "nao-trainer/turn-table",
        "importer_version": IMPORTER_VERSION,
        "root": str(root.resolve()),
        "compat": compat,
        "filter": select.describe() if select is not None else None,
        "studies": sorted(set(table["study"].tolist())),
        "inputs": sorted(set(table["input"].tolist())),
        "simulated_sessions": simulated_sessions(table),
        "sessions": len(table.sessions),
        "turns": len(table),
        "skipped": [str(p) for p in problems],
        "excluded_turns": [str(e) for e in excluded],
        "notes": notes,
        "fingerprint": table.fingerprint(),
    }
    return ImportResult(table, problems, cached, provenance, excluded, notes)


def _read_cache(path: Path, key: str) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[str]] | None:
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("key") != key or not isinstance(data.get("rows"), list):
        return None
    return _from_json(data["rows"]), list(data.get("excluded", [])), list(data.get("notes", []))


def _write_cache(path: Path, key: str, rows: list[dict[str, Any]], excluded: list[Any] = (),
                 notes: list[str] = ()) -> None:
    try:
        write_text_atomic(path, json.dumps({"key": key, "rows": _json_safe(rows),
                                            "excluded": [asdict(e) for e in excluded], "notes": list(notes)}))
    except OSError as exc:  # a cache that cannot be written only costs time
        print(f"nao-trainer: warning: cannot write import cache {path}: {exc.strerror}", file=sys.stderr)


def cache_dir(root: Path, compat: str | None, beside: Path | None = None) -> Path:
    """The one rule for the import cache folder of ``root``.

    Beside a table being written (``nao-trainer import --out FILE``): ``FILE.cache/``, so the cache
    travels with the table. Otherwise (``nao-trainer fit DATASET``) per user:
    ``$XDG_CACHE_HOME/nao-trainer/import/<sha256 of the root path, 16 hex>-<compat or default>``.
    """
    if beside is not None:
        beside = Path(beside)
        return beside.with_name(beside.name + ".cache")
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "nao-trainer" / "import"
    digest = hashlib.sha256(str(Path(root).resolve()).encode()).hexdigest()[:16]
    return base / f"{digest}-{compat or 'default'}"
