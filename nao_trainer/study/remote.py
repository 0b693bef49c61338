"""A study folder whose registry is on a PostgreSQL server (``study init --registry postgresql://...``).

The folder holds ``protocol.yaml`` and ``registry.url``: the server and database, with neither user nor
password (each command connects as the role of whoever runs it: ``PGUSER`` or the service file, the
password from ``PGPASSWORD``, ``PGPASSFILE`` or the service file). Enrolment, status, sites and the
unblinding go through ``study.pg``.

A site's laptop (its folder a copy of the administrator's) runs its sessions with :func:`run_next`: the
registry gives the configuration of the participant's next session (not the arm); the session is written
to ``sessions/`` as on one laptop, and its entry goes to ``outbox/<key>.json`` first, then to the registry
under its key (idempotent). An entry the registry did not take (the network went during the session) stays
in the outbox: :func:`flush` (``study record``, ``study repair``, the next ``study next``) records it,
once, when the server is back; a session whose process was killed is recorded as its folder says.

The statistician's folder (a copy too, with the sites' ``sessions/`` folders copied into its own) is
analysed and exported through :func:`statistician_study`: the sessions the registry lists, each folder
checked against the checksums the site recorded, and the arms read through the logged unblinding.

:func:`amend` (the administrator) changes the registry's protocol; each folder's copy follows at its next
command (:func:`open_protocol`). ``study next --resume`` continues the participant's interrupted last
session on the laptop that ran it, under its key (:func:`_resume`).
"""
from __future__ import annotations

import datetime as dt
import json
import re
import socket
import sys
from pathlib import Path
from typing import Any, TextIO

from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import write_text_atomic
from nao_trainer.study import pg
from nao_trainer.study.protocol import Protocol, load_protocol, protocol_hash
from nao_trainer.policies.participant_state import participant_template
from nao_trainer.session.config import load_config

URL_FILE = "registry.url"
OUTBOX = "outbox"


def is_remote(root: Path) -> bool:
    return (Path(root) / URL_FILE).is_file()


def _without_user(url: str) -> str:
    return re.sub(r"^(postgres(?:ql)?://)[^@/]*@", r"\1", url)


def url_of(root: Path) -> str:
    try:
        return (Path(root) / URL_FILE).read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise DataError(f"{root / URL_FILE}: cannot read ({exc.strerror})") from None


def connect(root: Path):
    return pg.connect(url_of(root), autocommit=True)


def init(protocol_path: Path, out: Path, url: str, stratify_by_site: bool,
         allocation_seed: int | None = None) -> dict[str, Any]:
    """Create the registry in the (empty) database ``url`` as the connecting administrator, and the folder.
    ``allocation_seed``: a seed a third party supplied (``--allocation-seed-file``; not stored), else the
    operating system's entropy."""
    from nao_trainer.study.registry import allocation_sequence, entropy_rng

    if not re.match(r"postgres(ql)?://", url):
        raise ConfigError(f"--registry {url!r}: give a postgresql:// URL")
    out = Path(out)
    if is_remote(out) or (out / "registry.db").is_file():
        raise ConfigError(f"{out}: already holds a study; give another --out")
    protocol = load_protocol(protocol_path)
    if protocol.allocation.strata and stratify_by_site:
        raise ConfigError("--stratify-by-site: the protocol has strata of its own; use one or the other")
    draw = entropy_rng(allocation_seed)
    conn = pg.connect(url, autocommit=True)
    with conn:
        if pg.call(conn, "study init", "SELECT count(*) FROM pg_tables WHERE schemaname = 'public'")[0][0]:
            raise ConfigError(f"{pg.redact(url)}: the database is not empty; create an empty one for the study")
        db = pg.call(conn, "study init", "SELECT current_database()")[0][0]
        prefix = re.sub(r"[^a-z0-9_]", "_", db.lower())[:20]
        prefix = prefix if re.match(r"[a-z]", prefix) else f"s_{prefix}"[:20]
        # stratified by site: a sequence per site, drawn as sites are added (the sequence of '' is unused)
        sequences = allocation_sequence(protocol, draw)
        from nao_trainer.study.registry import file_sha256

        pg.create(conn, prefix, sequences, {a.name: a.config_overrides() for a in protocol.arms},
                  stratify_by_site, protocol.target_n, protocol.pseudonym_prefix,
                  {"protocol_base": str(Path(protocol.source).parent), "protocol_sha256": protocol.sha256,
                   "protocol_text": protocol.text, "study_config_sha256": file_sha256(protocol.study_config),
                   "study_config": str(protocol.study_config)})
        if stratify_by_site:
            pg.call(conn, "study init", "INSERT INTO meta VALUES ('draw_per_site', 'true')")
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "protocol.yaml", protocol.text)
    write_text_atomic(out / URL_FILE, _without_user(url) + "\n")
    return {"prefix": prefix, "protocol": protocol}


