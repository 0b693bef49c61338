"""The study folder: the frozen protocol, the concealed allocation sequence and the participant registry.

``STUDY_DIR/`` holds

* ``protocol.yaml``: the protocol's text as initialised (or last amended); its SHA-256 is in the registry;
* ``allocation.json``: the blocked-randomisation sequence per stratum (checksummed). It is written once,
  at ``init``, and read only to allocate the next participant: no command prints it (concealment);
* ``registry.json``: checksummed (``files.JsonFormat``): the protocol's hash and origin, amendments (time,
  reason, old and new hash), participants (pseudonym, arm, stratum, consent date and version, enrolment
  time, withdrawal, sessions). Never names or contact details;
* ``sessions/``: the session folders ``study next`` writes (and ``participants/`` learning states).

An edited or torn file is refused in one line (exit 2). Changes are read-modify-write under a file lock,
so two operators enrolling at once cannot lose an entry.
"""
from __future__ import annotations

import contextlib
import datetime as dt
import fcntl
import hashlib
import json
import os
import re
import shutil
import socket
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import JsonFormat, read_text, write_text_atomic
from nao_trainer.policies.participant_state import participant_dir
from nao_trainer.study.protocol import Protocol, load_protocol, protocol_hash

REGISTRY = JsonFormat("nao-trainer/study-registry", 1, "study registry", "study registry",
                      "restore the file from a backup; it must not be edited by hand")
ALLOCATION = JsonFormat("nao-trainer/study-allocation", 1, "allocation sequence", "allocation",
                        "restore the file from a backup; it must not be edited by hand")
PROTOCOL_FILE, REGISTRY_FILE, ALLOCATION_FILE = "protocol.yaml", "registry.json", "allocation.json"
SESSIONS = "sessions"
DATA_CHOICES = ("keep", "delete")


def now_iso() -> str:
    return dt.datetime.now(dt.timezone.utc).astimezone().isoformat(timespec="seconds")


