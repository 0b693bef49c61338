"""The study registry on a PostgreSQL server, blinding enforced by the database (issue 31 items 2-3).

One database per study. ``create`` (run by the study's administrator, a role that may create roles)
lays out the tables, the group roles and the functions:

* ``<prefix>_operator`` (a group; each site's login role is a member, ``site_add``): no privilege on any
  table. It enrols (``enrol``: the next slot of the ONE concealed sequence, stratified by site when the
  protocol says so, a pseudonym from its site's range), reads its site's pseudonyms, consent and session
  counts (view ``site_participants``, filtered by ``session_user``; its sessions' keys, folders and
  statuses: ``site_sessions``), records sessions by an idempotent key (``record_session``: a laptop that
  lost the network records once when it is back; a counted session is never set back, a second counted
  session N of a participant is kept as ``duplicate``), records withdrawals (``withdraw``) and receives the
  configuration of its next session (``session_config``: the arm's settings, not its name). It cannot
  SELECT an arm: the table ``allocation`` grants it nothing, and every function it may call is
  ``SECURITY DEFINER`` with a fixed ``search_path``.
* ``<prefix>_statistician``: ``unblind(reason)`` returns every participant's arm and logs the unblinding
  (time, role, reason) in the same transaction; it may read the log and the sessions, not the table of arms.
* both: ``study_info()``: the schema version, the protocol's hash and text, the study configuration's
  hash, the session salt and which role the caller is.

Credentials are never written here or into the study folder: a URL carries no password, libpq reads it
from ``PGPASSWORD``, ``PGPASSFILE`` (``~/.pgpass``) or a service file (``PGSERVICEFILE``). ``site_add``
returns the new site's password once, to hand to the site.

psycopg 3 (the ``study-pg`` extra) is imported only when a PostgreSQL registry is used.
"""
from __future__ import annotations

import json
import re
import secrets
from typing import Any

from nao_trainer.errors import ConfigError, DataError

SCHEMA_VERSION = 2  # 2: sessions keep their whole entry; withdraw, study_info, site_sessions
DONE = ("completed", "time limit")  # the statuses that count towards a participant's sessions (study.runner)
_NAME = re.compile(r"[a-z][a-z0-9_]{0,30}")


def _psycopg():
    try:
        import psycopg
    except ImportError:
        raise ConfigError("a PostgreSQL registry needs psycopg: pip install 'nao-trainer[study-pg]'") from None
    return psycopg


def _ident(name: str, what: str) -> str:
    if not _NAME.fullmatch(name):
        raise ConfigError(f"{what} {name!r}: use lower-case letters, digits and _ (starting with a letter, "
                          "at most 31 characters)")
    return name


def redact(url: str) -> str:
    """The URL without a password (for messages)."""
    return re.sub(r"(://[^:/@]+):[^@]*@", r"\1:***@", url)


def connect(url: str, **kwargs: Any):
    """A connection, or one line: the server cannot be reached, or the credentials are refused."""
    psycopg = _psycopg()
    if re.search(r"://[^/@]*:[^@]*@", url) or re.search(r"(^|[?&\s])password=", url):
        raise ConfigError(f"{redact(url)}: a registry URL must not carry a password; give it in PGPASSWORD, "
                          "a PGPASSFILE or a service file")
    try:
        return psycopg.connect(url, connect_timeout=10, **kwargs)
    except psycopg.OperationalError as exc:
        text = " ".join(str(exc).split())
        if "password" in text or "authentication" in text or "role" in text and "does not exist" in text:
            raise ConfigError(f"{redact(url)}: the server refused the credentials ({text}); check PGPASSFILE / "
                              "PGPASSWORD / the service file for this role") from None
        raise DataError(f"{redact(url)}: cannot reach the registry server ({text}); check the network and the "
                        "URL, then run the command again") from None


def _refused(exc: BaseException, what: str) -> ConfigError:
    return ConfigError(f"{what}: refused by the registry ({' '.join(str(exc).split())}); this role may not do it")


