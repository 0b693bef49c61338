"""``study status``: enrolment, sessions per arm, overdue participants, withdrawals, data quality per session.

Data quality is read from each session's own files (``turns.csv``, ``events.jsonl``): turns completed
(an outcome recorded and not marked invalid), turns with EEG (a completed turn with an engagement value),
turns marked invalid by the operator, turns interrupted, and robot interruptions (``robot_lost`` events).
Nothing here reveals the allocation of a participant not yet enrolled.
"""
from __future__ import annotations

import csv
import datetime as dt
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nao_trainer.study.registry import Study
from nao_trainer.study.runner import DONE, days_between, done_sessions, pending_sessions


@dataclass(frozen=True)
class Quality:
    turns: int
    with_eeg: int
    invalid: int
    interrupted: int
    robot_lost: int


def session_quality(folder: Path) -> Quality | None:
    """Counts from a session folder; None when its turn table is missing."""
    turns_csv = folder / "turns.csv"
    if not turns_csv.is_file():
        return None
    with open(turns_csv, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    invalid = sum(r.get("invalid") == "True" for r in rows)
    outcome = [r for r in rows if r.get("success") in ("True", "False") and r.get("invalid") != "True"]
    interrupted = sum(r.get("success") not in ("True", "False") for r in rows)
    with_eeg = sum(bool((r.get("engagement") or "").strip()) for r in outcome)
    lost = 0
    events = folder / "events.jsonl"
    if events.is_file():
        for line in events.read_text(encoding="utf-8").splitlines():
            try:
                lost += json.loads(line).get("event") == "robot_lost"
            except ValueError:
                continue  # a torn last line
    return Quality(len(outcome), with_eeg, invalid, interrupted, lost)


@dataclass(frozen=True)
class Status:
    lines: list[str]
    sessions: list[dict[str, Any]]  # one row per session (pseudonym, arm or blinded, number, status, quality)
    overdue: list[str]


def study_status(study: Study, now: dt.datetime | None = None, show_arms: bool | None = None) -> Status:
    """The status report; arms shown unless the protocol is blinded (``show_arms`` overrides)."""
    now = now or dt.datetime.now(dt.timezone.utc).astimezone()
    protocol = study.protocol
    show = (not protocol.blinding) if show_arms is None else show_arms
    people = study.participants
    withdrawn = [p for p in people if p["withdrawn"]]
    lines = [f"study {protocol.name} (protocol {protocol.sha256[:12]}, {len(study.registry['amendments'])} "
             f"amendment(s)); blinding {'on' if protocol.blinding else 'off'}",
             f"enrolled {len(people)} of {protocol.target_n}; withdrawn {len(withdrawn)}; "
             f"complete {sum(len(done_sessions(p)) >= protocol.sessions.per_participant for p in people)}"]
    if show:
        for arm in protocol.arms:
            mine = [p for p in people if study.arm_of(p["pseudonym"]) == arm.name]
            lines.append(f"  arm {arm.name}: {len(mine)} participants, "
                         f"{sum(len(done_sessions(p)) for p in mine)} sessions done")
    else:
        lines.append(f"  sessions done: {sum(len(done_sessions(p)) for p in people)} (per arm: hidden, blinded)")
    overdue = []
    for p in people:
        done = done_sessions(p)
        if p["withdrawn"] or len(done) >= protocol.sessions.per_participant:
            continue
        since = done[-1]["ended"] if done else p["enrolled"]
        gap = days_between(since, now)
        if gap > protocol.sessions.max_days:
            overdue.append(f"{p['pseudonym']}: session {len(done) + 1} overdue ({gap:.1f} days since "
                           f"{'session ' + str(len(done)) if done else 'enrolment'}; max {protocol.sessions.max_days:g})")
    lines += [f"overdue: {len(overdue)}", *(f"  {o}" for o in overdue)]
    for p in withdrawn:
        lines.append(f"withdrawn: {p['pseudonym']} on {p['withdrawn']['time'][:10]} (data {p['withdrawn']['data']})")
    rows = []
    for p in people:
        for s in p["sessions"]:
            q = session_quality(study.sessions_dir / s["folder"]) if s.get("folder") else None
            rows.append({"pseudonym": p["pseudonym"], "arm": study.arm_of(p["pseudonym"]) if show else "blinded", "session": s["number"],
                         "folder": s["folder"], "status": s["status"],
                         "counts": s["status"] in DONE, "outside_interval": s.get("outside_interval", False),
                         **({"turns": q.turns, "turns_eeg": q.with_eeg, "invalid": q.invalid,
                             "interrupted": q.interrupted, "robot_lost": q.robot_lost} if q else
                            {"turns": None, "turns_eeg": None, "invalid": None, "interrupted": None,
                             "robot_lost": None})})
    if rows:
        lines.append("pseudonym  arm            session  status      turns  with EEG  invalid  interrupted  robot lost")
        for r in rows:
            q = [("-" if r[k] is None else str(r[k])) for k in ("turns", "turns_eeg", "invalid", "interrupted",
                                                                   "robot_lost")]
            lines.append(f"{r['pseudonym']:<10} {r['arm']:<14} {r['session']:>7}  {r['status']:<10} {q[0]:>6} "
                         f"{q[1]:>9} {q[2]:>8} {q[3]:>12} {q[4]:>11}" + ("  (outside interval)" if
                                                                          r["outside_interval"] else ""))
    pending = pending_sessions(study)
    if pending:
        lines.append(f"not yet recorded: {len(pending)} session(s) on disk or killed while running; record them "
                     f"with `nao-trainer study repair {study.root}`")
        lines += [f"  {e['pseudonym']} session {e['number']}: {e['folder'] or 'no folder'} ({e['status']})"
                  for e in pending]
    amended = [a for a in study.registry["amendments"] if a.get("changes")]
    for a in amended:
        lines.append(f"amendment {a['time'][:10]} changed what arms do after {a['enrolled_at_amendment']} "
                     f"enrolment(s): {'; '.join(a['changes'])}")
    if study.unblinded:
        lines += [f"unblinded {u['time']} by {u['who']} ({u['reason']})" for u in study.registry["unblindings"]]
    return Status(lines, rows, overdue)
