"""A study at a glance: one row per session written by ``nao-trainer run`` (``nao-trainer study``).

Columns (:data:`STUDY_COLUMNS`): the session folder, pseudonym, the study it ran in (``study.name``), who
answered (``input``: simulated, tactile, keyboard), start date, completed turns, total score
(equation (1)), success rate per level (empty when the level was not played), mean listening-phase
engagement (recomputed from the raw EEG, ``data/own.py``), how many turns had an engagement value (EEG
lost mid-session shows here), the policy, the session's status, its
duration in seconds, and its span (``span``, ``span_lo``, ``span_hi``): the sequence length in letters
succeeded at ``span_rate`` (75 %, or R when the study's objective was ``target:R``) under the pooled
psychometric prior given to :func:`read_study`
(``core.psychometric.session_span``: posterior median and 90 % interval; empty without a prior or
counted turns). Turns left out of the turn table (interrupted, invalid) do not count.
"""
from __future__ import annotations

import csv
import datetime as dt
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from nao_trainer.core.psychometric import SPAN_RATE, PooledModel, level_counts, session_span
from nao_trainer.data import own
from nao_trainer.errors import DataError

if TYPE_CHECKING:
    from nao_trainer.data.turn_table import SessionFilter

STUDY_COLUMNS: tuple[str, ...] = ("session", "pseudonym", "study", "input", "date", "turns", "score", "success_L1",
                                  "success_L2", "success_L3", "success_L4", "engagement", "eeg_turns", "policy",
                                  "status", "duration_s", "span", "span_lo", "span_hi", "span_rate")

@dataclass
class StudySession:
    """One row of the study table, and the per-turn levels behind the figure."""

    row: dict[str, Any]
    levels: list[int] = field(default_factory=list)  # level of each completed turn, in order
    success: list[int] = field(default_factory=list)  # 1/0 per completed turn
    engagement: list[float] = field(default_factory=list)  # per completed turn (NaN when none)


@dataclass
class Study:
    sessions: list[StudySession]
    problems: list[str]  # one line per session left out
    notes: list[str]

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(STUDY_COLUMNS)
        for s in self.sessions:
            w.writerow(["" if v is None or (isinstance(v, float) and math.isnan(v)) else v
                        for v in (s.row[c] for c in STUDY_COLUMNS)])
        return buf.getvalue()


def _when(text: Any) -> dt.datetime | None:
    try:
        return dt.datetime.fromisoformat(str(text))
    except ValueError:
        return None


def _span_rate(info: dict[str, Any], path: Path) -> float:
    """The rate the session gave its span at (session.json ``span.rate``: the study's target), else 75 %."""
    rec = info.get("span")
    rate = rec.get("rate") if isinstance(rec, dict) else None
    if rate is None:
        return SPAN_RATE
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate < 1:
        raise DataError(f"{path / 'session.json'}: span.rate must be a number between 0 and 1, got {rate!r}")
    return float(rate)


def _span(rows: list[dict[str, Any]], prior: PooledModel | None, rate: float) -> dict[str, float | None]:
    empty = {"span": None, "span_lo": None, "span_hi": None, "span_rate": rate}
    if prior is None or not rows:
        return empty
    try:
        span = session_span(prior, level_counts([r["level"] for r in rows], [bool(r["success"]) for r in rows]),
                            rate)
    except ValueError:  # a prior whose lapse rate rules this rate out: no span, as without a prior
        return empty
    return {"span": round(span.median, 2), "span_lo": round(span.lo, 2), "span_hi": round(span.hi, 2),
            "span_rate": rate}


def study_session(path: Path, prior: PooledModel | None = None) -> StudySession:
    """The study row of one session folder; DataError when it cannot be read. ``prior``: for the span."""
    sess = own.read_session(path)
    eng = own.own_session_engagement(path)
    rows, _excluded = own.table_rows(sess, {t.turn: t for t in eng.turns})
    started, ended = _when(sess.info.get("started")), _when(sess.info.get("ended"))
    success = {}
    for level in (1, 2, 3, 4):
        played = [r["success"] for r in rows if r["level"] == level]
        success[f"success_L{level}"] = round(sum(played) / len(played), 4) if played else None
    values = [r["engagement"] for r in rows if not math.isnan(r["engagement"])]
    policy = sess.info.get("policy")
    row = {
        "session": sess.id, "pseudonym": sess.pseudonym, "study": sess.study, "input": sess.input,
        "date": started.date().isoformat() if started else "",
        "turns": len(rows), "score": sum(r["score"] for r in rows), **success,
        "engagement": round(sum(values) / len(values), 4) if values else None,
        "eeg_turns": len(values),  # turns with an engagement value: EEG lost mid-session shows here
        "policy": policy if policy is not None else "",
        "status": sess.status,
        "duration_s": round((ended - started).total_seconds(), 1) if started and ended else None,
        # the span is a sequence length under the prior fitted on the published data: that task's only
        **_span(rows, prior if getattr(own.session_task(sess), "published_data", False) else None,
                _span_rate(sess.info, Path(path))),
    }
    return StudySession(row, [r["level"] for r in rows], [r["success"] for r in rows],
                        [r["engagement"] for r in rows])


def read_study(root: Path, select: "SessionFilter | None" = None, prior: PooledModel | None = None) -> Study:
    """Every session folder written by ``run`` under ``root``, by start time; DataError when none reads.

    ``select`` (``data.turn_table.SessionFilter``) keeps some studies / inputs; the others are noted.
    ``prior`` (``learn.psychometric_prior.load_prior``) fills the span columns; empty without it."""
    root = Path(root)
    if not root.is_dir():
        raise DataError(f"{root}: no such folder (give a study folder holding session folders written by `run`)")
    paths = own.find_own_sessions(root)
    if not paths:
        raise DataError(f"{root}: no session folders written by `nao-trainer run` (folders with a session.json)")
    sessions, problems, notes = [], [], []
    for p in paths:
        try:
            s = study_session(p, prior)
        except DataError as exc:
            problems.append(f"{own.session_id(p)}: skipped: {exc}")
            continue
        if select is not None and not select.keeps(s.row["study"], s.row["input"]):
            notes.append(f"{s.row['session']}: left out by the filter (study {s.row['study']!r}, "
                         f"input {s.row['input']!r})")
            continue
        sessions.append(s)
    if not sessions and notes:
        raise DataError(f"{root}: the filter left none of the {len(paths)} sessions; check --study / --input")
    if not sessions:
        raise DataError(f"{root}: none of {len(paths)} sessions could be read ({problems[0]})")
    sessions.sort(key=lambda s: (s.row["date"], s.row["session"]))
    return Study(sessions, problems, notes)
