"""``study export --bids OUT``: the study as a BIDS-EEG dataset (mne-bids), for sharing.

Per counted session of every participant whose data is kept: ``sub-<pseudonym>/ses-<nn>/``

* ``eeg/``: the raw EEG the session saved (``eeg/raw.csv``, microvolts; channel names and nominal rate
  from ``eeg/stream.json``) written by mne-bids as BrainVision, with ``events.tsv`` from the session's
  markers (``eeg/events.csv``: session and turn events) and the turns' listening and answer phases
  (``eeg/phases.csv``). Sessions without EEG export their behaviour only;
* ``beh/``: the turns (``turns.csv``) as ``*_beh.tsv`` with a JSON sidecar describing every column.

At the root: ``participants.tsv`` (pseudonym, arm, stratum, consent version; never names, contact
details or dates of birth), ``dataset_description.json`` (the protocol's name, hash and arms in
``GeneratedBy``), ``README``, and the frozen protocol itself under ``code/``.
"""
from __future__ import annotations

import csv
import datetime as dt
import json
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer import __version__
from nao_trainer.data import own
from nao_trainer.errors import DataError
from nao_trainer.files import read_json, write_json_atomic, write_text_atomic
from nao_trainer.study.registry import PROTOCOL_FILE, Study
from nao_trainer.study.runner import DONE

#: The label of a task without ``bids_name`` is its name's letters and digits (BIDS labels are alphanumeric).
#: turns.csv column -> (BIDS sidecar description, unit or None).
BEH_COLUMNS: dict[str, tuple[str, str | None]] = {
    "turn": ("turn number within the session, 1..N", None),
    "start_time": ("wall-clock time the turn started (ISO 8601)", None),
    "state": ("MDP turn-state index (level-1)*27 + feedback*9 + previous_score+4 (nao_trainer/core/mdp.py)", None),
    "length": ("sequence length: 3, 5, 7 or 9 letters", None),
    "level": ("difficulty level 1-4 (length 3/5/7/9)", None),
    "feedback": ("feedback spoken before the turn: 0 none, 1 encouraging, 2 challenging", None),
    "previous_score": ("signed score of the previous turn (+level or -level; 0 for the first)", None),
    "action": ("the policy's action that produced this turn: L1-L4 (a new sequence), RF1/RF2 (feedback)", None),
    "sequence": ("the letters the robot said (A, B, C)", None),
    "response": ("the letters the participant entered", None),
    "success": ("True when the response equals the sequence; empty when the turn was interrupted", None),
    "score": ("equation (1) of Tsiakas et al. 2018: +level on success, -1 on failure", None),
    "signed_score": ("+level on success, -level on failure", None),
    "reaction_time": ("time from the start of the answer window to the first press", "s"),
    "completion_time": ("time from the start of the answer window to the last press", "s"),
    "engagement": ("normalised task engagement of the listening phase, 0-1 (empty: no usable EEG)", None),
    "engagement_index": ("mean engagement index beta/(alpha+theta) of the listening phase", None),
    "eeg_quality": ("fraction of the listening phase with clean EEG", None),
    "answer_engagement": ("normalised engagement while the participant answered", None),
    "engagement_note": ("why the turn has no engagement value, if it has none", None),
    "notes": ("operator or session notes on the turn (interruptions, overrides)", None),
    "invalid": ("True when the operator marked the turn invalid", None),
    "replay": ("True when the turn replays one interrupted before", None),
    "phase": ("what the policy said the turn was for (e.g. assessment)", None),
}


@dataclass(frozen=True)
class TaskInfo:
    """What BIDS says of a session's task: its label, description and column descriptions."""

    label: str
    description: str
    columns: dict[str, tuple[str, str | None]]


def task_info(folder: Path) -> TaskInfo:
    """The BIDS view of the task a session played (``Task.bids_name``, ``description``, ``column_docs``)."""
    task = own.session_task(own.read_session(folder))
    label = getattr(task, "bids_name", None) or re.sub(r"[^A-Za-z0-9]", "", task.name)
    docs = {**BEH_COLUMNS, **dict(getattr(task, "column_docs", {}) or {})}
    return TaskInfo(label, str(getattr(task, "description", "") or f"the {task.name} task with a NAO robot"), docs)


def _mne() -> tuple[Any, Any]:
    try:
        import mne
        import mne_bids
    except ImportError as exc:
        raise DataError(f"BIDS export needs mne and mne-bids ({exc}); pip install 'nao-trainer[study]'") from None
    return mne, mne_bids