def call(conn, what: str, sql: str, params: tuple = ()) -> list[tuple]:
    """One statement in one transaction; a privilege error is one line."""
    psycopg = _psycopg()
    try:
        with conn.transaction():
            cur = conn.execute(sql, params)
            return cur.fetchall() if cur.description else []
    except psycopg.errors.InsufficientPrivilege as exc:
        raise _refused(exc, what) from None
    except psycopg.errors.RaiseException as exc:
        raise ConfigError(f"{what}: {exc.diag.message_primary}") from None
    except psycopg.IntegrityError as exc:
        raise ConfigError(f"{what}: refused by the registry ({exc.diag.message_primary})") from None
    except psycopg.OperationalError as exc:
        raise DataError(f"{what}: lost the registry server ({' '.join(str(exc).split())}); nothing was changed "
                        "unless the command says so; run it again") from None


def create(conn, prefix: str, sequences: dict[str, list[str]], arm_configs: dict[str, dict[str, Any]],
           stratify_by_site: bool, target_n: int, pseudonym_prefix: str = "P",
           public: dict[str, Any] | None = None) -> None:
    """Tables, roles and functions of a new study registry in the connected (empty) database."""
    p = _ident(prefix, "study prefix")
    op, st = f"{p}_operator", f"{p}_statistician"
    ddl = f"""
    CREATE TABLE meta (key text PRIMARY KEY, value jsonb NOT NULL);
    CREATE TABLE arms (name text PRIMARY KEY, config jsonb NOT NULL);
    CREATE TABLE allocation (stratum text NOT NULL, position int NOT NULL, arm text NOT NULL REFERENCES arms,
                             PRIMARY KEY (stratum, position));
    CREATE TABLE sites (name text PRIMARY KEY, role name NOT NULL UNIQUE, first_number int NOT NULL,
                        last_number int NOT NULL, next_number int NOT NULL);
    CREATE TABLE participants (pseudonym text PRIMARY KEY, number int NOT NULL UNIQUE,
                               site text NOT NULL REFERENCES sites, stratum text NOT NULL,
                               allocation_index int NOT NULL, consent_date date NOT NULL,
                               consent_version text NOT NULL, enrolled timestamptz NOT NULL DEFAULT now(),
                               withdrawn jsonb, UNIQUE (stratum, allocation_index));
    CREATE TABLE sessions (key text PRIMARY KEY, pseudonym text NOT NULL REFERENCES participants,
                           number int NOT NULL, folder text, status text NOT NULL, files jsonb,
                           entry jsonb NOT NULL DEFAULT '{{}}', recorded_by name NOT NULL DEFAULT session_user,
                           recorded timestamptz NOT NULL DEFAULT now());
    -- a participant's session N counts once: a second laptop's completed session N is kept as 'duplicate'
    CREATE UNIQUE INDEX sessions_done_once ON sessions (pseudonym, number) WHERE status IN ('completed', 'time limit');
    CREATE TABLE unblindings (id serial PRIMARY KEY, time timestamptz NOT NULL DEFAULT now(),
                              who name NOT NULL, reason text NOT NULL);
    CREATE TABLE amendments (id serial PRIMARY KEY, time timestamptz NOT NULL DEFAULT now(),
                             who name NOT NULL DEFAULT session_user, reason text NOT NULL, old_sha256 text NOT NULL,
                             new_sha256 text NOT NULL, enrolled_at_amendment int NOT NULL,
                             changes jsonb NOT NULL DEFAULT '[]', study_config text NOT NULL);
    REVOKE ALL ON ALL TABLES IN SCHEMA public FROM PUBLIC;
    REVOKE CREATE ON SCHEMA public FROM PUBLIC;

    CREATE VIEW site_participants AS
      SELECT pa.pseudonym, pa.site, pa.consent_date, pa.consent_version, pa.enrolled, pa.withdrawn IS NOT NULL
             AS withdrawn, (SELECT count(*) FROM sessions s WHERE s.pseudonym = pa.pseudonym
                            AND s.status IN ('completed', 'time limit')) AS sessions_done
      FROM participants pa JOIN sites si ON si.name = pa.site WHERE si.role = session_user;

    CREATE VIEW site_sessions AS
      SELECT s.key, s.pseudonym, s.number, s.folder, s.status, s.entry ->> 'ended' AS ended, s.recorded
      FROM sessions s JOIN participants pa ON pa.pseudonym = s.pseudonym JOIN sites si ON si.name = pa.site
      WHERE si.role = session_user;

    CREATE FUNCTION study_info() RETURNS jsonb LANGUAGE sql STABLE SECURITY DEFINER
      SET search_path = public, pg_temp AS $$
      SELECT jsonb_object_agg(key, value) || jsonb_build_object(
               'earlier_sha256', (SELECT coalesce(jsonb_agg(old_sha256), '[]') FROM amendments), 'role',
               CASE WHEN EXISTS (SELECT 1 FROM sites WHERE role = session_user) THEN 'site'
                    WHEN session_user = (SELECT tableowner FROM pg_tables WHERE schemaname = 'public'
                                         AND tablename = 'meta')
                         OR (SELECT rolsuper FROM pg_roles WHERE rolname = session_user) THEN 'admin'
                    WHEN pg_has_role(session_user, '{st}', 'MEMBER') THEN 'statistician' ELSE 'other' END,
               'site', (SELECT name FROM sites WHERE role = session_user))
      FROM meta WHERE key IN ('schema_version', 'prefix', 'protocol_sha256', 'study_config_sha256', 'protocol_base',
                              'session_salt', 'protocol_text')
    $$;

    CREATE FUNCTION enrol(consent date, consent_version text, stratum text DEFAULT '')
      RETURNS text LANGUAGE plpgsql SECURITY DEFINER SET search_path = public, pg_temp AS $$
    DECLARE s sites; key text; pos int; n int; pseud text; total int;
    BEGIN
      SELECT * INTO s FROM sites WHERE role = session_user FOR UPDATE;
      IF NOT FOUND THEN RAISE EXCEPTION 'role % is not a site of this study', session_user; END IF;
      IF trim(consent_version) = '' THEN RAISE EXCEPTION 'give the consent version'; END IF;
      LOCK TABLE participants IN SHARE ROW EXCLUSIVE MODE;  -- one concealed sequence, one slot at a time
      SELECT count(*) INTO total FROM participants;
      IF total >= (SELECT (value #>> '{{}}')::int FROM meta WHERE meta.key = 'target_n') THEN
        RAISE EXCEPTION 'target_n participants already enrolled'; END IF;
      key := CASE WHEN (SELECT value = 'true'::jsonb FROM meta WHERE meta.key = 'stratify_by_site')
                  THEN s.name ELSE stratum END;
      SELECT count(*) INTO pos FROM participants p WHERE p.stratum = key;
      IF NOT EXISTS (SELECT 1 FROM allocation a WHERE a.stratum = key AND a.position = pos) THEN
        RAISE EXCEPTION 'the allocation sequence of stratum % is used up or unknown', key; END IF;
      n := s.next_number;
      IF n > s.last_number THEN RAISE EXCEPTION 'site %: its pseudonym range is used up', s.name; END IF;
      pseud := (SELECT value #>> '{{}}' FROM meta WHERE meta.key = 'pseudonym_prefix') || lpad(n::text, 3, '0');
      INSERT INTO participants (pseudonym, number, site, stratum, allocation_index, consent_date, consent_version)
        VALUES (pseud, n, s.name, key, pos, consent, trim(consent_version));
      UPDATE sites SET next_number = n + 1 WHERE name = s.name;
      RETURN pseud;
    END $$;

    CREATE FUNCTION _own(pseud text) RETURNS participants LANGUAGE plpgsql SECURITY DEFINER
      SET search_path = public, pg_temp AS $$
    DECLARE p participants;
    BEGIN
      SELECT pa.* INTO p FROM participants pa JOIN sites si ON si.name = pa.site
        WHERE pa.pseudonym = pseud AND si.role = session_user;
      IF NOT FOUND THEN RAISE EXCEPTION '% is not a participant of your site', pseud; END IF;
      RETURN p;
    END $$;

    CREATE FUNCTION session_config(pseud text) RETURNS jsonb LANGUAGE plpgsql SECURITY DEFINER
      SET search_path = public, pg_temp AS $$
    DECLARE p participants;
    BEGIN
      p := _own(pseud);
      IF p.withdrawn IS NOT NULL THEN
        RAISE EXCEPTION '%: withdrew on %; no further sessions', pseud, left(p.withdrawn ->> 'time', 10); END IF;
      RETURN jsonb_build_object('pseudonym', p.pseudonym, 'next_session',
               (SELECT count(*) FROM sessions s WHERE s.pseudonym = p.pseudonym
                AND s.status IN ('completed', 'time limit')) + 1,
               'last_ended', (SELECT s.entry ->> 'ended' FROM sessions s WHERE s.pseudonym = p.pseudonym
                              AND s.status IN ('completed', 'time limit') ORDER BY s.number DESC LIMIT 1),
               'config', (SELECT ar.config FROM allocation a JOIN arms ar ON ar.name = a.arm
                          WHERE a.stratum = p.stratum AND a.position = p.allocation_index));
    END $$;

    -- idempotent by its key: recorded again (a retry after the network came back) it is one row; a counted
    -- session is never set back (a late 'running'); a second counted session N of a participant is 'duplicate'
    CREATE FUNCTION record_session(skey text, pseud text, num int, folder text, status text, files jsonb,
                                   entry jsonb DEFAULT '{{}}') RETURNS text LANGUAGE plpgsql SECURITY DEFINER
      SET search_path = public, pg_temp AS $$
    DECLARE p participants; old sessions; st text := status;
    BEGIN
      p := _own(pseud);
      PERFORM 1 FROM participants pa WHERE pa.pseudonym = p.pseudonym FOR UPDATE;  -- one record at a time
      SELECT * INTO old FROM sessions s WHERE s.key = skey;
      IF FOUND AND (old.pseudonym <> p.pseudonym OR old.number <> num) THEN
        RAISE EXCEPTION 'session key % is recorded for another session', skey; END IF;
      IF FOUND AND old.status IN ('completed', 'time limit', 'duplicate') AND NOT st IN ('completed', 'time limit') THEN
        RETURN old.status; END IF;
      IF st IN ('completed', 'time limit') AND EXISTS (SELECT 1 FROM sessions s WHERE s.pseudonym = p.pseudonym
           AND s.number = num AND s.key <> skey AND s.status IN ('completed', 'time limit')) THEN
        st := 'duplicate'; END IF;
      INSERT INTO sessions AS s (key, pseudonym, number, folder, status, files, entry)
        VALUES (skey, p.pseudonym, num, folder, st, files, entry)
        ON CONFLICT (key) DO UPDATE SET status = EXCLUDED.status, files = EXCLUDED.files, folder = EXCLUDED.folder,
          entry = EXCLUDED.entry, recorded = now(), recorded_by = session_user;
      RETURN st;
    END $$;

    CREATE FUNCTION withdraw(pseud text, data text, reason text) RETURNS jsonb LANGUAGE plpgsql SECURITY DEFINER
      SET search_path = public, pg_temp AS $$
    DECLARE p participants; w jsonb;
    BEGIN
      p := _own(pseud);
      IF data NOT IN ('keep', 'delete') THEN RAISE EXCEPTION '--data %: use keep or delete', data; END IF;
      IF p.withdrawn IS NOT NULL THEN
        IF p.withdrawn ->> 'data' = 'delete' THEN RETURN p.withdrawn; END IF;  -- a deletion to finish
        RAISE EXCEPTION '%: already withdrawn on %', pseud, p.withdrawn ->> 'time'; END IF;
      w := jsonb_build_object('time', to_char(now() AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS"+00:00"'),
                              'data', data, 'reason', reason, 'by', session_user);
      UPDATE participants SET withdrawn = w WHERE pseudonym = p.pseudonym;
      RETURN w;
    END $$;

    CREATE FUNCTION unblind(reason text) RETURNS TABLE (pseudonym text, arm text) LANGUAGE plpgsql
      SECURITY DEFINER SET search_path = public, pg_temp AS $$
    BEGIN
      IF trim(reason) = '' THEN RAISE EXCEPTION 'an unblinding needs its reason'; END IF;
      INSERT INTO unblindings (who, reason) VALUES (session_user, trim(reason));
      RETURN QUERY SELECT pa.pseudonym, a.arm FROM participants pa
        JOIN allocation a ON a.stratum = pa.stratum AND a.position = pa.allocation_index ORDER BY pa.number;
    END $$;

    REVOKE ALL ON ALL FUNCTIONS IN SCHEMA public FROM PUBLIC;
    CREATE ROLE {op} NOLOGIN;
    CREATE ROLE {st} NOLOGIN;
    GRANT USAGE ON SCHEMA public TO {op}, {st};
    GRANT SELECT ON site_participants, site_sessions TO {op};
    GRANT EXECUTE ON FUNCTION enrol(date, text, text), session_config(text),
          record_session(text, text, int, text, text, jsonb, jsonb), withdraw(text, text, text) TO {op};
    GRANT EXECUTE ON FUNCTION study_info() TO {op}, {st};
    GRANT EXECUTE ON FUNCTION unblind(text) TO {st};
    GRANT SELECT ON unblindings, sessions, sites, meta, amendments TO {st};
    GRANT SELECT (pseudonym, number, site, stratum, consent_date, consent_version, enrolled, withdrawn)
          ON participants TO {st};
    """
    with conn.transaction():
        conn.execute(ddl)
        for k, v in {"schema_version": SCHEMA_VERSION, "prefix": p, "target_n": target_n,
                     "stratify_by_site": stratify_by_site, "pseudonym_prefix": pseudonym_prefix,
                     "session_salt": secrets.token_hex(16), **(public or {})}.items():
            conn.execute("INSERT INTO meta VALUES (%s, %s)", (k, json.dumps(v)))
        for name, config in arm_configs.items():
            conn.execute("INSERT INTO arms VALUES (%s, %s)", (name, json.dumps(config, sort_keys=True)))
        with conn.cursor() as cur:
            cur.executemany("INSERT INTO allocation VALUES (%s, %s, %s)",
                            [(k, i, arm) for k, seq in sequences.items() for i, arm in enumerate(seq)])