def site_add(root: Path, name: str) -> tuple[str, str]:
    from nao_trainer.study.registry import allocation_sequence, entropy_rng

    with connect(root) as conn:
        role, password = pg.site_add(conn, name)
        if pg.call(conn, "study site add", "SELECT 1 FROM meta WHERE key = 'draw_per_site'"):
            protocol = open_protocol(root, pg.study_info(conn))
            seq = allocation_sequence(protocol, entropy_rng())[""]
            with conn.transaction(), conn.cursor() as cur:
                cur.executemany("INSERT INTO allocation VALUES (%s, %s, %s)",
                                [(name, i, arm) for i, arm in enumerate(seq)])
    return role, password


def enrol(root: Path, consent_date: str, consent_version: str, strata: dict[str, str] | None = None) -> str:
    """The next pseudonym of the connecting site; ``strata``: the participant's level of each of the protocol's
    strata (``--stratum NAME=LEVEL``), checked against the protocol as on one laptop."""
    from nao_trainer.study.registry import _parse_date, _stratum_key

    day = _parse_date(consent_date)
    with connect(root) as conn:
        info = pg.study_info(conn)
        key = _stratum_key(_study(root, info, open_protocol(root, info)), strata or {})
        return pg.enrol(conn, day, consent_version, key)


def status_lines(root: Path) -> list[str]:
    """What the connecting role may see: a site its own participants; the statistician every site's
    counts and the unblinding log; neither an arm."""
    with connect(root) as conn:
        who = pg.call(conn, "study status", "SELECT session_user")[0][0]
        site = pg.call(conn, "study status", "SELECT has_table_privilege('site_participants', 'SELECT')")
    lines = [f"{root}: registry {pg.redact(url_of(root))}, connected as {who}"]
    with connect(root) as conn:
        if site and site[0][0]:
            people = pg.site_participants(conn)
            lines.append(f"  site view (pseudonyms, consent, sessions; arms: not readable by this role): "
                         f"{len(people)} participant(s)")
            lines += [f"  {p['pseudonym']}  consent {p['consent_date']} v{p['consent_version']}  sessions "
                      f"{p['sessions_done']}{'  WITHDRAWN' if p['withdrawn'] else ''}" for p in people]
            kept = len(list((Path(root) / OUTBOX).glob("*.json")))
            if kept:
                lines.append(f"  on this laptop, not yet in the registry: {kept} session entr{'y' if kept == 1 else 'ies'} "
                             f"in {Path(root) / OUTBOX} (running, or the network went): `nao-trainer study record "
                             f"{root}`")
            return lines
        rows = pg.call(conn, "study status", "SELECT p.site, count(DISTINCT p.pseudonym), count(s.key) FILTER "
                       "(WHERE s.status IN ('completed', 'time limit')) FROM participants p LEFT JOIN sessions s ON "
                       "s.pseudonym = p.pseudonym GROUP BY p.site ORDER BY p.site")
        log = pg.call(conn, "study status", "SELECT time::text, who, reason FROM unblindings ORDER BY id")
    lines.append("  per site (participants, completed sessions; arms only through `study unblind`, logged):")
    lines += [f"  {site}: {n} participant(s), {done} session(s)" for site, n, done in rows]
    lines += [f"  unblinded {t} by {w}: {r}" for t, w, r in log] or ["  not unblinded"]
    return lines


def unblind(root: Path, reason: str) -> list[tuple[str, str]]:
    with connect(root) as conn:
        return pg.unblind(conn, reason)


# --- the protocol on a site's (or the statistician's) laptop -------------------------------------------

