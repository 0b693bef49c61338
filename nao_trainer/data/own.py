"""Sessions written by ``nao-trainer run``, read back as data.

A session folder ``<study>/<pseudonym>_<YYYYmmdd-HHMMSS>[_n]/`` (``session/record.py``) holds
``session.json`` (format ``nao-trainer/session``, version :data:`FORMAT_VERSION`; older folders have no
version and count as version 1), ``turns.csv`` (one row per turn, interrupted turns included),
``events.jsonl`` and, with EEG, ``eeg/`` (the live monitor's files: ``stream.json``, ``raw.csv``,
``phases.csv``, ``windows.csv``, ``events.csv``, ``gaps.csv``) and ``session.xdf``.

Two things are read here:

* the turns, converted to the encodings of the tidy turn table (``data/dataset.py``): success 0/1,
  the action as its ``core.mdp`` index. A turn that was interrupted, or whose fields contradict
  each other, is kept out with the reason (:class:`Excluded`);
* the per-turn engagement, **recomputed from the raw EEG the session saved** (``eeg/raw.csv``) with
  the processing settings the session used (``eeg/stream.json``), replaying the session's phases
  (``eeg/phases.csv``) in order through the same code as the live monitor
  (``core.engagement.OnlineEngagement`` and ``core.phase.summarise_phase``), with a fresh estimator and
  scale where the session started them (``eeg/segments.csv``, ``monitor_started``: a resumed session).
  For a session recorded by this version the result equals the live values in ``phases.csv`` (tested
  to 1e-9).

A torn last line (a killed session) is dropped and said; a malformed row of turns.csv or phases.csv
is left out and said (file:line), the valid rows are kept; anything else malformed is a one-line
``DataError`` naming the file and line. Files larger than any session writes (:data:`MAX_JSON_BYTES`,
:data:`MAX_CSV_BYTES`, :data:`MAX_RAW_BYTES`) are refused before they are read; ``raw.csv`` is read in
blocks, so memory stays near the size of its samples.
"""
from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.core import mdp, task
from nao_trainer.core.eeg import Processing
from nao_trainer.core.engagement import OnlineEngagement, WindowResult
from nao_trainer.core.montage import thresholds_from
from nao_trainer.core.phase import EngagementNormaliser, summarise_phase
from nao_trainer.data.engagement import SessionEngagement, TurnEngagement, TurnSeries
from nao_trainer.data.raw_csv import MAX_RAW_BYTES, read_raw  # noqa: F401 - read_raw is part of this module's API
from nao_trainer import registry
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import read_json, read_text

FORMAT = "nao-trainer/session"
FORMAT_VERSION = 1
#: turns.csv columns the reader needs (the file has more; see ``session/record.py``).
TURN_FIELDS = ("turn", "state", "length", "level", "feedback", "previous_score", "action", "sequence", "response",
               "success", "score", "signed_score", "reaction_time", "completion_time", "engagement",
               "engagement_index", "eeg_quality", "engagement_note", "notes")
PHASE_FIELDS = ("turn", "phase", "t_begin", "t_end", "engagement", "engagement_index")
#: Largest files read (bytes; docs/reference/data.md). session.json / stream.json are a few kB; turns.csv holds ~300 bytes a
#: turn, phases.csv ~200 a phase; raw.csv: ``data.raw_csv.MAX_RAW_BYTES``.
MAX_JSON_BYTES = 16_000_000
MAX_CSV_BYTES = 64_000_000
#: Turn numbers a session can have (1..MAX_TURN); others are refused (a crafted or corrupt row).
MAX_TURN = 100_000
_STAMP = re.compile(r"_\d{8}-\d{6}(?:_\d+)?$")


def is_own_session(path: Path) -> bool:
    """A folder written by ``nao-trainer run``: it has a ``session.json``."""
    return Path(path).is_dir() and (Path(path) / "session.json").is_file()


def find_own_sessions(root: Path) -> list[Path]:
    """``root`` itself when it is a session, else the session folders up to two levels below it."""
    root = Path(root)
    if is_own_session(root):
        return [root]
    found = {p.parent for pattern in ("*/session.json", "*/*/session.json") for p in root.glob(pattern)}
    return sorted(p for p in found if is_own_session(p))


def session_id(path: Path) -> str:
    """The session's folder name (``<pseudonym>_<stamp>``): unique within a study."""
    return Path(path).resolve().name


# ----------------------------------------------------------------------------------------------
# session.json and turns.csv
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Excluded:
    """A turn kept in the record (turns.csv) but left out of the turn table and the models."""

    session: str
    turn: int
    reason: str

    def __str__(self) -> str:
        return f"{self.session} turn {self.turn}: {self.reason}"