def _ours(out: Path) -> bool:
    """A dataset this export wrote before (``GeneratedBy`` names nao-trainer): only that one is replaced."""
    try:
        generated = json.loads((out / "dataset_description.json").read_text(encoding="utf-8")).get("GeneratedBy")
        return isinstance(generated, list) and any(isinstance(g, dict) and g.get("Name") == "nao-trainer"
                                                   for g in generated)
    except (OSError, ValueError, AttributeError):
        return False


def export_bids(study: Study, out: Path) -> str:
    """Write the BIDS dataset; returns a one-line summary. Refuses a non-empty ``out`` it did not write."""
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not _ours(out):
        raise DataError(f"{out}: not empty and not a BIDS dataset exported by nao-trainer; give an empty or new "
                        "folder")
    mne, mne_bids = _mne()
    mne.set_log_level("ERROR")
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    eeg_n = beh_n = 0
    tasks: dict[str, str] = {}
    kept = [p for p in study.participants if not (p["withdrawn"] and p["withdrawn"]["data"] == "delete")]
    for p in kept:
        for s in p["sessions"]:
            if s["status"] not in DONE:
                continue
            folder = study.sessions_dir / s["folder"]
            sub, ses = p["pseudonym"], f"{int(s['number']):02d}"
            task = task_info(folder)
            tasks[task.label] = task.description
            if (folder / "eeg" / "raw.csv").is_file():
                _write_eeg(mne, mne_bids, folder, out, sub, ses, task)
                eeg_n += 1
            _write_beh(folder, out, sub, ses, task)
            beh_n += 1
    _write_root(study, out, kept, tasks)
    return f"{out}: BIDS dataset: {len(kept)} participants, {beh_n} sessions of behaviour, {eeg_n} with EEG"


def read_raw_csv(folder: Path) -> tuple[np.ndarray, np.ndarray, list[str], float]:
    """(times, data (channels, samples) in microvolts, channel names, nominal rate) of a session's EEG."""
    stream = read_json(folder / "eeg" / "stream.json", DataError)
    path = folder / "eeg" / "raw.csv"
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], [r for r in rows[1:] if len(r) == len(rows[0])]
    if len(body) < 2:
        raise DataError(f"{path}: fewer than 2 samples; the session has no EEG to export")
    values = np.array(body, dtype=float)
    return values[:, 0], values[:, 1:].T, header[1:], float(stream.get("nominal_srate") or 256.0)


def _annotations(folder: Path, t0: float) -> list[tuple[float, float, str]]:
    """(onset s, duration s, description) from the markers and the turns' phases."""
    out = []
    events = folder / "eeg" / "events.csv"
    if events.is_file():
        with open(events, newline="", encoding="utf-8") as fh:
            for r in csv.DictReader(fh):
                try:
                    onset = float(r["lsl_time"]) - t0
                except (TypeError, ValueError):
                    continue
                if onset >= 0:
                    out.append((onset, 0.0, r["event"]))
    phases = folder / "eeg" / "phases.csv"
    if phases.is_file():
        with open(phases, newline="", encoding="utf-8") as fh:
            for r in csv.DictReader(fh):
                try:
                    begin, end = float(r["t_begin"]) - t0, float(r["t_end"]) - t0
                except (TypeError, ValueError):
                    continue
                if begin >= 0 and end >= begin:
                    turn = f"/turn{r['turn']}" if r["turn"] else ""
                    out.append((begin, end - begin, f"{r['phase']}{turn}"))
    return sorted(out)


def _write_eeg(mne: Any, mne_bids: Any, folder: Path, out: Path, sub: str, ses: str, task: TaskInfo) -> None:
    times, data, names, rate = read_raw_csv(folder)
    info = mne.create_info(names, rate, ch_types=["eeg" if n.upper() != "RIGHT AUX" and "AUX" not in n.upper()
                                                  else "misc" for n in names])
    raw = mne.io.RawArray(data * 1e-6, info, verbose="ERROR")  # Muse/LSL values are microvolts
    started = _started(folder)
    if started is not None:
        raw.set_meas_date(started)
    raw.info["line_freq"] = 50.0
    length = data.shape[1] / rate  # markers after the last sample (the goodbye) are left out
    notes = [(o, min(d, length - o - 1.0 / rate), text) for o, d, text in _annotations(folder, float(times[0]))
             if o < length - 1.0 / rate]
    if notes:
        raw.set_annotations(mne.Annotations([n[0] for n in notes], [n[1] for n in notes], [n[2] for n in notes]))
    path = mne_bids.BIDSPath(subject=sub, session=ses, task=task.label, datatype="eeg", root=out)
    mne_bids.write_raw_bids(raw, path, format="BrainVision", allow_preload=True, overwrite=True, verbose="ERROR")
    sidecar = path.copy().update(suffix="eeg", extension=".json")
    meta = json.loads(Path(sidecar.fpath).read_text(encoding="utf-8"))
    meta.update(EEGReference="Fpz (Muse reference electrode)", EEGGround="Fpz region (Muse)",
                Manufacturer="InteraXon (Muse)", TaskDescription=task.description,
                SoftwareFilters="n/a", PowerLineFrequency=50)
    write_json_atomic(sidecar.fpath, meta)