def site_add(conn, name: str, size: int = 100) -> tuple[str, str]:
    """A site: its own login role (a member of the operator group) and its own pseudonym range.
    Returns (role, password): the password is shown once and stored nowhere by nao-trainer."""
    site = _ident(name, "site name")
    prefix = call(conn, "study site add", "SELECT value #>> '{}' FROM meta WHERE key = 'prefix'")[0][0]
    role = _ident(f"{prefix}_site_{site}", "site role")
    password = secrets.token_urlsafe(24)
    psycopg = _psycopg()
    from psycopg import sql
    try:
        with conn.transaction():
            if conn.execute("SELECT 1 FROM sites WHERE name = %s", (site,)).fetchone():
                raise ConfigError(f"site {site!r} already exists")
            first = conn.execute("SELECT coalesce(max(last_number), 0) + 1 FROM sites").fetchone()[0]
            conn.execute(sql.SQL("CREATE ROLE {} LOGIN PASSWORD {} IN ROLE {}").format(
                sql.Identifier(role), sql.Literal(password), sql.Identifier(f"{prefix}_operator")))
            conn.execute("INSERT INTO sites VALUES (%s, %s, %s, %s, %s)", (site, role, first, first + size - 1, first))
    except psycopg.errors.DuplicateObject:
        raise ConfigError(f"role {role!r} already exists on the server; choose another site name") from None
    except psycopg.errors.InsufficientPrivilege as exc:
        raise _refused(exc, "study site add") from None
    return role, password