def open_protocol(root: Path, info: dict[str, Any]) -> Protocol:
    """The study folder's protocol, checked against the one frozen in the registry (restored from it when
    the copy is missing), with its study configuration unchanged since ``study init``."""
    from nao_trainer.study.registry import PROTOCOL_FILE, file_sha256

    path = Path(root) / PROTOCOL_FILE
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        text = info["protocol_text"]
        try:
            write_text_atomic(path, text)
        except OSError as exc:
            raise DataError(f"{path}: cannot restore the protocol copy from the registry ({exc.strerror})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read ({exc})") from None
    if protocol_hash(text) != info["protocol_sha256"] and protocol_hash(text) in info.get("earlier_sha256", []):
        try:  # the version an amendment replaced: the registry's text is the study's protocol now
            write_text_atomic(path, info["protocol_text"])
        except OSError as exc:
            raise DataError(f"{path}: cannot write the amended protocol from the registry ({exc.strerror})") from None
        text = info["protocol_text"]
    if protocol_hash(text) != info["protocol_sha256"]:
        raise DataError(f"{path}: not the protocol frozen in the registry (hash differs); copy protocol.yaml from "
                        "the study's administrator again (or delete it: the next command restores it)")
    protocol = load_protocol(path, base=Path(info["protocol_base"]), fallback=Path(root))
    if file_sha256(protocol.study_config) != info["study_config_sha256"]:
        raise DataError(f"{protocol.study_config}: the study configuration differs from the one frozen at `study "
                        "init` (hash differs from the registry); use the administrator's copy")
    return protocol


def _study(root: Path, info: dict[str, Any], protocol: Protocol, registry: dict[str, Any] | None = None):
    from nao_trainer.study.registry import Study, file_sha256

    entry = {"sha256": protocol.sha256, "base": info["protocol_base"], "study_config": str(protocol.study_config),
             "study_config_sha256": file_sha256(protocol.study_config), "name": protocol.name}
    return Study(Path(root), protocol, {"protocol": entry, "session_salt": info["session_salt"], "amendments": [],
                                        "participants": [], "unblindings": [], **(registry or {})})


def _role(conn, root: Path, what: str, want: str) -> dict[str, Any]:
    info = pg.study_info(conn)
    if info["role"] != want:
        who = pg.call(conn, what, "SELECT session_user")[0][0]
        mine = f"site {info['site']}" if info["role"] == "site" else info["role"]
        whose = "a site's role (an operator's PGUSER)" if want == "site" else "the statistician's role"
        raise ConfigError(f"{what}: {whose} only; connected as {who} ({mine}): set PGUSER to that role")
    return info


# --- a site's sessions: the outbox ---------------------------------------------------------------------

def _outbox_file(root: Path, key: str) -> Path:
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", key):
        raise DataError(f"session key {key!r}: not a key nao-trainer writes")
    return Path(root) / OUTBOX / f"{key}.json"


def _keep(root: Path, entry: dict[str, Any]) -> None:
    path = _outbox_file(root, entry["key"])
    try:
        path.parent.mkdir(exist_ok=True)
        write_text_atomic(path, json.dumps(entry, sort_keys=True, default=str))
    except OSError as exc:
        raise DataError(f"{path}: cannot keep the session's entry ({exc.strerror}); free disk space") from None


def _send(conn, entry: dict[str, Any]) -> str:
    return pg.record_session(conn, entry["key"], entry["pseudonym"], int(entry["number"]), entry.get("folder"),
                             entry["status"], entry.get("files"), entry)


def _outbox(root: Path) -> list[tuple[Path, dict[str, Any]]]:
    out = []
    for path in sorted((Path(root) / OUTBOX).glob("*.json")):
        try:
            entry = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):
            entry = None
        if not (isinstance(entry, dict) and all(isinstance(entry.get(k), str) for k in ("key", "pseudonym", "status"))
                and type(entry.get("number")) is int and entry["key"] == path.stem):
            raise DataError(f"{path}: not a session entry nao-trainer wrote (edited or torn); move it out of "
                            f"{path.parent} and run the command again")
        out.append((path, entry))
    return out


