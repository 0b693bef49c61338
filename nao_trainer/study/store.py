"""The study registry in a database: one storage interface, SQLite in the study folder by default.

Why plain ``sqlite3`` (the standard library) and not SQLAlchemy + Alembic: the schema is six small
tables, every query is written once here, and the registry must open on a lab laptop with nothing to
install; a versioned schema is the ``meta.schema_version`` row and the ordered ``MIGRATIONS`` below, run
in the transaction that opens an older file. (Measured on this machine: ``import sqlite3`` 2 ms.)

Every command is ONE transaction (``BEGIN IMMEDIATE``: writers queue, 60 s busy timeout), in WAL mode
with ``synchronous=FULL``: a SIGKILL or a full disk at any moment leaves the state before or after the
command, never a mix. Each transaction checks the registry's HMAC (``seal.mac``) before it reads and
writes a new one before it commits: a row edited with the ``sqlite3`` shell is refused in one line.
"""
from __future__ import annotations

import contextlib
import json
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from nao_trainer.errors import DataError
from nao_trainer.study import seal

DB_FILE = "registry.db"
FORMAT = "nao-trainer/study-registry-db"
SCHEMA_VERSION = 1
_FIX = "restore the study folder from a backup; the registry must not be edited by hand"

_SCHEMA_V1 = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE allocation (stratum TEXT NOT NULL, position INTEGER NOT NULL, sealed_arm TEXT NOT NULL,
                         PRIMARY KEY (stratum, position));
CREATE TABLE participants (pseudonym TEXT PRIMARY KEY, number INTEGER NOT NULL UNIQUE, site TEXT NOT NULL,
                           stratum TEXT NOT NULL, allocation_index INTEGER NOT NULL, consent_date TEXT NOT NULL,
                           consent_version TEXT NOT NULL, enrolled TEXT NOT NULL, withdrawn TEXT,
                           UNIQUE (stratum, allocation_index));
CREATE TABLE sessions (key TEXT PRIMARY KEY, pseudonym TEXT NOT NULL REFERENCES participants(pseudonym),
                       number INTEGER NOT NULL, folder TEXT, status TEXT NOT NULL, exit_code INTEGER,
                       started TEXT, ended TEXT, outside_interval INTEGER NOT NULL DEFAULT 0,
                       protocol_sha256 TEXT NOT NULL, host TEXT, pid INTEGER, files TEXT);
CREATE TABLE amendments (id INTEGER PRIMARY KEY, time TEXT NOT NULL, reason TEXT NOT NULL,
                         old_sha256 TEXT NOT NULL, new_sha256 TEXT NOT NULL, enrolled_at_amendment INTEGER NOT NULL,
                         changes TEXT NOT NULL DEFAULT '[]');