def allocation_sequence(protocol: Protocol) -> dict[str, list[str]]:
    """Blocked randomisation: per stratum, random permutations of one block until ``target_n`` is covered.

    A block holds every arm ``ratio x block_size / sum(ratios)`` times, so after each full block the arms
    are in exact balance. One ``numpy`` generator seeded by ``allocation.seed`` draws the strata in order:
    the same protocol always gives the same sequence.
    """
    rng = np.random.default_rng(protocol.allocation.seed)
    rounds = protocol.allocation.block_size // sum(a.ratio for a in protocol.arms)
    block = [a.name for a in protocol.arms for _ in range(a.ratio * rounds)]
    n_blocks = -(-protocol.target_n // len(block))
    return {key: [block[i] for _ in range(n_blocks) for i in rng.permutation(len(block))]
            for key in protocol.allocation.stratum_keys()}


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass
class Study:
    """A study folder, verified: its protocol, registry payload and allocation payload."""

    root: Path
    protocol: Protocol
    registry: dict[str, Any]
    allocation: dict[str, Any]

    @property
    def sessions_dir(self) -> Path:
        return self.root / SESSIONS

    @property
    def participants(self) -> list[dict[str, Any]]:
        return self.registry["participants"]

    def participant(self, pseudonym: str) -> dict[str, Any]:
        for p in self.participants:
            if p["pseudonym"] == pseudonym:
                return p
        known = ", ".join(p["pseudonym"] for p in self.participants) or "none yet"
        raise DataError(f"{self.root}: pseudonym {pseudonym!r} is not enrolled in this study (enrolled: {known}); "
                        "enrol with `nao-trainer study enrol`")

    def check_study_config(self) -> None:
        """The study configuration the arms start from must be the one the protocol was frozen with."""
        path = self.protocol.study_config
        if not path.is_file() or file_sha256(path) != self.registry["protocol"]["study_config_sha256"]:
            raise DataError(f"{path}: the study configuration changed since the protocol was frozen (hash differs "
                            f"from {self.root / REGISTRY_FILE}); restore it, or record the change with "
                            "`nao-trainer study amend`")

    def save(self) -> None:
        REGISTRY.write(self.root / REGISTRY_FILE, self.registry)


def init_study(protocol_path: Path, out: Path) -> Study:
    """Create the study folder (refused when it already holds a study: the protocol is frozen there)."""
    protocol = load_protocol(protocol_path)
    out = Path(out)
    if (out / REGISTRY_FILE).exists():
        raise ConfigError(f"{out}: already holds a study (registry.json); its protocol is frozen: change it with "
                          "`nao-trainer study amend STUDY_DIR PROTOCOL --reason TEXT`, or give another --out")
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: not a folder; give another --out")
    try:
        (out / SESSIONS).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{out}: cannot create the study folder ({exc.strerror}); give another --out") from None
    allocation = {"seed": protocol.allocation.seed, "block_size": protocol.allocation.block_size,
                  "sequences": allocation_sequence(protocol)}
    registry = {"protocol": _protocol_entry(protocol), "created": now_iso(), "amendments": [],
                "participants": [], "next": {k: 0 for k in allocation["sequences"]}}
    write_text_atomic(out / PROTOCOL_FILE, protocol.text)
    ALLOCATION.write(out / ALLOCATION_FILE, allocation)
    registry["allocation_sha256"] = file_sha256(out / ALLOCATION_FILE)
    REGISTRY.write(out / REGISTRY_FILE, registry)
    return Study(out, protocol, registry, allocation)


def _protocol_entry(protocol: Protocol) -> dict[str, Any]:
    return {"name": protocol.name, "sha256": protocol.sha256, "source": protocol.source,
            "base": str(Path(protocol.source).parent), "study_config": str(protocol.study_config),
            "study_config_sha256": file_sha256(protocol.study_config)}


def open_study(root: Path) -> Study:
    """Read and verify a study folder; ``DataError`` in one line for anything missing, torn or edited."""
    root = Path(root)
    if not (root / REGISTRY_FILE).is_file():
        raise DataError(f"{root}: not a study folder (no {REGISTRY_FILE}); create one with "
                        "`nao-trainer study init PROTOCOL --out STUDY_DIR`")
    registry = REGISTRY.read(root / REGISTRY_FILE, DataError)
    _check_header(registry, root / REGISTRY_FILE)
    text = read_text(root / PROTOCOL_FILE, DataError, "protocol copy missing", REGISTRY.fix)
    if protocol_hash(text) != registry["protocol"]["sha256"]:
        raise DataError(f"{root / PROTOCOL_FILE}: altered since it was frozen (hash differs from the registry); "
                        "restore it, or record a change with `nao-trainer study amend`")
    alloc_path = root / ALLOCATION_FILE
    allocation = ALLOCATION.read(alloc_path, DataError)
    if file_sha256(alloc_path) != registry.get("allocation_sha256"):
        raise DataError(f"{alloc_path}: not the allocation this study was initialised with (hash differs from "
                        f"the registry); {ALLOCATION.fix}")
    protocol = load_protocol(root / PROTOCOL_FILE, base=Path(registry["protocol"]["base"]))
    _check_participants(registry, allocation, root / REGISTRY_FILE)
    return Study(root, protocol, registry, allocation)


def _bad(path: Path, what: str) -> DataError:
    return DataError(f"{path}: {what}: edited or corrupt; {REGISTRY.fix}")


def _check_header(registry: dict[str, Any], path: Path) -> None:
    """The registry's own shape, before anything reads it (a consistent checksum proves no more than that)."""
    entry = registry.get("protocol")
    if not isinstance(entry, dict) or not all(isinstance(entry.get(k), str) for k in
                                              ("sha256", "base", "study_config", "study_config_sha256")):
        raise _bad(path, "the protocol entry is missing or malformed")
    if not isinstance(registry.get("participants"), list) or not isinstance(registry.get("amendments"), list):
        raise _bad(path, "participants or amendments are not lists")
    nxt = registry.get("next")
    if not isinstance(nxt, dict) or not all(type(v) is int and v >= 0 for v in nxt.values()):
        raise _bad(path, "the allocation position ('next') is malformed")


def _check_participants(registry: dict[str, Any], allocation: dict[str, Any], path: Path) -> None:
    """Every participant well formed and holding the arm the concealed sequence gave them, pseudonyms unique,
    and the allocation position equal to the number enrolled per stratum."""
    sequences = allocation.get("sequences")
    if not isinstance(sequences, dict) or set(sequences) != set(registry["next"]):
        raise _bad(path, "the allocation position does not match the allocation's strata")
    pattern = re.compile(r"[A-Za-z0-9]+")  # a folder name and a BIDS label (the prefix may have been amended)
    seen: set[str] = set()
    for i, p in enumerate(registry["participants"], 1):
        if not isinstance(p, dict) or not isinstance(p.get("pseudonym"), str):
            raise _bad(path, f"participant {i} is malformed")
        name = p["pseudonym"]
        if not pattern.fullmatch(name) or name in seen:
            raise _bad(path, f"participant {i}: pseudonym {name!r} is malformed or repeated")
        seen.add(name)
        stratum, index = p.get("stratum"), p.get("allocation_index")
        if stratum not in sequences or type(index) is not int or not 0 <= index < len(sequences[stratum]):
            raise _bad(path, f"{name}: stratum or allocation position is malformed")
        if p.get("arm") != sequences[stratum][index]:
            raise _bad(path, f"{name}: arm {p.get('arm')!r} is not the one the allocation gave")
        withdrawn, sessions = p.get("withdrawn"), p.get("sessions")
        if not (withdrawn is None or (isinstance(withdrawn, dict) and withdrawn.get("data") in DATA_CHOICES
                                      and isinstance(withdrawn.get("time"), str))):
            raise _bad(path, f"{name}: the withdrawal entry is malformed")
        if not isinstance(sessions, list) or not all(_session_ok(s) for s in sessions):
            raise _bad(path, f"{name}: the sessions are malformed")
    for stratum, count in Counter(p["stratum"] for p in registry["participants"]).items():
        if registry["next"][stratum] != count:
            raise _bad(path, f"stratum {stratum or '(all)'}: {count} enrolled but the allocation is at "
                             f"{registry['next'][stratum]}")


def _session_ok(s: Any) -> bool:
    folder = s.get("folder") if isinstance(s, dict) else None
    return (isinstance(folder, str) and bool(folder) and "/" not in folder and "\\" not in folder
            and folder not in (".", "..") and type(s.get("number")) is int and isinstance(s.get("status"), str)
            and isinstance(s.get("ended"), str))


def study_holding(path: Path) -> Path | None:
    """The study folder ``path`` lies in (itself or an ancestor holding a study registry), or None.

    A bare ``run`` must not write there: its session would sit among the study's without being in the
    registry, with another configuration, and could move the participant's learning state."""
    path = Path(path).resolve()
    for folder in (path, *path.parents):
        try:
            head = (folder / REGISTRY_FILE).read_text(encoding="utf-8", errors="replace")[:200]
        except OSError:
            continue
        if REGISTRY.name in head:
            return folder
    return None


@contextlib.contextmanager
def locked(root: Path) -> Iterator[Study]:
    """The study, opened under an exclusive lock for a read-modify-write; saved by the caller."""
    root = Path(root)
    if not (root / REGISTRY_FILE).is_file():
        open_study(root)  # raises the one-line "not a study folder"
    with open(root / ".registry.lock", "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield open_study(root)
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _parse_date(text: str) -> str:
    try:
        day = dt.date.fromisoformat(text)
    except ValueError:
        raise ConfigError(f"consent date {text!r}: not a date; write it as YYYY-MM-DD") from None
    if day > dt.date.today():
        raise ConfigError(f"consent date {text}: in the future; give the date consent was signed")
    return day.isoformat()


def _stratum_key(study: Study, given: dict[str, str]) -> str:
    strata = study.protocol.allocation.strata
    names = {s.name for s in strata}
    unknown = set(given) - names
    if unknown:
        raise ConfigError(f"--stratum {', '.join(sorted(unknown))}: not a stratum of this protocol "
                          f"({', '.join(sorted(names)) or 'none'})")
    parts = []
    for s in strata:
        if s.name not in given:
            raise ConfigError(f"stratum {s.name!r} missing: give --stratum {s.name}={'|'.join(s.levels)}")
        if given[s.name] not in s.levels:
            raise ConfigError(f"--stratum {s.name}={given[s.name]}: use one of {', '.join(s.levels)}")
        parts.append(f"{s.name}={given[s.name]}")
    return ",".join(parts)


def enrol(root: Path, consent_date: str, consent_version: str, strata: dict[str, str] | None = None
          ) -> dict[str, Any]:
    """Enrol the next participant: a new pseudonym and the next arm of the concealed sequence."""
    day = _parse_date(consent_date)
    if not consent_version.strip():
        raise ConfigError("--consent-version: give the version of the consent form the participant signed")
    with locked(root) as study:
        key = _stratum_key(study, strata or {})
        if len(study.participants) >= study.protocol.target_n:
            raise ConfigError(f"{root}: target_n {study.protocol.target_n} participants already enrolled; raise "
                              "target_n with `nao-trainer study amend` to enrol more")
        index = study.registry["next"][key]
        sequence = study.allocation["sequences"][key]
        if index >= len(sequence):
            raise ConfigError(f"{root}: the allocation sequence of stratum {key or '(all)'} is used up")
        number = len(study.participants) + 1
        entry = {"pseudonym": f"{study.protocol.pseudonym_prefix}{number:03d}", "arm": sequence[index],
                 "stratum": key, "allocation_index": index, "consent_date": day,
                 "consent_version": consent_version.strip(), "enrolled": now_iso(), "withdrawn": None,
                 "sessions": []}
        study.participants.append(entry)
        study.registry["next"][key] = index + 1
        study.save()
        return entry


def withdraw(root: Path, pseudonym: str, data: str, reason: str = "") -> tuple[dict[str, Any], list[Path]]:
    """Record a withdrawal; ``data="delete"`` removes the participant's session folders and learning state."""
    if data not in DATA_CHOICES:
        raise ConfigError(f"--data {data!r}: use keep or delete")
    with locked(root) as study:
        p = study.participant(pseudonym)
        if p["withdrawn"]:
            raise ConfigError(f"{pseudonym}: already withdrawn on {p['withdrawn']['time']}")
        running = _running_session(study.root, pseudonym)
        if running:
            raise ConfigError(f"{pseudonym}: a session is running ({running}); stop it (key s or the console), "
                              "then record the withdrawal")
        deleted = [study.sessions_dir / s["folder"] for s in p["sessions"]] if data == "delete" else []
        if data == "delete":
            deleted.append(participant_dir(study.sessions_dir, pseudonym))
        p["withdrawn"] = {"time": now_iso(), "data": data, "reason": reason}
        study.save()  # recorded first: a crash while deleting leaves the decision on file
        for folder in deleted:
            if folder.exists():
                shutil.rmtree(folder)
        return p, [f for f in deleted if not f.exists()]


def amend(root: Path, protocol_path: Path, reason: str) -> dict[str, Any]:
    """Replace the frozen protocol by a new version, recorded with its time, reason and hashes.

    Once someone is enrolled, what the allocation was drawn from cannot change (arms, ratios, block
    size, seed, strata): that would break the concealed sequence already in use.
    """
    if not reason.strip():
        raise ConfigError("--reason: an amendment needs its reason")
    new = load_protocol(protocol_path)
    with locked(root) as study:
        old = study.protocol
        if new.sha256 == old.sha256 and file_sha256(new.study_config) == \
                study.registry["protocol"]["study_config_sha256"]:
            raise ConfigError(f"{protocol_path}: identical to the frozen protocol; nothing to amend")
        if study.participants:
            drawn = lambda p: ([(a.name, a.ratio) for a in p.arms], p.allocation)  # noqa: E731
            if drawn(new) != drawn(old):
                raise ConfigError(f"{protocol_path}: changes the arms or the allocation after enrolment began; "
                                  "only other keys can be amended (start a new study for a new design)")
            if new.target_n > old.target_n and any(len(s) < new.target_n for s in study.allocation["sequences"].values()):
                raise ConfigError(f"{protocol_path}: target_n {new.target_n} exceeds the allocation sequence drawn "
                                  "at init; start a new study")
        entry = {"time": now_iso(), "reason": reason.strip(), "old_sha256": old.sha256, "new_sha256": new.sha256,
                 "enrolled_at_amendment": len(study.participants)}
        study.registry["amendments"].append(entry)
        study.registry["protocol"] = _protocol_entry(new)
        write_text_atomic(study.root / PROTOCOL_FILE, new.text)
        if not study.participants:  # nobody allocated yet: draw the sequence of the new design
            allocation = {"seed": new.allocation.seed, "block_size": new.allocation.block_size,
                          "sequences": allocation_sequence(new)}
            ALLOCATION.write(study.root / ALLOCATION_FILE, allocation)
            study.registry["allocation_sha256"] = file_sha256(study.root / ALLOCATION_FILE)
            study.registry["next"] = {k: 0 for k in allocation["sequences"]}
        study.save()
        return entry


def record_session(root: Path, pseudonym: str, entry: dict[str, Any]) -> None:
    """Add or update (same folder) one session of a participant."""
    with locked(root) as study:
        sessions = study.participant(pseudonym)["sessions"]
        sessions[:] = [s for s in sessions if s["folder"] != entry["folder"]] + [entry]
        study.save()


def _running_session(root: Path, pseudonym: str) -> str:
    """'pid N on HOST' when the participant's ``study next`` lock is held by a live process, else ''."""
    try:
        held = json.loads((root / "locks" / f"{pseudonym}.lock").read_text(encoding="utf-8"))
        pid, host = int(held["pid"]), str(held["host"])
    except (OSError, ValueError, KeyError, TypeError):
        return ""
    if host != socket.gethostname() or pid_alive(pid):
        return f"pid {pid} on {host}"
    return ""


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