def flush(root: Path, conn, pseudonym: str | None = None, progress: TextIO | None = None) -> list[dict[str, Any]]:
    """Record what this laptop's outbox holds: sessions the registry did not take (the network went), and
    sessions whose process was killed (recorded as their folder says: ``completed`` counts, otherwise
    ``interrupted``). A session still running on this host is left. Each entry is removed from the outbox
    only after the registry took it: a kill in between records it again under its key, once."""
    from nao_trainer.study.registry import participant_folders, pid_alive
    from nao_trainer.study.runner import _adopted, _stamp_time

    pending = [(f, e) for f, e in _outbox(root) if pseudonym is None or e["pseudonym"] == pseudonym]
    if not pending:
        return []
    info = pg.study_info(conn)
    study = _study(root, info, open_protocol(root, info))
    host, done = socket.gethostname(), []
    known = {s["folder"] for s in pg.site_sessions(conn) if s["folder"]} | {e.get("folder") for _, e in pending}
    for path, entry in pending:
        if entry["status"] == "running":
            if entry.get("host") not in (None, host) or (entry.get("pid") and pid_alive(int(entry["pid"]))):
                continue  # running now (or another laptop's entry): not ours to close
            folder = entry.get("folder")
            if folder is None:  # the first folder of the participant made after the session started
                start = dt.datetime.fromisoformat(entry["started"]).astimezone().replace(tzinfo=None, microsecond=0)
                after = [f for f in participant_folders(study, entry["pseudonym"])
                         if f.name not in known and (_stamp_time(f.name) or start) >= start]
                folder = after[0].name if after else None
                known.add(folder)
            entry = _adopted(study, entry, folder)
            _keep(root, entry)
        entry["recorded_as"] = _send(conn, entry)
        path.unlink(missing_ok=True)
        done.append(entry)
        if progress is not None:
            print(f"study: {entry['pseudonym']}'s session {entry['number']} ({entry.get('folder') or 'no folder'}) "
                  f"recorded as {entry['recorded_as']} (from {OUTBOX}/)", file=progress, flush=True)
    return done


def record(root: Path, progress: TextIO | None = None) -> list[dict[str, Any]]:
    """``study record`` / ``study repair`` on a site's laptop: the outbox into the registry."""
    with connect(root) as conn:
        _role(conn, root, "study record", "site")
        return flush(root, conn, None, progress)


def _recorder(root: Path, progress: TextIO):
    """Each entry kept in the outbox first, then sent on a new connection (the session's may have gone);
    a final entry the registry took leaves the outbox. Unreachable: kept, one line, the session goes on."""
    said = []

    def send(entry: dict[str, Any]) -> None:
        _keep(root, entry)
        try:
            with connect(root) as conn:
                _send(conn, entry)
        except DataError as exc:
            if not said:
                print(f"study next: the registry cannot be reached ({exc}); the session goes on and is kept in "
                      f"{Path(root) / OUTBOX}: `nao-trainer study record {root}` (or the next `study next`) "
                      "records it when the network is back", file=progress, flush=True)
            said.append(entry["status"])
            return
        if entry["status"] != "running":
            _outbox_file(root, entry["key"]).unlink(missing_ok=True)

    send.failed = said  # type: ignore[attr-defined]
    return send


def run_next(root: Path, pseudonym: str, flags: dict[str, Any], options: Any, progress: TextIO | None = None,
             resume: bool = False):
    """``study next`` on a site's laptop: the next session's configuration from the registry (the arm's
    settings, not its name), played and recorded as on one laptop, through the outbox."""
    import uuid

    from nao_trainer.study.registry import now_iso
    from nao_trainer.study.runner import BLIND_LABEL, NextSession, check_blinding, days_between, participant_lock, \
        play, session_seed

    progress = progress or sys.stderr
    if resume:
        given = [k for k, v in flags.items() if v is not None]
        if given:
            raise ConfigError(f"--resume continues a session with its own configuration; drop the flags for "
                              f"{', '.join(given)}")
    with connect(root) as conn:
        info = _role(conn, root, "study next", "site")
        protocol = open_protocol(root, info)
        study = _study(root, info, protocol)
    with participant_lock(study, pseudonym, progress):
        with connect(root) as conn:
            flush(root, conn, pseudonym, progress)
            got = pg.session_config(conn, pseudonym)
            mine = [x for x in pg.site_sessions(conn) if x["pseudonym"] == pseudonym]
        per = protocol.sessions.per_participant
        if resume:
            return _resume(root, study, info, mine, pseudonym, options, progress)
        number = int(got["next_session"])
        if number > per:
            raise DataError(f"{pseudonym}: has completed all {per} sessions of the protocol")
        warning = ""
        if got.get("last_ended"):
            gap = days_between(got["last_ended"], dt.datetime.now(dt.timezone.utc).astimezone())
            lo, hi = protocol.sessions.min_days, protocol.sessions.max_days
            if not lo <= gap <= hi:
                warning = (f"{pseudonym}'s session {number} comes {gap:.1f} days after session {number - 1}; the "
                           f"protocol allows {lo:g}-{hi:g} days (the session is recorded as outside the interval)")
        settings = dict(got["config"])
        extra = {**{k: v for k, v in flags.items() if v is not None}, "participant.pseudonym": pseudonym,
                 "session.output": str(study.sessions_dir.resolve()),
                 "session.seed": session_seed(study, pseudonym, number)}
        if "policy.state_path" not in settings:
            extra["policy.state_path"] = participant_template(settings["policy.kind"])
        config = load_config(protocol.study_config, {**settings, **extra})
        plan = NextSession(pseudonym, "", number, config, warning, key=uuid.uuid4().hex)
        check_blinding(study, plan, options)
        if warning:
            print(f"warning: {warning}", file=progress, flush=True)
        print(f"study {protocol.name}: {pseudonym}, session {number} of {per}, {BLIND_LABEL} (site "
              f"{info['site']}; {now_iso()})", file=progress, flush=True)
        send = _recorder(root, progress)
        result = play(study, plan, options, progress, record=send)
        if send.failed and send.failed[-1] != "running":
            print(f"study next: {pseudonym}'s session {number} is kept in {Path(root) / OUTBOX} (not yet in the "
                  f"registry): run `nao-trainer study record {root}` when the network is back", file=progress,
                  flush=True)
        return plan, result