def _started(folder: Path) -> dt.datetime | None:
    info = read_json(folder / "session.json", DataError)
    try:
        when = dt.datetime.fromisoformat(str(info.get("started")))
    except ValueError:
        return None
    return when.astimezone(dt.timezone.utc)


def _write_beh(folder: Path, out: Path, sub: str, ses: str, task: TaskInfo) -> None:
    path = folder / "turns.csv"
    if not path.is_file():
        raise DataError(f"{path}: missing; the session cannot be exported (withdraw its data or restore it)")
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    docs = task.columns
    columns = [c for c in (rows[0] if rows else docs) if c in docs]
    target = out / f"sub-{sub}" / f"ses-{ses}" / "beh"
    target.mkdir(parents=True, exist_ok=True)
    stem = f"sub-{sub}_ses-{ses}_task-{task.label}_beh"

    def cell(v: str | None) -> str:
        v = (v or "").replace("\t", " ").replace("\n", " ")
        return v if v != "" else "n/a"
    lines = ["\t".join(columns)] + ["\t".join(cell(r.get(c)) for c in columns) for r in rows]
    write_text_atomic(target / f"{stem}.tsv", "\n".join(lines) + "\n")
    sidecar: dict[str, Any] = {"TaskName": task.label, "TaskDescription": task.description}
    for c in columns:
        desc, unit = docs[c]
        sidecar[c] = {"Description": desc, **({"Units": unit} if unit else {})}
    write_json_atomic(target / f"{stem}.json", sidecar)


def _write_root(study: Study, out: Path, kept: list[dict[str, Any]], tasks: dict[str, str]) -> None:
    protocol = study.protocol
    rows = ["participant_id\tarm\tstratum\tconsent_version"]
    rows += [f"sub-{p['pseudonym']}\t{p['arm']}\t{p['stratum'] or 'n/a'}\t{p['consent_version']}" for p in kept]
    write_text_atomic(out / "participants.tsv", "\n".join(rows) + "\n")
    write_json_atomic(out / "participants.json", {
        "participant_id": {"Description": "the study's pseudonym (no names or contact details are kept)"},
        "arm": {"Description": "allocated arm (blocked randomisation)",
                "Levels": {a.name: f"policy {a.policy}" for a in protocol.arms}},
        "stratum": {"Description": "stratum of the allocation (n/a: none)"},
        "consent_version": {"Description": "version of the consent form signed"}})
    arms = "; ".join(f"{a.name}: policy {a.policy}" for a in protocol.arms)
    write_json_atomic(out / "dataset_description.json", {
        "Name": f"{protocol.name}: {protocol.description}"[:200], "BIDSVersion": "1.9.0", "DatasetType": "raw",
        "GeneratedBy": [{"Name": "nao-trainer", "Version": __version__,
                         "Description": f"study protocol {protocol.name} (sha256 {protocol.sha256}, "
                                        f"{len(study.registry['amendments'])} amendment(s)); arms {arms}; "
                                        f"{protocol.sessions.per_participant} sessions per participant; model "
                                        f"{protocol.analysis.model}; the protocol is code/{PROTOCOL_FILE}"}]})
    (out / "code").mkdir(exist_ok=True)
    shutil.copyfile(study.root / PROTOCOL_FILE, out / "code" / PROTOCOL_FILE)
    readme = [f"# {protocol.name}", "", protocol.description, "",
              f"Exported by nao-trainer {__version__} (`nao-trainer study export --bids`). Task: "
              + ("; ".join(f"{label}: {text}" for label, text in sorted(tasks.items())) or "none exported") + ".",
              f"Protocol sha256 {protocol.sha256}; arms: {arms}.",
              "Sessions without EEG hold their behaviour (beh/) only."]
    write_text_atomic(out / "README", "\n".join(readme) + "\n")
