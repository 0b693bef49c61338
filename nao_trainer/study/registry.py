"""The study folder: the frozen protocol, the sealed allocation and the participant registry.

``STUDY_DIR/`` holds

* ``registry.db``: the registry (SQLite, ``study.store``): the protocol's text, hash and origin,
  amendments (time, reason, hashes, what they changed), participants (pseudonym, site, stratum,
  allocation position, consent date and version, enrolment, withdrawal), sessions (registered when
  they start, with their folder and files' checksums) and unblindings. Never names or contact details.
  Every command is one transaction: a kill or a full disk leaves the state before or after it;
* the allocation sequence inside it, **sealed**: each slot's arm encrypted with the study key, which
  lives outside the folder (``study.seal``). Its seed is drawn from the operating system's entropy at
  ``init`` and kept nowhere; block sizes are random (multiples of the arms' round, up to the protocol's
  ``block_size``). No command prints an arm of a blinded study before ``study unblind``;
* ``protocol.yaml``: a readable copy of the frozen protocol (restored from the registry when a kill
  left the previous version);
* ``sessions/``: the session folders ``study next`` writes (and ``participants/`` learning states).

A registry edited outside nao-trainer is refused in one line (exit 2): its HMAC does not match.
A study folder of an older nao-trainer (``registry.json``) is migrated once by ``study init`` (the
JSON files are kept in ``backup-json/``).
"""
from __future__ import annotations

import datetime as dt
import getpass
import hashlib
import json
import os
import re
import secrets
import shutil
import socket
import uuid
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import JsonFormat, read_text, write_text_atomic
from nao_trainer.policies.participant_state import participant_dir
from nao_trainer.study import seal, store
from nao_trainer.study.names import check_name, name_problem
from nao_trainer.study.protocol import Protocol, load_protocol, protocol_hash

# The JSON registry of nao-trainer <= this version: read only to migrate it.
REGISTRY = JsonFormat("nao-trainer/study-registry", 1, "study registry", "study registry",
                      "restore the file from a backup; it must not be edited by hand")
ALLOCATION = JsonFormat("nao-trainer/study-allocation", 1, "allocation sequence", "allocation",
                        "restore the file from a backup; it must not be edited by hand")
PROTOCOL_FILE, REGISTRY_FILE, ALLOCATION_FILE = "protocol.yaml", "registry.json", "allocation.json"
DB_FILE = store.DB_FILE
SESSIONS = "sessions"
DATA_CHOICES = ("keep", "delete")
BACKUP = "backup-json"


def now_iso() -> str:
    return dt.datetime.now(dt.timezone.utc).astimezone().isoformat(timespec="seconds")


def block_sizes(protocol: Protocol) -> list[int]:
    """The block sizes drawn from: every multiple of the arms' round (sum of ratios) up to ``block_size``."""
    round_size = sum(a.ratio for a in protocol.arms)
    return list(range(round_size, protocol.allocation.block_size + 1, round_size))