def _resume(root: Path, study, info: dict[str, Any], sessions: list[dict[str, Any]], pseudonym: str, options: Any,
            progress: TextIO):
    """``study next --resume`` on a site's laptop: the participant's last session, when the registry has it as
    interrupted and its folder is on this laptop, continued under its own key (``session.resume``)."""
    from nao_trainer.session.resume import prepare_resume
    from nao_trainer.study.runner import BLIND_LABEL, DONE, NextSession, check_blinding, play

    last = sessions[-1] if sessions else None
    if last is None or last["status"] in DONE or last["status"] == "duplicate" or not last["folder"]:
        raise DataError(f"{pseudonym}: no interrupted session to resume; run the next one without --resume")
    config, resumption = prepare_resume(study.sessions_dir / last["folder"])
    plan = NextSession(pseudonym, "", int(last["number"]), config, "", resumption, key=last["key"])
    check_blinding(study, plan, options)
    print(f"study {study.protocol.name}: {pseudonym}, session {plan.number} of "
          f"{study.protocol.sessions.per_participant} (resumed), {BLIND_LABEL} (site {info['site']})",
          file=progress, flush=True)
    send = _recorder(root, progress)
    result = play(study, plan, options, progress, record=send)
    if send.failed and send.failed[-1] != "running":
        print(f"study next: {pseudonym}'s session {plan.number} is kept in {Path(root) / OUTBOX} (not yet in the "
              f"registry): run `nao-trainer study record {root}` when the network is back", file=progress, flush=True)
    return plan, result


def withdraw(root: Path, pseudonym: str, data: str, reason: str = "") -> tuple[dict[str, Any], list[Path]]:
    """``study withdraw`` on the participant's site: recorded in the registry (the site's role, its own
    participants only), then with ``--data delete`` the participant's session folders and learning state on
    this laptop removed (a kill while deleting: the same command finishes it)."""
    from nao_trainer.study.registry import DATA_CHOICES, _running_session, delete_data

    if data not in DATA_CHOICES:
        raise ConfigError(f"--data {data!r}: use keep or delete")
    with connect(root) as conn:
        info = _role(conn, root, "study withdraw", "site")
        study = _study(root, info, open_protocol(root, info))
        running = _running_session(Path(root), pseudonym)
        if running:
            raise ConfigError(f"{pseudonym}: a session is running ({running}); stop it (key s or the console), "
                              "then record the withdrawal")
        flush(root, conn, pseudonym)  # a killed session of this participant is on record first
        entry = pg.withdraw(conn, pseudonym, data, reason)
        recorded = {s["folder"] for s in pg.site_sessions(conn) if s["pseudonym"] == pseudonym and s["folder"]}
    if entry["data"] != "delete":
        return entry, []
    return entry, delete_data(study, pseudonym, recorded)