def statistician_add(conn, login: str) -> tuple[str, str]:
    """A login role for the statistician; returns its password (shown once)."""
    prefix = call(conn, "study statistician add", "SELECT value #>> '{}' FROM meta WHERE key = 'prefix'")[0][0]
    role = _ident(f"{prefix}_{_ident(login, 'login')}", "statistician role")
    password = secrets.token_urlsafe(24)
    from psycopg import sql
    with conn.transaction():
        conn.execute(sql.SQL("CREATE ROLE {} LOGIN PASSWORD {} IN ROLE {}").format(
            sql.Identifier(role), sql.Literal(password), sql.Identifier(f"{prefix}_statistician")))
    return role, password


# --- what a site's laptop calls ----------------------------------------------------------------------

def enrol(conn, consent_date: str, consent_version: str, stratum: str = "") -> str:
    return call(conn, "study enrol", "SELECT enrol(%s, %s, %s)", (consent_date, consent_version, stratum))[0][0]


def site_participants(conn) -> list[dict[str, Any]]:
    rows = call(conn, "study status", "SELECT pseudonym, site, consent_date::text, consent_version, withdrawn, "
                "sessions_done FROM site_participants ORDER BY pseudonym")
    keys = ("pseudonym", "site", "consent_date", "consent_version", "withdrawn", "sessions_done")
    return [dict(zip(keys, r)) for r in rows]