@dataclass
class OwnSession:
    """One session folder of ``nao-trainer run``: its metadata and its turns.csv rows (as text)."""

    path: Path
    info: dict[str, Any]
    rows: list[dict[str, str]]
    notes: list[str] = field(default_factory=list)  # e.g. a torn last line that was dropped

    @property
    def id(self) -> str:
        return session_id(self.path)

    @property
    def pseudonym(self) -> str:
        cfg = self.info.get("config") if isinstance(self.info.get("config"), dict) else {}
        values = cfg.get("values", cfg) if isinstance(cfg, dict) else {}
        p = (values.get("participant") or {}).get("pseudonym") if isinstance(values, dict) else None
        return str(p) if p else _STAMP.sub("", self.id)

    @property
    def study(self) -> str:
        """``study.name`` of the configuration the session ran with ("" when not recorded)."""
        cfg = self.info.get("config") if isinstance(self.info.get("config"), dict) else {}
        values = cfg.get("values", cfg) if isinstance(cfg, dict) else {}
        study = values.get("study") if isinstance(values, dict) else None
        name = study.get("name") if isinstance(study, dict) else None
        return str(name)[:200] if name else ""

    @property
    def task(self) -> str:
        """``task.name`` of the configuration the session ran with; when not recorded (older folders, from before
        the task was a setting) the setting's default, as for a config that names none (the sequence task)."""
        cfg = self.info.get("config") if isinstance(self.info.get("config"), dict) else {}
        values = cfg.get("values", cfg) if isinstance(cfg, dict) else {}
        section = values.get("task") if isinstance(values, dict) else None
        name = section.get("name") if isinstance(section, dict) else None
        return str(name)[:100] if name else registry.default("task")

    @property
    def input(self) -> str:
        """Who answered: ``simulated`` (a simulated participant), ``tactile`` or ``keyboard`` (a person)."""
        kind = self.info.get("input")
        return str(kind)[:40] if kind else "unknown"

    @property
    def status(self) -> str:
        status = str(self.info.get("status", "?"))
        return "incomplete (no end recorded: killed?)" if status == "running" else status


def read_info(path: Path) -> dict[str, Any]:
    """``session.json``, its format and version checked (a newer version is refused, not guessed)."""
    info = read_json(Path(path) / "session.json", DataError, max_bytes=MAX_JSON_BYTES)
    if not isinstance(info, dict):
        raise DataError(f"{Path(path) / 'session.json'}: not a session record (expected a JSON object)")
    fmt, version = info.get("format", FORMAT), info.get("format_version", 1)
    if fmt != FORMAT:
        raise DataError(f"{Path(path) / 'session.json'}: format {fmt!r} is not {FORMAT!r}")
    if not isinstance(version, int) or version > FORMAT_VERSION or version < 1:
        raise DataError(f"{Path(path) / 'session.json'}: format_version {version!r} is unknown to this nao-trainer "
                        f"(reads 1..{FORMAT_VERSION}); upgrade nao-trainer to read it")
    return info


def _csv_rows(path: Path, required: tuple[str, ...], notes: list[str]) -> list[dict[str, str]]:
    """Rows of a CSV file written line by line; a torn last line is dropped (and noted), others are errors."""
    text = read_text(path, DataError, max_bytes=MAX_CSV_BYTES)
    lines = text.splitlines()
    if not lines:
        raise DataError(f"{path}: empty (no header)")
    header = next(csv.reader([lines[0]]))
    missing = [c for c in required if c not in header]
    if missing:
        raise DataError(f"{path}:1: missing columns {', '.join(missing)}")
    rows = []
    try:
        records = list(csv.reader(io.StringIO(text)))[1:]
    except csv.Error as exc:
        raise DataError(f"{path}: not a readable CSV file ({exc})") from None
    complete = text.endswith("\n")  # every row is written whole, newline included: a missing one is a torn write
    for k, rec in enumerate(records, 2):
        last = k == len(records) + 1
        if not rec and not last:
            continue
        if last and (not complete or len(rec) != len(header)):
            if rec:
                notes.append(f"{path.name} line {k} torn ({len(rec)} of {len(header)} fields): dropped")
            break
        if len(rec) != len(header):  # a garbage line: left out and said, the valid rows are kept
            notes.append(f"{path.name}:{k}: expected {len(header)} fields, got {len(rec)}: line left out")
            continue
        rows.append(dict(zip(header, rec)))
    return rows