def statistician_study(root: Path, what: str):
    """The study as the analysis and the export read it (``registry.Study``), for the statistician's role:
    participants and sessions from the registry, each counted session's folder under ``STUDY_DIR/sessions``
    checked against the checksums its site recorded, the arms read through ``unblind`` (so logged). A
    blinded study must have been unblinded first (``study unblind``), as on one laptop."""
    from nao_trainer.study.registry import file_sha256
    from nao_trainer.study.runner import DONE

    root = Path(root)
    with connect(root) as conn:
        info = _role(conn, root, what, "statistician")
        protocol = open_protocol(root, info)
        log = pg.call(conn, what, "SELECT time::text, who, reason FROM unblindings ORDER BY id")
        if protocol.blinding and not log:
            raise DataError(f"{root}: the study is blinded; its arms are revealed only after `nao-trainer study "
                            f"unblind {root} --reason TEXT` (the statistician; the unblinding is logged)")
        people = pg.call(conn, what, "SELECT pseudonym, number, site, stratum, consent_date::text, consent_version, "
                         "enrolled::text, withdrawn FROM participants ORDER BY number")
        rows = pg.call(conn, what, "SELECT key, pseudonym, number, folder, status, files, entry FROM sessions "
                       "ORDER BY pseudonym, number, recorded")
        amendments = [dict(zip(("time", "reason", "old_sha256", "new_sha256", "enrolled_at_amendment", "changes",
                                "study_config"), r))
                      for r in pg.call(conn, what, "SELECT time::text, reason, old_sha256, new_sha256, "
                                       "enrolled_at_amendment, changes, study_config FROM amendments ORDER BY id")]
        arms = dict(pg.unblind(conn, f"{what}: the arms read for it"))
    sessions: dict[str, list[dict[str, Any]]] = {}
    for key, pseud, number, folder, status, files, entry in rows:
        sessions.setdefault(pseud, []).append({**(entry or {}), "key": key, "number": number, "folder": folder,
                                               "status": status, "files": files})
    participants = []
    keys = ("pseudonym", "number", "site", "stratum", "consent_date", "consent_version", "enrolled", "withdrawn")
    for row in people:
        p = dict(zip(keys, row))
        p.update(allocation_index=None, arm=arms[p["pseudonym"]],
                 sessions=sessions.get(p["pseudonym"], []))
        participants.append(p)
        if p["withdrawn"] and p["withdrawn"].get("data") == "delete":
            continue
        for s in p["sessions"]:
            if s["status"] not in DONE:
                continue
            folder = root / "sessions" / (s["folder"] or "")
            if not s["folder"] or not folder.is_dir():
                raise DataError(f"{folder}: {p['pseudonym']}'s session {s['number']} (site {p['site']}) is not in "
                                f"{root / 'sessions'}; copy every site's sessions/ folder into it (e.g. rsync -a "
                                f"SITE:STUDY_DIR/sessions/ {root / 'sessions'}/), then run the command again")
            for name, sha in (s["files"] or {}).items():
                path = folder / name
                if not path.is_file() or file_sha256(path) != sha:
                    raise DataError(f"{path}: {'missing' if not path.is_file() else 'differs from the checksum'} "
                                    f"its site recorded ({p['pseudonym']} session {s['number']}); copy the folder "
                                    "from the site again")
    unblindings = [{"time": t, "who": w, "reason": r} for t, w, r in log]
    return _study(root, info, protocol, {"participants": participants, "unblindings": unblindings,
                                         "amendments": amendments})