def session_config(conn, pseudonym: str) -> dict[str, Any]:
    return call(conn, "study next", "SELECT session_config(%s)", (pseudonym,))[0][0]


def record_session(conn, key: str, pseudonym: str, number: int, folder: str | None, status: str,
                   files: dict[str, str] | None, entry: dict[str, Any] | None = None) -> str:
    """Idempotent by ``key``: the same session recorded again (a retry after the network came back) is one row.
    Returns the status recorded (``duplicate`` when the participant's session ``number`` already counts)."""
    return call(conn, "study record", "SELECT record_session(%s, %s, %s, %s, %s, %s, %s)",
                (key, pseudonym, number, folder, status, json.dumps(files) if files is not None else None,
                 json.dumps(entry or {}, default=str)))[0][0]


def study_info(conn) -> dict[str, Any]:
    """What every role may read of the study: schema version, protocol hashes, session salt, its own role."""
    psycopg = _psycopg()
    try:
        with conn.transaction():
            info = conn.execute("SELECT study_info()").fetchone()[0]
    except psycopg.errors.UndefinedFunction:
        raise ConfigError("the registry was created by an earlier nao-trainer (schema 1, without study_info); "
                          "create the study again with `study init --registry` on an empty database") from None
    except psycopg.errors.InsufficientPrivilege as exc:
        raise _refused(exc, "study") from None
    except psycopg.OperationalError as exc:
        raise DataError(f"lost the registry server ({' '.join(str(exc).split())}); run the command again") from None
    if info.get("schema_version") != SCHEMA_VERSION:
        raise ConfigError(f"the registry has schema {info.get('schema_version')}, this nao-trainer reads schema "
                          f"{SCHEMA_VERSION}; use the nao-trainer version that created the study")
    return info


def site_sessions(conn) -> list[dict[str, Any]]:
    rows = call(conn, "study next", "SELECT key, pseudonym, number, folder, status, ended FROM site_sessions "
                "ORDER BY pseudonym, number, recorded")
    return [dict(zip(("key", "pseudonym", "number", "folder", "status", "ended"), r)) for r in rows]


def withdraw(conn, pseudonym: str, data: str, reason: str) -> dict[str, Any]:
    return call(conn, "study withdraw", "SELECT withdraw(%s, %s, %s)", (pseudonym, data, reason))[0][0]


def unblind(conn, reason: str) -> list[tuple[str, str]]:
    return [tuple(r) for r in call(conn, "study unblind", "SELECT * FROM unblind(%s)", (reason,))]