CREATE TABLE unblindings (id INTEGER PRIMARY KEY, time TEXT NOT NULL, who TEXT NOT NULL, reason TEXT NOT NULL);
"""
#: schema version -> the SQL that brings the previous version to it (version 1: the schema itself)
MIGRATIONS: dict[int, str] = {1: _SCHEMA_V1}

_SESSION_COLS = ("key", "pseudonym", "number", "folder", "status", "exit_code", "started", "ended",
                 "outside_interval", "protocol_sha256", "host", "pid", "files")


def db_error(path: Path, exc: BaseException) -> DataError:
    """A database failure in one line: a full disk or a file limit changes nothing (the transaction is
    rolled back); anything else is a damaged file."""
    text = str(exc)
    if isinstance(exc, sqlite3.OperationalError) and ("full" in text or "disk I/O" in text or "locked" in text):
        return DataError(f"{path}: cannot write the registry ({text}): nothing was changed; free disk space (or "
                         "raise the file size limit) and run the command again")
    if isinstance(exc, OSError):
        return DataError(f"{path}: cannot write ({exc.strerror}): the registry was not changed; free disk space "
                         "and run the command again")
    return DataError(f"{path}: not a readable study registry ({text}); {_FIX}")


@dataclass
class Tx:
    """One open transaction on the registry (the storage interface the study layer writes through)."""

    conn: sqlite3.Connection
    path: Path
    key: bytes | None

    # --- reading -------------------------------------------------------------------------------------
    def meta(self, name: str, default: Any = ...) -> Any:
        row = self.conn.execute("SELECT value FROM meta WHERE key = ?", (name,)).fetchone()
        if row is None:
            if default is ...:
                raise DataError(f"{self.path}: the registry has no {name!r}: edited or corrupt; {_FIX}")
            return default
        try:
            return json.loads(row[0])
        except (ValueError, RecursionError):
            raise DataError(f"{self.path}: the registry's {name!r} is malformed: edited or corrupt; {_FIX}") from None

    def rows(self, table: str, order: str) -> list[dict[str, Any]]:
        cur = self.conn.execute(f"SELECT * FROM {table} ORDER BY {order}")  # noqa: S608 (names are ours)
        names = [d[0] for d in cur.description]
        return [dict(zip(names, r)) for r in cur.fetchall()]

    def content(self) -> dict[str, Any]:
        """Everything the HMAC covers."""
        meta = {r["key"]: r["value"] for r in self.rows("meta", "key") if r["key"] != "seal"}
        return {"meta": meta, "allocation": self.rows("allocation", "stratum, position"),
                "participants": self.rows("participants", "number"), "sessions": self.rows("sessions", "key"),
                "amendments": self.rows("amendments", "id"), "unblindings": self.rows("unblindings", "id")}

    # --- writing -------------------------------------------------------------------------------------
    def set_meta(self, name: str, value: Any) -> None:
        self.conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)",
                          (name, json.dumps(value, sort_keys=True)))

    def add_allocation(self, sequences: dict[str, list[str]]) -> None:
        assert self.key is not None
        self.conn.execute("DELETE FROM allocation")
        self.conn.executemany("INSERT INTO allocation VALUES (?, ?, ?)",
                              [(stratum, i, seal.seal(self.key, arm)) for stratum, seq in sequences.items()
                               for i, arm in enumerate(seq)])

    def add_participant(self, p: dict[str, Any]) -> None:
        self.conn.execute("INSERT INTO participants VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                          (p["pseudonym"], p["number"], p.get("site", ""), p["stratum"], p["allocation_index"],
                           p["consent_date"], p["consent_version"], p["enrolled"],
                           json.dumps(p["withdrawn"]) if p.get("withdrawn") else None))

    def set_withdrawn(self, pseudonym: str, withdrawn: dict[str, Any]) -> None:
        self.conn.execute("UPDATE participants SET withdrawn = ? WHERE pseudonym = ?",
                          (json.dumps(withdrawn), pseudonym))

    def put_session(self, s: dict[str, Any]) -> None:
        """Insert or update one session by its key (idempotent: the same key recorded twice is one session)."""
        values = [s.get(c) for c in _SESSION_COLS]
        values[_SESSION_COLS.index("outside_interval")] = int(bool(s.get("outside_interval")))
        values[_SESSION_COLS.index("files")] = json.dumps(s["files"]) if s.get("files") is not None else None
        self.conn.execute(f"INSERT OR REPLACE INTO sessions ({', '.join(_SESSION_COLS)}) VALUES "
                          f"({', '.join('?' * len(_SESSION_COLS))})", values)

    def delete_sessions(self, pseudonym: str) -> None:
        self.conn.execute("DELETE FROM sessions WHERE pseudonym = ?", (pseudonym,))

    def add_amendment(self, a: dict[str, Any]) -> None:
        self.conn.execute("INSERT INTO amendments (time, reason, old_sha256, new_sha256, enrolled_at_amendment, "
                          "changes) VALUES (?, ?, ?, ?, ?, ?)",
                          (a["time"], a["reason"], a["old_sha256"], a["new_sha256"], a["enrolled_at_amendment"],
                           json.dumps(a.get("changes", []))))

    def add_unblinding(self, time: str, who: str, reason: str) -> None:
        self.conn.execute("INSERT INTO unblindings (time, who, reason) VALUES (?, ?, ?)", (time, who, reason))

    def sealed_arm(self, stratum: str, position: int) -> str | None:
        row = self.conn.execute("SELECT sealed_arm FROM allocation WHERE stratum = ? AND position = ?",
                                (stratum, position)).fetchone()
        return row[0] if row else None

    def sequence_lengths(self) -> dict[str, int]:
        return dict(self.conn.execute("SELECT stratum, COUNT(*) FROM allocation GROUP BY stratum").fetchall())


def _connect(path: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(path, timeout=60, isolation_level=None)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA synchronous=FULL")
    conn.execute("PRAGMA foreign_keys=ON")
    return conn


def exists(root: Path) -> bool:
    return (Path(root) / DB_FILE).is_file()


@contextlib.contextmanager
def transaction(root: Path, write: bool, key_of: Any = None, create: bool = False,
                db_path: Path | None = None) -> Iterator[Tx]:
    """A transaction on ``root/registry.db``: checked (format, schema version, HMAC) before the caller reads,
    sealed and committed after it writes; rolled back on any exception. ``key_of(study_id)`` loads the key
    (``create``: a new database; the caller writes everything, ``key`` set on the ``Tx``)."""
    path = db_path or Path(root) / DB_FILE
    if not create and not path.is_file():
        raise DataError(f"{root}: not a study folder (no {DB_FILE}); create one with "
                        "`nao-trainer study init PROTOCOL --out STUDY_DIR`")
    try:
        conn = _connect(path)
    except sqlite3.Error as exc:
        raise db_error(path, exc) from None
    try:
        conn.execute("BEGIN IMMEDIATE" if write or create else "BEGIN")
        tx = Tx(conn, path, None)
        if create:
            for stmt in MIGRATIONS[1].split(";"):
                if stmt.strip():
                    conn.execute(stmt)
            tx.set_meta("format", FORMAT)
            tx.set_meta("schema_version", SCHEMA_VERSION)
        else:
            _check(tx, key_of)
        yield tx
        if write or create:
            if tx.key is None:
                raise DataError(f"{path}: no study key to seal the registry with")
            conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES ('seal', ?)",
                         (json.dumps(seal.mac(tx.key, tx.content())),))
            conn.execute("COMMIT")
        else:
            conn.execute("ROLLBACK")
    except BaseException as exc:
        with contextlib.suppress(sqlite3.Error):
            conn.execute("ROLLBACK")
        if isinstance(exc, (sqlite3.Error, OSError)) and not isinstance(exc, FileNotFoundError):
            raise db_error(path, exc) from None
        raise
    finally:
        conn.close()


def _check(tx: Tx, key_of: Any) -> None:
    try:
        names = {r[0] for r in tx.conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    except sqlite3.DatabaseError as exc:
        raise db_error(tx.path, exc) from None
    if "meta" not in names or tx.meta("format", None) != FORMAT:
        raise DataError(f"{tx.path}: not a nao-trainer study registry; {_FIX}")
    version = tx.meta("schema_version")
    if type(version) is not int or version > SCHEMA_VERSION:
        raise DataError(f"{tx.path}: registry schema version {version!r} is newer than this nao-trainer knows "
                        f"({SCHEMA_VERSION}); update nao-trainer")
    for v in range(version + 1, SCHEMA_VERSION + 1):  # an older registry: migrated in this transaction
        for stmt in MIGRATIONS[v].split(";"):
            if stmt.strip():
                tx.conn.execute(stmt)
        tx.set_meta("schema_version", v)
    study_id = tx.meta("study_id")
    tx.key = key_of(study_id) if key_of else seal.load_key(study_id, tx.path.parent)
    if tx.meta("seal", None) != seal.mac(tx.key, tx.content()):
        raise DataError(f"{tx.path}: the registry was edited outside nao-trainer (its seal does not match its "
                        f"contents); {_FIX}")