def amend(root: Path, protocol_path: Path, reason: str, change_arms: bool = False) -> dict[str, Any]:
    """``study amend`` by the study's administrator (the role that ran ``study init``), with the rules of one
    laptop (``registry.amend``): once someone is enrolled, what the allocation was drawn from cannot change,
    and what an arm does only with ``change_arms``. Registry, arms' configurations and the amendment's
    record change in one transaction; each site's copy of the protocol is replaced by the registry's text
    at its next command (the old version is in the amendments)."""
    from nao_trainer.study.registry import allocation_sequence, arm_changes, entropy_rng, file_sha256

    if not reason.strip() or "\n" in reason.strip():
        raise ConfigError("--reason: an amendment needs its reason (one line)")
    with connect(root) as conn:
        info = pg.study_info(conn)
        if info["role"] != "admin":
            raise ConfigError(f"study amend: the study's administrator only (the role that ran `study init`); this "
                              f"is {'site ' + info['site'] if info['role'] == 'site' else info['role']}'s role")
        old = open_protocol(root, info)
        new = load_protocol(protocol_path, fallback=Path(info["protocol_base"]))
        new_config_sha = file_sha256(new.study_config)
        if new.sha256 == old.sha256 and new_config_sha == info["study_config_sha256"]:
            raise ConfigError(f"{protocol_path}: identical to the frozen protocol; nothing to amend")
        what = "study amend"
        enrolled = pg.call(conn, what, "SELECT count(*) FROM participants")[0][0]
        changes: list[str] = []
        drawn = lambda p: ([(a.name, a.ratio) for a in p.arms], p.allocation.block_size,  # noqa: E731
                           p.allocation.strata)
        if enrolled:
            if drawn(new) != drawn(old):
                raise ConfigError(f"{protocol_path}: changes the arms or the allocation after enrolment began; "
                                  "only other keys can be amended (start a new study for a new design)")
            changes = arm_changes(old, new)
            if changes and not change_arms:
                raise ConfigError(f"{protocol_path}: {'; '.join(changes)} while {enrolled} participant(s) are "
                                  "enrolled; if that is intended, give --change-arms (recorded in the registry and "
                                  "reported by the analysis)")
            shortest = pg.call(conn, what, "SELECT min(n) FROM (SELECT count(*) AS n FROM allocation GROUP BY "
                               "stratum) c")[0][0]
            if new.target_n > old.target_n and new.target_n > (shortest or 0):
                raise ConfigError(f"{protocol_path}: target_n {new.target_n} exceeds the allocation sequence drawn "
                                  "at init; start a new study")
        per_site = bool(pg.call(conn, what, "SELECT 1 FROM meta WHERE key = 'draw_per_site'"))
        if per_site and new.allocation.strata:
            raise ConfigError(f"{protocol_path}: strata of its own in a study stratified by site; use one or the other")
        psycopg = pg._psycopg()
        try:
            with conn.transaction():
                conn.execute("LOCK TABLE participants IN SHARE ROW EXCLUSIVE MODE")  # no enrolment meanwhile
                if conn.execute("SELECT count(*) FROM participants").fetchone()[0] != enrolled:
                    raise ConfigError(f"{root}: someone was enrolled meanwhile; run the amendment again")
                entry = {"reason": reason.strip(), "old_sha256": old.sha256, "new_sha256": new.sha256,
                         "enrolled_at_amendment": enrolled, "changes": changes, "study_config": str(new.study_config)}
                conn.execute("INSERT INTO amendments (reason, old_sha256, new_sha256, enrolled_at_amendment, changes, "
                             "study_config) VALUES (%s, %s, %s, %s, %s, %s)",
                             (entry["reason"], old.sha256, new.sha256, enrolled, json.dumps(changes),
                              entry["study_config"]))
                for key, value in {"protocol_text": new.text, "protocol_sha256": new.sha256,
                                   "study_config_sha256": new_config_sha, "study_config": str(new.study_config),
                                   "protocol_base": new.base, "target_n": new.target_n}.items():
                    conn.execute("INSERT INTO meta VALUES (%s, %s) ON CONFLICT (key) DO UPDATE SET value = "
                                 "EXCLUDED.value", (key, json.dumps(value)))
                if not enrolled:  # nobody allocated yet: the sequence of the new design
                    sites = [r[0] for r in conn.execute("SELECT name FROM sites ORDER BY name")]
                    conn.execute("DELETE FROM allocation")
                    conn.execute("DELETE FROM arms")
                    for a in new.arms:
                        conn.execute("INSERT INTO arms VALUES (%s, %s)",
                                     (a.name, json.dumps(a.config_overrides(), sort_keys=True)))
                    draw = entropy_rng()
                    sequences = {s: allocation_sequence(new, draw)[""] for s in sites} if per_site \
                        else allocation_sequence(new, draw)
                    with conn.cursor() as cur:
                        cur.executemany("INSERT INTO allocation VALUES (%s, %s, %s)",
                                        [(k, i, arm) for k, seq in sequences.items() for i, arm in enumerate(seq)])
                else:
                    for a in new.arms:
                        conn.execute("UPDATE arms SET config = %s WHERE name = %s",
                                     (json.dumps(a.config_overrides(), sort_keys=True), a.name))
                entry["time"] = conn.execute("SELECT now()::text").fetchone()[0]
        except psycopg.errors.InsufficientPrivilege as exc:
            raise pg._refused(exc, what) from None
    try:
        write_text_atomic(Path(root) / "protocol.yaml", new.text)
    except OSError:
        pass  # the registry holds the text; the next command restores the copy
    return entry
