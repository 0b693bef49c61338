"""``study export --published OUT``: the study in the published dataset's folder layout.

Tools written for the authors' data (Tsiakas et al. 2018; ``data/published.py`` documents the format)
read a new study unchanged: ``OUT/user_<n>/session_<k>/`` with

* ``logfile``: ``turn length rf score success reaction_time completion_time [sequence] [response]``
  (score +level/-level, success +1/-1, letters as Python lists of 'a', 'b', 'c');
* ``state_EEG``: ``length rf previous_score robot_<turn> user_<turn>``;
* with EEG, the raw layout's recordings ``intro`` (the baseline), ``robot_<turn>`` (listening phase) and
  ``user_<turn>`` (answer phase): one ``eeg v1 v2 v3 v4`` line per sample (TP9, AF7, AF8, TP10, microvolts).
  The published data also hold the Muse's own band-power lines; a study recorded over LSL has only the raw
  EEG, so readers compute band powers from it (``nao-trainer engagement --source raw``).

Only completed, valid turns are written (the published sessions have no interrupted turns), numbered
1..N in order. ``user_<n>`` is the participant's number (P007 -> user_7); ``participants.csv`` at the root
maps it to the pseudonym and the arm.
"""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

from nao_trainer.errors import DataError
from nao_trainer.files import write_text_atomic
from nao_trainer.study.bids import read_raw_csv
from nao_trainer.study.registry import Study
from nao_trainer.study.runner import DONE

SCALP = ("TP9", "AF7", "AF8", "TP10")
MAPPING_HEADER = "user_id,pseudonym,arm"  # participants.csv: also how a re-export knows its own folder


def _ours(out: Path) -> bool:
    """A folder this export wrote before (its participants.csv header), so replacing it loses nothing else."""
    try:
        with open(out / "participants.csv", encoding="utf-8") as fh:
            return fh.readline().strip() == MAPPING_HEADER
    except (OSError, UnicodeDecodeError):
        return False


def export_published(study: Study, out: Path) -> str:
    """Write the layout; returns a one-line summary. Refuses a non-empty ``out`` it did not write."""
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not _ours(out):
        raise DataError(f"{out}: not empty and not a study export of nao-trainer; give an empty or new folder")
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    kept = [p for p in study.participants if not (p["withdrawn"] and p["withdrawn"]["data"] == "delete")]
    n_sessions = n_eeg = 0
    mapping = [MAPPING_HEADER]
    for p in kept:
        user = int("".join(ch for ch in p["pseudonym"] if ch.isdigit()))
        mapping.append(f"{user},{p['pseudonym']},{p['arm']}")
        for s in p["sessions"]:
            if s["status"] not in DONE:
                continue
            folder = study.sessions_dir / s["folder"]
            target = out / f"user_{user}" / f"session_{int(s['number'])}"
            target.mkdir(parents=True)
            turns = _turns(folder)
            _write_behaviour(turns, target)
            if (folder / "eeg" / "raw.csv").is_file():
                _write_recordings(folder, turns, target)
                n_eeg += 1
            n_sessions += 1
    write_text_atomic(out / "participants.csv", "\n".join(mapping) + "\n")
    return f"{out}: published layout: {len(kept)} users, {n_sessions} sessions, {n_eeg} with raw EEG"


def _turns(folder: Path) -> list[dict[str, str]]:
    path = folder / "turns.csv"
    if not path.is_file():
        raise DataError(f"{path}: missing; the session cannot be exported (withdraw its data or restore it)")
    with open(path, newline="", encoding="utf-8") as fh:
        return [r for r in csv.DictReader(fh) if r["success"] in ("True", "False") and r.get("invalid") != "True"]


def _letters(text: str) -> str:
    return "[" + ", ".join(repr(ch.lower()) for ch in text) + "]"


def _write_behaviour(turns: list[dict[str, str]], target: Path) -> None:
    log, states = [], []
    previous = 0
    for i, r in enumerate(turns, 1):
        level = int(r["level"])
        ok = r["success"] == "True"
        signed = level if ok else -level
        log.append(f"{i} {r['length']} {r['feedback']} {signed} {1 if ok else -1} {_num(r['reaction_time'])} "
                   f"{_num(r['completion_time'])} {_letters(r['sequence'])} {_letters(r['response'])}")
        states.append(f"{r['length']} {r['feedback']} {previous} robot_{i} user_{i}")
        previous = signed
    write_text_atomic(target / "logfile", "\n".join(log) + "\n")
    write_text_atomic(target / "state_EEG", "\n".join(states) + "\n")


def _num(text: str) -> str:
    return text if text.strip() else "0.0"


def _write_recordings(folder: Path, turns: list[dict[str, str]], target: Path) -> None:
    times, data, names, _rate = read_raw_csv(folder)
    cols = [names.index(c) for c in SCALP if c in names]
    if len(cols) != 4:
        raise DataError(f"{folder / 'eeg' / 'raw.csv'}: needs channels {', '.join(SCALP)}, has {', '.join(names)}")
    eeg = data[cols].T
    phases = _phases(folder)

    def write(name: str, begin: float, end: float) -> None:
        sel = eeg[(times >= begin) & (times <= end)]
        write_text_atomic(target / name, "".join(f"eeg {a:.6f} {b:.6f} {c:.6f} {d:.6f}\n" for a, b, c, d in sel))

    if ("", "baseline") in phases:
        write("intro", *phases[("", "baseline")])
    for i, r in enumerate(turns, 1):
        for phase, prefix in (("listening", "robot"), ("answer", "user")):
            span = phases.get((r["turn"], phase))
            if span is not None:
                write(f"{prefix}_{i}", *span)
            else:
                write_text_atomic(target / f"{prefix}_{i}", "")


def _phases(folder: Path) -> dict[tuple[str, str], tuple[float, float]]:
    path = folder / "eeg" / "phases.csv"
    out: dict[tuple[str, str], tuple[float, float]] = {}
    if not path.is_file():
        return out
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            try:
                out[(r["turn"], r["phase"])] = (float(r["t_begin"]), float(r["t_end"]))
            except (TypeError, ValueError):
                continue
    return out