def read_session(path: Path) -> OwnSession:
    """Read one session folder (metadata and turns); DataError when it cannot be read at all."""
    path = Path(path)
    info = read_info(path)
    notes: list[str] = []
    turns = path / "turns.csv"
    session = OwnSession(path, info, [], notes)
    columns = session_task(session).columns  # a task writes the common columns and its own (tasks.base)
    required = tuple(f for f in TURN_FIELDS if f in columns)
    session.rows = _csv_rows(turns, required, notes) if turns.is_file() else []
    if not turns.is_file():
        notes.append("no turns.csv")
    return session


def session_task(session: OwnSession) -> Any:
    """The task class the session played (the registry's); one DataError line when it is not installed."""
    try:
        return registry.load("task", session.task)
    except ConfigError as exc:
        raise DataError(f"{session.path / 'session.json'}: the session's task cannot be read: {exc}") from None


# ----------------------------------------------------------------------------------------------
# Turns -> tidy turn-table rows
# ----------------------------------------------------------------------------------------------


def _int(v: str, what: str) -> int:
    try:
        return int(v)
    except ValueError:
        raise ValueError(f"invalid: {what} {v!r} is not a whole number") from None


def _float(v: str) -> float:
    try:
        return float(v) if v.strip() else math.nan
    except ValueError:
        return math.nan


def _turn_row(r: dict[str, str]) -> dict[str, Any]:
    """One completed turn in the table's encodings; ValueError saying why it is invalid."""
    marked = r.get("invalid", "").strip()
    if marked == "True":  # the operator marked it (recorded, not learned from)
        said = next((n.strip() for n in r.get("notes", "").split(";") if n.strip().startswith("invalid (")), "")
        raise ValueError(f"invalid: marked by the operator{f' ({said})' if said else ''}")
    if marked not in ("", "False"):  # never counted as valid on a guess
        raise ValueError(f"invalid: column 'invalid' is {marked[:40]!r}, not True/False")
    number = _int(r["turn"], "turn")
    if not 1 <= number <= MAX_TURN:
        raise ValueError(f"invalid: turn number {r['turn'][:30]!r} is not in 1..{MAX_TURN}")
    if r["success"] not in ("True", "False"):
        notes = r.get("notes", "")
        why = next((n.strip() for n in notes.split(";") if n.strip().startswith("interrupted")), "")
        raise ValueError(why or f"no outcome (success {r['success']!r})")
    ok = r["success"] == "True"
    state = _int(r["state"], "state")
    if not 0 <= state < mdp.N_TURN_STATES:
        raise ValueError(f"invalid: state {state} is not in 0..{mdp.N_TURN_STATES - 1}")
    st = mdp.decode(state)
    parts = {"length": st.length, "level": st.level, "feedback": st.feedback, "previous_score": st.previous}
    for name, want in parts.items():
        if name in r and _int(r[name], name) != want:  # length: a column of the sequence task only
            raise ValueError(f"invalid: {name} {r[name]} contradicts state {state} ({mdp.state_label(state)})")
    if r["action"] not in mdp.ACTION_NAMES:
        raise ValueError(f"invalid: unknown action {r['action']!r} (known: {', '.join(mdp.ACTION_NAMES)})")
    if "sequence" in r and len(r["sequence"]) != st.length:  # the sequence task's letters: L of them
        raise ValueError(f"invalid: sequence {r['sequence']!r} is not {st.length} letters long")
    score, signed = task.score(st.level, ok), task.signed_score(st.level, ok)
    if _int(r["score"], "score") != score or _int(r["signed_score"], "signed_score") != signed:
        raise ValueError(f"invalid: score {r['score']}/{r['signed_score']} contradicts level {st.level} and success {ok}")
    return {
        "turn": number, "state": state, **parts, "action": mdp.ACTION_NAMES.index(r["action"]),
        "sequence": r.get("sequence", ""), "response": r["response"], "success": int(ok), "score": score,
        "signed_score": signed, "reaction_time": _float(r["reaction_time"]),
        "completion_time": _float(r["completion_time"]),
    }