def allocation_sequence(protocol: Protocol, rng: np.random.Generator) -> dict[str, list[str]]:
    """Blocked randomisation with random block sizes: per stratum, blocks of a size drawn from
    :func:`block_sizes`, each a random permutation holding every arm ``ratio x size / round`` times,
    until ``target_n`` (rounded up to whole rounds) is covered exactly, so the arms balance at target_n
    as after each block; the random sizes keep an operator who counts from guessing a block's last
    assignments."""
    sizes = block_sizes(protocol)
    round_size = sizes[0]
    out = {}
    for key in protocol.allocation.stratum_keys():
        seq: list[str] = []
        total = -(-protocol.target_n // round_size) * round_size  # whole rounds: balanced at target_n
        while len(seq) < total:
            size = int(rng.choice([s for s in sizes if s <= total - len(seq)]))
            block = [a.name for a in protocol.arms for _ in range(a.ratio * (size // round_size))]
            seq += [block[i] for i in rng.permutation(len(block))]
        out[key] = seq
    return out


def entropy_rng(supplied: int | None = None) -> np.random.Generator:
    """A generator seeded from the operating system's entropy (128 bits), or from a seed a third party
    supplied (``study init --allocation-seed-file``). The seed is not stored."""
    return np.random.default_rng(supplied if supplied is not None else secrets.randbits(128))


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass
class Study:
    """A study folder, verified. ``registry`` is the registry as a dict (protocol entry, amendments,
    participants with their sessions, allocation position); a participant's ``arm`` is there only when
    the study was opened with ``reveal`` (unblinded or not blinded)."""

    root: Path
    protocol: Protocol
    registry: dict[str, Any]
    key: bytes = field(repr=False, default=b"")
    sealed: dict[tuple[str, int], str] = field(repr=False, default_factory=dict)

    @property
    def sessions_dir(self) -> Path:
        return self.root / SESSIONS

    @property
    def participants(self) -> list[dict[str, Any]]:
        return self.registry["participants"]

    @property
    def unblinded(self) -> bool:
        return bool(self.registry["unblindings"])

    def participant(self, pseudonym: str) -> dict[str, Any]:
        for p in self.participants:
            if p["pseudonym"] == pseudonym:
                return p
        if name_problem(pseudonym):
            raise DataError(f"{self.root}: pseudonym {pseudonym!r} is not a pseudonym (must be "
                            f"{name_problem(pseudonym)})")
        known = ", ".join(p["pseudonym"] for p in self.participants) or "none yet"
        raise DataError(f"{self.root}: pseudonym {pseudonym!r} is not enrolled in this study (enrolled: {known}); "
                        "enrol with `nao-trainer study enrol`")

    def arm_of(self, pseudonym: str) -> str:
        """The participant's arm, unsealed (to configure a session; never printed while blinded)."""
        p = self.participant(pseudonym)
        token = self.sealed.get((p["stratum"], p["allocation_index"]))
        if token is None:
            raise DataError(f"{self.root / DB_FILE}: {pseudonym}'s allocation slot is missing: edited or corrupt")
        arm = seal.unseal(self.key, token, self.root / DB_FILE)
        if arm not in [a.name for a in self.protocol.arms]:
            raise DataError(f"{self.root / DB_FILE}: {pseudonym}'s sealed arm {arm!r} is not an arm of the protocol")
        return arm

    def check_study_config(self) -> None:
        """The study configuration the arms start from must be the one the protocol was frozen with."""
        path = self.protocol.study_config
        if not path.is_file() or file_sha256(path) != self.registry["protocol"]["study_config_sha256"]:
            raise DataError(f"{path}: the study configuration changed since the protocol was frozen (hash differs "
                            f"from {self.root / DB_FILE}); restore it, or record the change with "
                            "`nao-trainer study amend`")


def _protocol_entry(protocol: Protocol) -> dict[str, Any]:
    return {"name": protocol.name, "sha256": protocol.sha256, "source": protocol.source,
            "base": protocol.base or str(Path(protocol.source).parent), "study_config": str(protocol.study_config),
            "study_config_sha256": file_sha256(protocol.study_config)}


# --- init and migration ----------------------------------------------------------------------------------

def init_study(protocol_path: Path, out: Path, allocation_seed: int | None = None) -> Study:
    """Create the study folder (refused when it already holds one), or migrate a JSON study folder once."""
    out = Path(out)
    if store.exists(out):
        raise ConfigError(f"{out}: already holds a study ({DB_FILE}); its protocol is frozen: change it with "
                          "`nao-trainer study amend STUDY_DIR PROTOCOL --reason TEXT`, or give another --out")
    if (out / REGISTRY_FILE).is_file():
        return migrate_json(out)
    protocol = load_protocol(protocol_path)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: not a folder; give another --out")
    try:
        (out / SESSIONS).mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / PROTOCOL_FILE, protocol.text)
    except OSError as exc:
        raise ConfigError(f"{out}: cannot create the study folder ({exc.strerror}); free space or give another "
                          "--out") from None
    sequences = allocation_sequence(protocol, entropy_rng(allocation_seed))
    _create_db(out, protocol, sequences, {"session_salt": secrets.token_hex(16)}, [], [])
    return open_study(out)


def _create_db(out: Path, protocol: Protocol, sequences: dict[str, list[str]], extra: dict[str, Any],
               participants: list[dict[str, Any]], amendments: list[dict[str, Any]]) -> None:
    """Write a complete registry into a temporary database, then rename it into place: a kill leaves no
    registry or a whole one."""
    study_id = uuid.uuid4().hex
    key = seal.new_key(study_id)
    tmp = out / f".{DB_FILE}.tmp-{os.getpid()}"
    for leftover in out.glob(f".{DB_FILE}.tmp-*"):
        leftover.unlink(missing_ok=True)
    try:
        with store.transaction(out, write=True, create=True, db_path=tmp) as tx:
            tx.key = key
            tx.set_meta("study_id", study_id)
            tx.set_meta("created", extra.pop("created", now_iso()))
            tx.set_meta("protocol", extra.pop("protocol_entry", None) or _protocol_entry(protocol))
            tx.set_meta("protocol_text", protocol.text)
            tx.set_meta("next", {k: 0 for k in sequences})
            for k, v in extra.items():
                tx.set_meta(k, v)
            tx.add_allocation(sequences)
            nxt = {k: 0 for k in sequences}
            for p in participants:
                tx.add_participant(p)
                nxt[p["stratum"]] += 1
                for s in p["sessions"]:
                    tx.put_session({**s, "pseudonym": p["pseudonym"], "key": s.get("key") or uuid.uuid4().hex})
            tx.set_meta("next", nxt)
            tx.set_meta("participants", len(participants))
            for a in amendments:
                tx.add_amendment(a)
        os.replace(tmp, out / DB_FILE)
    finally:
        for suffix in ("", "-wal", "-shm"):
            Path(f"{tmp}{suffix}").unlink(missing_ok=True)


def migrate_json(out: Path) -> Study:
    """A JSON study (registry.json, allocation.json) into the database, once; the JSON files are moved to
    ``backup-json/`` after the database is in place (a kill before leaves the JSON study as it was)."""
    registry = REGISTRY.read(out / REGISTRY_FILE, DataError)
    _check_header(registry, out / REGISTRY_FILE)
    text = read_text(out / PROTOCOL_FILE, DataError, "protocol copy missing", REGISTRY.fix)
    if protocol_hash(text) != registry["protocol"]["sha256"]:
        raise DataError(f"{out / PROTOCOL_FILE}: altered since it was frozen (hash differs from the registry); "
                        "restore it before migrating")
    allocation = ALLOCATION.read(out / ALLOCATION_FILE, DataError)
    if file_sha256(out / ALLOCATION_FILE) != registry.get("allocation_sha256"):
        raise DataError(f"{out / ALLOCATION_FILE}: not the allocation this study was initialised with; "
                        f"{ALLOCATION.fix}")
    _check_participants(registry, allocation, out / REGISTRY_FILE)
    protocol = load_protocol(out / PROTOCOL_FILE, base=Path(registry["protocol"]["base"]))
    people = [{**p, "number": i, "site": ""} for i, p in enumerate(registry["participants"], 1)]
    amendments = [{**a, "changes": a.get("changes", [])} for a in registry["amendments"]]
    # the sessions' seeds continue as before (they were derived from the protocol's seed)
    extra = {"session_salt": str(protocol.allocation.seed), "created": registry.get("created", now_iso()),
             "migrated": {"time": now_iso(), "from": "registry.json"},
             "protocol_entry": {k: registry["protocol"][k] for k in ("name", "sha256", "source", "base", "study_config",
                                                                      "study_config_sha256") if k in registry["protocol"]}}
    _create_db(out, protocol, allocation["sequences"], extra, people, amendments)
    backup = out / BACKUP
    backup.mkdir(exist_ok=True)
    for name in (REGISTRY_FILE, ALLOCATION_FILE):
        os.replace(out / name, backup / name)
    return open_study(out)


# --- opening ---------------------------------------------------------------------------------------------

def _load(tx: store.Tx, root: Path) -> dict[str, Any]:
    """The registry as a dict (the shape the study layer reads), checked for consistency."""
    entry = tx.meta("protocol")
    if not isinstance(entry, dict) or not all(isinstance(entry.get(k), str) for k in
                                              ("sha256", "base", "study_config", "study_config_sha256")):
        raise DataError(f"{tx.path}: the protocol entry is malformed: edited or corrupt")
    sessions: dict[str, list[dict[str, Any]]] = {}
    for s in tx.rows("sessions", "pseudonym, number, started, key"):
        s["outside_interval"] = bool(s["outside_interval"])
        s["files"] = json.loads(s["files"]) if s["files"] else None
        sessions.setdefault(s["pseudonym"], []).append(s)
    people = []
    for p in tx.rows("participants", "number"):
        p["withdrawn"] = json.loads(p["withdrawn"]) if p["withdrawn"] else None
        p["sessions"] = sessions.get(p["pseudonym"], [])
        people.append(p)
    amendments = tx.rows("amendments", "id")
    for a in amendments:
        a["changes"] = json.loads(a["changes"])
    reg = {"protocol": entry, "created": tx.meta("created"), "amendments": amendments, "participants": people,
           "next": tx.meta("next"), "study_id": tx.meta("study_id"), "session_salt": tx.meta("session_salt"),
           "unblindings": tx.rows("unblindings", "id"), "protocol_text": tx.meta("protocol_text"),
           "participant_count": tx.meta("participants"), "sites": tx.meta("sites", {})}
    lengths = tx.sequence_lengths()
    counts = Counter(p["stratum"] for p in people)
    if set(reg["next"]) != set(lengths) or any(reg["next"][k] != counts.get(k, 0) for k in lengths) \
            or reg["participant_count"] != len(people):
        raise DataError(f"{tx.path}: the participants do not match the allocation position (a participant removed "
                        "or added by hand): edited or corrupt")
    for i, p in enumerate(people, 1):
        if name_problem(p["pseudonym"]) or p["number"] != i:
            raise DataError(f"{tx.path}: participant {i}: pseudonym {p['pseudonym']!r} is malformed or out of order")
    return reg


def open_study(root: Path, reveal: bool = False) -> Study:
    """Read and verify a study folder; ``DataError`` in one line for anything missing, torn or edited.

    ``reveal``: put each participant's arm in the registry dict (analysis, export): refused while a
    blinded study has not been unblinded."""
    root = Path(root)
    if not store.exists(root) and (root / REGISTRY_FILE).is_file():
        raise DataError(f"{root}: a study folder of an older nao-trainer (registry.json); migrate it once with "
                        f"`nao-trainer study init {root / PROTOCOL_FILE} --out {root}`")
    sealed: dict[tuple[str, int], str] = {}
    with store.transaction(root, write=False) as tx:
        registry = _load(tx, root)
        key = tx.key
        sealed = {(r["stratum"], r["position"]): r["sealed_arm"] for r in tx.rows("allocation", "stratum, position")}
    text = registry["protocol_text"]
    _ensure_protocol_copy(root, registry, text)
    protocol = load_protocol(root / PROTOCOL_FILE, base=Path(registry["protocol"]["base"]))
    study = Study(root, protocol, registry, key or b"", sealed)
    if reveal:
        if protocol.blinding and not study.unblinded:
            raise DataError(f"{root}: the study is blinded; its arms are revealed only after `nao-trainer study "
                            f"unblind {root} --reason TEXT` (the statistician; the unblinding is recorded)")
        for p in study.participants:
            p["arm"] = study.arm_of(p["pseudonym"])
    return study


def _ensure_protocol_copy(root: Path, registry: dict[str, Any], text: str) -> None:
    """The readable copy must be the frozen text. A copy of the version an amendment replaced (a kill
    between the registry's commit and the copy) is restored; any other difference is refused."""
    path = root / PROTOCOL_FILE
    try:
        current = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        current = None
    if current is not None and protocol_hash(current) == registry["protocol"]["sha256"]:
        return
    earlier = {a["old_sha256"] for a in registry["amendments"]}
    if current is not None and protocol_hash(current) not in earlier:
        raise DataError(f"{path}: altered since it was frozen (hash differs from the registry); restore it, or "
                        "record a change with `nao-trainer study amend`")
    try:
        write_text_atomic(path, text)
    except OSError as exc:
        raise DataError(f"{path}: cannot restore the protocol copy ({exc.strerror}); free disk space") from None


def study_holding(path: Path) -> Path | None:
    """The study folder ``path`` lies in (itself or an ancestor holding a study registry), or None.

    A bare ``run`` must not write there: its session would sit among the study's without being in the
    registry, with another configuration, and could move the participant's learning state."""
    path = Path(path).resolve()
    for folder in (path, *path.parents):
        if (folder / DB_FILE).is_file():
            return folder
        try:
            head = (folder / REGISTRY_FILE).read_text(encoding="utf-8", errors="replace")[:200]
        except OSError:
            continue
        if REGISTRY.name in head:
            return folder
    return None


def _write(root: Path):
    """A write transaction on the study (checked first: a damaged registry is refused before anything)."""
    return store.transaction(Path(root), write=True)


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


# --- the commands' changes: one transaction each ---------------------------------------------------------

def enrol(root: Path, consent_date: str, consent_version: str, strata: dict[str, str] | None = None,
          site: str = "") -> dict[str, Any]:
    """Enrol the next participant: a new pseudonym and the next (sealed) slot of the allocation."""
    day = _parse_date(consent_date)
    version = consent_version.strip()
    if not version or "\n" in version or "\r" in version:
        raise ConfigError("--consent-version: give the version of the consent form the participant signed (one line)")
    study = open_study(root)
    key = _stratum_key(study, strata or {})
    with _write(root) as tx:
        reg = _load(tx, Path(root))
        target = load_protocol_text(study, reg).target_n
        if len(reg["participants"]) >= target:
            raise ConfigError(f"{root}: target_n {target} participants already enrolled; raise "
                              "target_n with `nao-trainer study amend` to enrol more")
        index = reg["next"][key]
        if tx.sealed_arm(key, index) is None:
            raise ConfigError(f"{root}: the allocation sequence of stratum {key or '(all)'} is used up")
        number = len(reg["participants"]) + 1
        entry = {"pseudonym": check_name(f"{study.protocol.pseudonym_prefix}{number:03d}", "pseudonym"),
                 "number": number, "site": site, "stratum": key, "allocation_index": index, "consent_date": day,
                 "consent_version": version, "enrolled": now_iso(), "withdrawn": None, "sessions": []}
        tx.add_participant(entry)
        tx.set_meta("next", {**reg["next"], key: index + 1})
        tx.set_meta("participants", number)
    return entry


def load_protocol_text(study: Study, reg: dict[str, Any]) -> Protocol:
    """The protocol as the transaction sees it (another command may have amended it since ``study``)."""
    if reg["protocol"]["sha256"] == study.protocol.sha256:
        return study.protocol
    raise ConfigError(f"{study.root}: the protocol was amended meanwhile; run the command again")


def participant_folders(study: Study, pseudonym: str) -> list[Path]:
    """Every session folder of a participant on disk: recorded or not (``<pseudonym>_<stamp>``)."""
    pattern = re.compile(re.escape(pseudonym) + r"_\d{8}-\d{6}(_\d+)?")
    try:
        return sorted(f for f in study.sessions_dir.iterdir() if pattern.fullmatch(f.name) and f.is_dir())
    except OSError:
        return []


def withdraw(root: Path, pseudonym: str, data: str, reason: str = "") -> tuple[dict[str, Any], list[Path]]:
    """Record a withdrawal; ``data="delete"`` removes the participant's session folders (recorded or found
    on disk) and learning state. Returns the folders that existed and were removed."""
    if data not in DATA_CHOICES:
        raise ConfigError(f"--data {data!r}: use keep or delete")
    study = open_study(root)
    p = study.participant(pseudonym)
    recorded = [s["folder"] for s in p["sessions"] if s.get("folder")]
    if p["withdrawn"]:
        if p["withdrawn"]["data"] == "delete":  # a deletion a kill interrupted: finished now
            return p, delete_data(study, pseudonym, recorded)
        raise ConfigError(f"{pseudonym}: already withdrawn on {p['withdrawn']['time']}")
    running = _running_session(study.root, pseudonym)
    if running:
        raise ConfigError(f"{pseudonym}: a session is running ({running}); stop it (key s or the console), "
                          "then record the withdrawal")
    with _write(root) as tx:
        reg = _load(tx, Path(root))
        if any(q["pseudonym"] == pseudonym and q["withdrawn"] for q in reg["participants"]):
            raise ConfigError(f"{pseudonym}: already withdrawn")
        p["withdrawn"] = {"time": now_iso(), "data": data, "reason": reason}
        tx.set_withdrawn(pseudonym, p["withdrawn"])
    # recorded first: a kill while deleting leaves the decision on file (the same command finishes it)
    return p, (delete_data(study, pseudonym, recorded) if data == "delete" else [])


def delete_data(study: Study, pseudonym: str, recorded: Iterable[str]) -> list[Path]:
    """Delete a withdrawn participant's session folders (``recorded``: their names in the registry, plus any on
    disk) and their policy state; a kill or a failure midway is finished by the same withdraw command."""
    folders = {study.sessions_dir / f for f in recorded} | set(participant_folders(study, pseudonym))
    folders.add(participant_dir(study.sessions_dir, pseudonym))
    deleted = []
    for folder in sorted(folders):
        if folder.is_dir() and not folder.is_symlink():
            try:
                shutil.rmtree(folder)
            except OSError as exc:
                raise DataError(f"{folder}: cannot delete ({exc.strerror}); the withdrawal is recorded: run the "
                                "same withdraw command again to finish the deletion") from None
            deleted.append(folder)
    return deleted


def arm_changes(old: Protocol, new: Protocol) -> list[str]:
    """What an amendment changes in what an arm does, or in the blinding (needs --change-arms)."""
    changes = []
    before = {a.name: a for a in old.arms}
    for arm in new.arms:
        was = before.get(arm.name)
        if was is not None and (was.policy, dict(was.overrides)) != (arm.policy, dict(arm.overrides)):
            changes.append(f"arm {arm.name} changed ({was.policy} -> {arm.policy})")
    if old.blinding and not new.blinding:
        changes.append("blinding turned off")
    return changes


def amend(root: Path, protocol_path: Path, reason: str, change_arms: bool = False) -> dict[str, Any]:
    """Replace the frozen protocol by a new version, recorded with its time, reason, hashes and what it
    changes; protocol and registry change in one transaction.

    Once someone is enrolled, what the allocation was drawn from cannot change (arms, ratios, block
    size, strata); what an arm does, or the blinding, changes only with ``change_arms`` (recorded, and
    reported by the analysis)."""
    if not reason.strip() or "\n" in reason.strip():
        raise ConfigError("--reason: an amendment needs its reason (one line)")
    study = open_study(root)
    # a relative study_config resolves against the new file's folder, else against the study's (that of the
    # protocol given to init, or of the last amendment): an edited copy of STUDY_DIR/protocol.yaml works anywhere
    new = load_protocol(protocol_path, fallback=Path(study.registry["protocol"]["base"]))
    old = study.protocol
    if new.sha256 == old.sha256 and file_sha256(new.study_config) == study.registry["protocol"]["study_config_sha256"]:
        raise ConfigError(f"{protocol_path}: identical to the frozen protocol; nothing to amend")
    changes: list[str] = []
    if study.participants:
        drawn = lambda p: ([(a.name, a.ratio) for a in p.arms], p.allocation.block_size,  # noqa: E731
                           p.allocation.strata)
        if drawn(new) != drawn(old):
            raise ConfigError(f"{protocol_path}: changes the arms or the allocation after enrolment began; "
                              "only other keys can be amended (start a new study for a new design)")
        changes = arm_changes(old, new)
        if changes and not change_arms:
            raise ConfigError(f"{protocol_path}: {'; '.join(changes)} while {len(study.participants)} participant(s) "
                              "are enrolled; if that is intended, give --change-arms (recorded in the registry and "
                              "reported by the analysis)")
    with _write(root) as tx:
        reg = _load(tx, Path(root))
        if reg["protocol"]["sha256"] != old.sha256 or len(reg["participants"]) != len(study.participants):
            raise ConfigError(f"{root}: the study changed meanwhile; run the amendment again")
        if reg["participants"] and any(n < new.target_n for n in tx.sequence_lengths().values()) \
                and new.target_n > old.target_n:
            raise ConfigError(f"{protocol_path}: target_n {new.target_n} exceeds the allocation sequence drawn "
                              "at init; start a new study")
        entry = {"time": now_iso(), "reason": reason.strip(), "old_sha256": old.sha256, "new_sha256": new.sha256,
                 "enrolled_at_amendment": len(reg["participants"]), "changes": changes,
                 "study_config": str(new.study_config)}
        tx.add_amendment(entry)
        tx.set_meta("protocol", _protocol_entry(new))
        tx.set_meta("protocol_text", new.text)
        if not reg["participants"]:  # nobody allocated yet: draw the sequence of the new design
            sequences = allocation_sequence(new, entropy_rng())
            tx.add_allocation(sequences)
            tx.set_meta("next", {k: 0 for k in sequences})
    try:
        write_text_atomic(Path(root) / PROTOCOL_FILE, new.text)
    except OSError:
        pass  # the registry holds the text; the next command restores the copy
    return entry


def record_session(root: Path, pseudonym: str, entry: dict[str, Any]) -> dict[str, Any]:
    """Add or update one session of a participant by its key (idempotent; default key: the folder)."""
    entry = {**entry, "pseudonym": pseudonym}
    entry.setdefault("key", entry.get("folder") or uuid.uuid4().hex)
    folder = entry.get("folder")
    if folder is not None and (not isinstance(folder, str) or folder in (".", "..") or "/" in folder
                               or "\\" in folder or not folder):
        raise DataError(f"{folder!r}: not a session folder name")
    with _write(root) as tx:
        reg = _load(tx, Path(root))
        if not any(p["pseudonym"] == pseudonym for p in reg["participants"]):
            raise DataError(f"{root}: pseudonym {pseudonym!r} is not enrolled in this study")
        entry.setdefault("protocol_sha256", reg["protocol"]["sha256"])
        if folder:  # one folder is one session, whatever key recorded it first
            for p in reg["participants"]:
                for s in p["sessions"]:
                    if s["folder"] == folder and s["key"] != entry["key"]:
                        entry["key"] = s["key"]
        tx.put_session(entry)
    return entry


def unblind(root: Path, reason: str, who: str | None = None) -> list[tuple[str, str]]:
    """The statistician's unblinding: recorded (time, who, reason), then every participant's arm."""
    if not reason.strip() or "\n" in reason:
        raise ConfigError("--reason: an unblinding needs its reason (one line)")
    who = who or f"{getpass.getuser()}@{socket.gethostname()}"
    with _write(root) as tx:
        _load(tx, Path(root))
        tx.add_unblinding(now_iso(), who, reason.strip())
    study = open_study(root)
    return [(p["pseudonym"], study.arm_of(p["pseudonym"])) for p in study.participants]


def _running_session(root: Path, pseudonym: str) -> str:
    """'pid N on HOST' when the participant's ``study next`` lock is held by a live process, else ''."""
    held = read_lock(root / "locks" / f"{pseudonym}.lock")
    if held is None:
        return ""
    pid, host = held
    if host != socket.gethostname() or pid_alive(pid):
        return f"pid {pid} on {host}"
    return ""


def read_lock(path: Path) -> tuple[int, str] | None:
    """(pid, host) of a lock file; None when there is none or it cannot be read (a torn lock is stale)."""
    try:
        held = json.loads(path.read_text(encoding="utf-8"))
        pid, host = int(held["pid"]), str(held["host"])
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return None
    return (pid, host) if pid > 0 else None


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` (> 0) exists on this host (``os.kill(-1, 0)`` would test every process)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


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


