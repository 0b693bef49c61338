"""A study folder whose registry is on a PostgreSQL server (``study init --registry postgresql://...``).

The folder holds ``protocol.yaml`` and ``registry.url``: the server and database, with neither user nor
password (each command connects as the role of whoever runs it: ``PGUSER`` or the service file, the
password from ``PGPASSWORD``, ``PGPASSFILE`` or the service file). Enrolment, status, sites and the
unblinding go through ``study.pg``.
"""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import write_text_atomic
from nao_trainer.study import pg
from nao_trainer.study.protocol import load_protocol

URL_FILE = "registry.url"


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


def init(protocol_path: Path, out: Path, url: str, stratify_by_site: bool) -> dict[str, Any]:
    """Create the registry in the (empty) database ``url`` as the connecting administrator, and the folder."""
    from nao_trainer.study.registry import allocation_sequence, entropy_rng

    if not re.match(r"postgres(ql)?://", url):
        raise ConfigError(f"--registry {url!r}: give a postgresql:// URL")
    out = Path(out)
    if is_remote(out) or (out / "registry.db").is_file():
        raise ConfigError(f"{out}: already holds a study; give another --out")
    protocol = load_protocol(protocol_path)
    if protocol.allocation.strata and stratify_by_site:
        raise ConfigError("--stratify-by-site: the protocol has strata of its own; use one or the other")
    if protocol.allocation.strata:
        raise ConfigError(f"{protocol_path}: strata other than the site are not supported on PostgreSQL yet")
    draw = entropy_rng()
    conn = pg.connect(url, autocommit=True)
    with conn:
        if pg.call(conn, "study init", "SELECT count(*) FROM pg_tables WHERE schemaname = 'public'")[0][0]:
            raise ConfigError(f"{pg.redact(url)}: the database is not empty; create an empty one for the study")
        db = pg.call(conn, "study init", "SELECT current_database()")[0][0]
        prefix = re.sub(r"[^a-z0-9_]", "_", db.lower())[:20]
        prefix = prefix if re.match(r"[a-z]", prefix) else f"s_{prefix}"[:20]
        # stratified by site: a sequence per site, drawn as sites are added (the sequence of '' is unused)
        sequences = allocation_sequence(protocol, draw)
        pg.create(conn, prefix, sequences, {a.name: a.config_overrides() for a in protocol.arms},
                  stratify_by_site, protocol.target_n, protocol.pseudonym_prefix)
        pg.call(conn, "study init", "INSERT INTO meta VALUES ('protocol_base', %s)",
                (json.dumps(str(Path(protocol.source).parent)),))
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
            base = pg.call(conn, "study site add", "SELECT value #>> '{}' FROM meta WHERE key = 'protocol_base'")
            protocol = load_protocol(Path(root) / "protocol.yaml", base=Path(base[0][0]))
            seq = allocation_sequence(protocol, entropy_rng())[""]
            with conn.transaction(), conn.cursor() as cur:
                cur.executemany("INSERT INTO allocation VALUES (%s, %s, %s)",
                                [(name, i, arm) for i, arm in enumerate(seq)])
    return role, password


def enrol(root: Path, consent_date: str, consent_version: str) -> str:
    with connect(root) as conn:
        return pg.enrol(conn, consent_date, consent_version)


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
            return lines
        rows = pg.call(conn, "study status", "SELECT p.site, count(DISTINCT p.pseudonym), count(s.key) FILTER "
                       "(WHERE s.status = 'completed') FROM participants p LEFT JOIN sessions s ON "
                       "s.pseudonym = p.pseudonym GROUP BY p.site ORDER BY p.site")
        log = pg.call(conn, "study status", "SELECT time::text, who, reason FROM unblindings ORDER BY id")
    lines.append("  per site (participants, completed sessions; arms only through `study unblind`, logged):")
    lines += [f"  {site}: {n} participant(s), {done} session(s)" for site, n, done in rows]
    lines += [f"  unblinded {t} by {w}: {r}" for t, w, r in log] or ["  not unblinded"]
    return lines


def unblind(root: Path, reason: str) -> list[tuple[str, str]]:
    with connect(root) as conn:
        return pg.unblind(conn, reason)