def table_rows(session: OwnSession, engagement: "dict[int, Any] | None" = None
               ) -> tuple[list[dict[str, Any]], list[Excluded]]:
    """The session's completed, valid turns as turn-table rows, and the turns left out with why.

    ``engagement``: turn -> ``data.engagement.TurnEngagement`` (the offline re-analysis); without one
    (or for a turn it lacks) the live values of turns.csv are used.
    """
    out: list[dict[str, Any]] = []
    excluded: list[Excluded] = []
    for r in session.rows:
        try:
            row = _turn_row(r)
        except ValueError as exc:
            excluded.append(Excluded(session.id, _turn_number(r), str(exc)))
            continue
        t = (engagement or {}).get(row["turn"])
        if t is not None:
            eeg = (_nan(t.engagement_index), _nan(t.engagement), float(t.quality), t.reason)
        else:
            eeg = (_float(r["engagement_index"]), _float(r["engagement"]), _float(r["eeg_quality"]),
                   r.get("engagement_note", "") or ("" if r["engagement"] else "no EEG"))
        out.append({"session": session.id, "pseudonym": session.pseudonym, "study": session.study,
                    "input": session.input, **row,
                    "engagement_index": eeg[0], "engagement": eeg[1],
                    "eeg_quality": 0.0 if math.isnan(eeg[2]) else eeg[2], "contact": math.nan, "eeg_note": eeg[3]})
    return out, excluded


def _turn_number(r: dict[str, str]) -> int:
    try:
        n = int(r.get("turn", "0"))
    except ValueError:
        return 0
    return n if 1 <= n <= MAX_TURN else 0


def _nan(v: float | None) -> float:
    return math.nan if v is None else float(v)


# ----------------------------------------------------------------------------------------------
# Offline engagement: replay the session's phases over its raw EEG
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ReplayedPhase:
    """One row of phases.csv recomputed: the live values beside the offline ones."""

    turn: int | None
    phase: str
    t_begin: float
    t_end: float
    live_engagement: float | None
    live_index: float | None
    engagement: float | None
    index: float | None
    quality: float
    reason: str
    series: TurnSeries | None = None  # per window: seconds from the phase start, raw, smoothed, normalised E


def _processing(stream: dict[str, Any], path: Path) -> Processing:
    proc = stream.get("processing")
    if not isinstance(proc, dict):
        raise DataError(f"{path}: no 'processing' settings; the session's EEG cannot be re-analysed")
    known = {f.name for f in fields(Processing)}
    return Processing.from_mapping({k: v for k, v in proc.items() if k in known})


def _opt(v: str) -> float | None:
    return float(v) if v.strip() else None


def replay_phases(session_dir: Path) -> tuple[list[ReplayedPhase], list[str]]:
    """Recompute every phase of ``eeg/phases.csv`` from ``eeg/raw.csv`` as the live monitor did.

    Raises DataError when the session has no EEG record (no ``eeg/`` folder, no stream or phases file).
    """
    eeg = Path(session_dir) / "eeg"
    if not eeg.is_dir():
        raise DataError(f"{session_dir}: no eeg/ folder (EEG was off, or the folder was removed)")
    stream = read_json(eeg / "stream.json", DataError, missing="no EEG stream was recorded (stream.json missing)",
                       max_bytes=MAX_JSON_BYTES)
    if not isinstance(stream, dict):
        raise DataError(f"{eeg / 'stream.json'}: not a stream description (expected a JSON object)")
    proc = _processing(stream, eeg / "stream.json")
    labels = stream.get("scalp_channels")
    fs = stream.get("nominal_srate")
    if (not isinstance(labels, list) or not labels or not all(isinstance(v, str) for v in labels)
            or not isinstance(fs, (int, float)) or isinstance(fs, bool) or not math.isfinite(fs) or fs <= 0):
        raise DataError(f"{eeg / 'stream.json'}: needs scalp_channels (a list of channel names) and a finite "
                        "nominal_srate > 0")
    labels, fs = list(labels), float(fs)
    try:  # the device's quality thresholds as the session applied them (a Muse's in older sessions)
        thresholds = thresholds_from((stream.get("montage") or {}).get("thresholds")
                                     if isinstance(stream.get("montage"), dict) else None)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{eeg / 'stream.json'}: montage.thresholds is not valid ({exc})") from None
    notes: list[str] = []
    phases = _csv_rows(eeg / "phases.csv", PHASE_FIELDS, notes) if (eeg / "phases.csv").is_file() else []
    windows: list[WindowResult] = []
    if (eeg / "raw.csv").is_file():
        x, ts, raw_notes = read_raw(eeg / "raw.csv", len(labels))
        notes += raw_notes
        starts = _segment_starts(eeg / "segments.csv", notes)
        cuts = [0, *sorted({int(np.searchsorted(ts, t)) for t in starts} - {0}), len(ts)]
        for a, b in zip(cuts[:-1], cuts[1:]):  # a fresh estimator where the monitor started one
            if b > a:
                engine = OnlineEngagement(fs, len(labels), window_s=proc.window_s, hop_s=proc.hop_s, a=proc.ewma_a,
                                          thresholds=thresholds,
                                          min_clean_channels=min(proc.min_clean_channels, len(labels)),
                                          gap_factor=max(2.0, proc.gap_tolerance_s * fs), channel_names=labels)
                windows += engine.push(x[a:b], ts[a:b])
    t_end = np.array([w.t_end for w in windows])
    normaliser, had_baseline, monitor = EngagementNormaliser(), False, None
    out: list[ReplayedPhase] = []
    for k, p in enumerate(phases, 2):
        try:
            t0, t1 = float(p["t_begin"]), float(p["t_end"])
            last = _opt(p.get("last_sample") or "")
            live_e, live_i = _opt(p["engagement"]), _opt(p["engagement_index"])
            turn = int(p["turn"]) if p["turn"].strip() else None
        except ValueError as exc:
            raise DataError(f"{eeg / 'phases.csv'}:{k}: {exc}") from None
        if not (math.isfinite(t0) and math.isfinite(t1) and t0 <= t1) or (last is not None and not math.isfinite(last)):
            raise DataError(f"{eeg / 'phases.csv'}:{k}: t_begin {p['t_begin'][:30]!r} and t_end {p['t_end'][:30]!r} must "
                            "be finite times with t_begin <= t_end (corrupt or edited)")
        if turn is not None and not 1 <= turn <= MAX_TURN:
            raise DataError(f"{eeg / 'phases.csv'}:{k}: turn {p['turn'][:30]!r} is not in 1..{MAX_TURN}")
        upto = t1 if last is None else min(t1, last)
        lo, hi = np.searchsorted(t_end, t0, side="right"), np.searchsorted(t_end, upto, side="right")
        if p.get("monitor_started", "") != monitor:  # a new monitor (a resumed session): a new scale
            normaliser, had_baseline, monitor = EngagementNormaliser(), False, p.get("monitor_started", "")
        had_baseline = had_baseline or p["phase"] == "baseline"
        s = summarise_phase(windows[lo:hi], t0, t1, normaliser, baseline=p["phase"] == "baseline",
                            had_baseline=had_baseline, hop_s=proc.hop_s, min_quality=proc.min_quality)
        inside = windows[lo:hi]
        series = TurnSeries(np.array([w.t_end - t0 for w in inside]),
                            np.array([np.nan if w.index_raw is None else w.index_raw for w in inside], dtype=float),
                            s.smoothed, s.normalised)
        out.append(ReplayedPhase(turn, p["phase"], t0, t1, live_e, live_i, s.engagement, s.index,
                                 round(s.quality, 4), s.reason, series))
    return out, notes


def _segment_starts(path: Path, notes: list[str]) -> list[float]:
    """First sample of every estimator run the monitor started (``eeg/segments.csv``; none in older folders)."""
    if not path.is_file():
        return []
    out = []
    for k, row in enumerate(_csv_rows(path, ("first_sample",), notes), 2):
        try:
            out.append(float(row["first_sample"]))
        except ValueError:
            raise DataError(f"{path}:{k}: first_sample {row['first_sample']!r} is not a number") from None
    return out


def own_session_engagement(session_dir: Path, answer: bool = False) -> SessionEngagement:
    """Per-turn engagement of a ``run`` session, recomputed from its raw EEG (``data.engagement`` types).

    One row per turn of turns.csv; a turn played twice (interrupted, then replayed) takes the phase of
    its last play. Without an EEG record every turn is empty, with the reason.
    """
    session_dir = Path(session_dir)
    sess = read_session(session_dir)
    numbers = list(dict.fromkeys(_turn_number(r) for r in sess.rows))
    try:
        phases, _notes = replay_phases(session_dir)
        why = ""
    except DataError as exc:
        phases, why = [], str(exc)
    last: dict[tuple[int, str], ReplayedPhase] = {}
    for ph in phases:
        if ph.turn is not None:
            last[(ph.turn, ph.phase)] = ph
    turns = []
    for n in numbers:
        lis, ans = last.get((n, "listening")), last.get((n, "answer"))
        extra = {}
        if answer:
            extra = dict(answer_index=ans.index if ans else None, answer_engagement=ans.engagement if ans else None,
                         answer_quality=ans.quality if ans else None,
                         answer_reason=(ans.reason if ans else why or "no answer phase"))
        if lis is None:
            turns.append(TurnEngagement(n, None, None, 0.0, None, why or "no listening phase recorded", **extra))
        else:
            turns.append(TurnEngagement(n, lis.index, lis.engagement, lis.quality, None, lis.reason, **extra))
    series = {n: ph.series for (n, kind), ph in last.items() if kind == "listening" and ph.series is not None}
    return SessionEngagement(sess.id, session_dir, None, "raw", "session baseline + running bounds (live rule)",
                             turns, series, answer)
