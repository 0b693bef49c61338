"""Reading and writing the project's files: one-line errors on reads, never half a file on writes."""
from __future__ import annotations

import errno
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from nao_trainer.errors import ConfigError, UserError

#: What a failed write means, by errno: (the cause, how to fix it).
WRITE_CAUSES: dict[int, tuple[str, str]] = {
    errno.ENOSPC: ("the disk is full", "free some space on it"),
    errno.EDQUOT: ("the disk quota is used up", "free some space or raise the quota"),
    errno.EROFS: ("the file system is read-only", "make it writable or choose another folder"),
    errno.EACCES: ("no permission to write there", "make the folder writable for this user"),
    errno.EPERM: ("no permission to write there", "make the folder writable for this user"),
    errno.EMFILE: ("too many open files", "raise the limit (ulimit -n) or close other programs"),
    errno.ENFILE: ("too many open files on this system", "close other programs"),
    errno.EFBIG: ("the file is larger than this system allows", "raise the file size limit (ulimit -f)"),
    errno.EIO: ("an input/output error of the disk", "check the disk"),
}
#: The errors of a disk that fills or fails (no file name needed to know it is a write that failed).
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS})


def cannot_write(where: Any, what: str, exc: OSError, other: str) -> str:
    """``<file>: cannot write <what> (<cause>); <fix>``: the file (``exc``'s own when it names one), the
    cause by errno (full disk, file size limit, read-only, ...) and its fix, else ``other`` (e.g. "choose
    another --out")."""
    place = exc.filename if exc.filename is not None else where
    if exc.errno in WRITE_CAUSES:
        cause, fix = WRITE_CAUSES[exc.errno]
        fix = f"{fix}, or {other}" if other else fix
    else:
        cause, fix = exc.strerror or type(exc).__name__, other or "check the disk"
    return f"{place}: cannot write{' ' + what if what else ''} ({cause}); {fix}"


#: The checkout that holds config/, dialogue/, behaviors/ and sim/ beside the package.
PROJECT_ROOT = Path(__file__).resolve().parents[1]


def read_text(path: str | os.PathLike, error: type[UserError], missing: str = "file not found", fix: str = "",
              max_bytes: int | None = None) -> str:
    """The UTF-8 text of ``path``; ``error(...)`` naming the file (and ``fix``) when it cannot be read.

    ``max_bytes``: a larger file is refused before it is read (a crafted or runaway file must not
    exhaust the memory)."""
    path = Path(path)
    tail = f"; {fix}" if fix else ""
    try:
        if max_bytes is not None and path.stat().st_size > max_bytes:
            size = path.stat().st_size
            raise error(f"{path}: {size / 1e6:.0f} MB is larger than the {max_bytes / 1e6:.0f} MB this file can be "
                        f"(not written by nao-trainer, or corrupt){tail}")
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: {missing}{tail}") from None
    except UnicodeDecodeError as exc:
        line = exc.object[: exc.start].count(b"\n") + 1
        raise error(f"{path}:{line}: not a text file ({exc.reason} at byte {exc.start}; UTF-8 expected){tail}") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror}){tail}") from None


def read_json(path: str | os.PathLike, error: type[UserError], missing: str = "file not found", fix: str = "",
              max_bytes: int | None = None) -> Any:
    """The parsed JSON of ``path``; ``error`` naming file and line when unreadable or invalid (torn, edited,
    nested too deep to parse)."""
    text = read_text(path, error, missing, fix, max_bytes)
    tail = f"; {fix}" if fix else ""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}:{exc.lineno}: not valid JSON ({exc.msg}): torn or corrupt{tail}") from None
    except RecursionError:
        raise error(f"{path}: JSON nested too deeply to read: corrupt or crafted{tail}") from None


def read_yaml(path: str | os.PathLike, missing: str = "file not found", fix: str = "") -> tuple[Any, dict[str, int], str]:
    """Parse a YAML file; returns (data, dotted key -> line number, text) so validation can say where.

    Unreadable files, syntax errors, characters YAML forbids, values a tag cannot convert
    (``!!int notanumber``) and keys given twice raise ``ConfigError`` with file and line, in one line.
    """
    text = read_text(path, ConfigError, missing, fix)
    loader = None
    try:
        loader = _yaml_loader()(text)
        node = loader.get_single_node()
        lines: dict[str, int] = {}
        _collect_lines(node, "", lines, path)
        data = loader.construct_document(node) if node is not None else None
    except yaml.reader.ReaderError as exc:  # a control character or similar: no mark, a position
        line = text[: exc.position].count("\n") + 1 if isinstance(exc.position, int) else "?"
        char = f"U+{exc.character:04X}" if isinstance(exc.character, int) else repr(exc.character)
        raise ConfigError(f"{path}:{line}: control character {char} is not allowed in YAML; remove it") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        raise ConfigError(f"{where}: not valid YAML ({problem}); fix the syntax") from None
    except _ValueError as exc:
        raise ConfigError(f"{path}:{exc.line}: {exc.tag or 'value'} {exc.value!r} cannot be read ({exc.reason}); "
                          "fix the value or remove the tag") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested too deeply to be a configuration; fix the file") from None
    finally:
        if loader is not None:
            loader.dispose()
    return data, lines, text


class _ValueError(Exception):
    """A YAML tag could not convert its value (PyYAML raises a bare ValueError without a line)."""

    def __init__(self, line: int, tag: str, value: Any, reason: str) -> None:
        super().__init__(reason)
        self.line, self.tag, self.value, self.reason = line, tag, value, reason


_LOADER: Any = None


def _yaml_loader() -> Any:
    """PyYAML's SafeLoader (on libyaml's parser where installed: 5x faster, the same nodes and marks),
    made to report a value its tag cannot convert with the node's line."""
    global _LOADER
    if _LOADER is None:
        class Loader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
            def construct_object(self, node: Any, deep: bool = False) -> Any:
                try:
                    return super().construct_object(node, deep)
                except (yaml.YAMLError, _ValueError, RecursionError):
                    raise
                except (ValueError, TypeError, LookupError, ArithmeticError) as exc:
                    tag = str(node.tag).rsplit(":", 1)[-1]
                    value = node.value if isinstance(node.value, str) else None
                    reason = " ".join(str(exc).split()) or type(exc).__name__
                    raise _ValueError(node.start_mark.line + 1, f"!!{tag}", value, reason) from None

        _LOADER = Loader
    return _LOADER


def _collect_lines(node: Any, prefix: str, out: dict[str, int] | None, path: Any) -> None:
    """Record each dotted key's line (``out``); refuse a key given twice in one mapping (YAML keeps the last).

    Mappings inside lists are checked for repeated keys too, without recording lines.
    """
    if isinstance(node, yaml.MappingNode):
        seen: dict[str, int] = {}
        for key_node, value_node in node.value:
            name = str(key_node.value)
            key = f"{prefix}.{name}" if prefix else name
            line = key_node.start_mark.line + 1
            if isinstance(key_node, yaml.ScalarNode) and name in seen and key_node.tag != "tag:yaml.org,2002:merge":
                raise ConfigError(f"{path}:{line}: key {key!r} is given twice (first on line {seen[name]}); "
                                  "keep one (YAML would silently use the last)")
            seen[name] = line
            if out is not None:
                out[key] = line
            _collect_lines(value_node, key, out, path)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _collect_lines(item, f"{prefix}[{i}]", None, path)


def _number(value: float | int) -> str:
    """A JSON number as ``json`` writes it; NaN and infinity refused, as ``allow_nan=False`` does."""
    if value.__class__ is int or (isinstance(value, int) and not isinstance(value, bool)):
        return int.__repr__(value)
    if value != value or value in (_INF, -_INF):
        raise ValueError(f"Out of range float values are not JSON compliant: {value!r}")
    return float.__repr__(value)


_INF = float("inf")
_STRING = json.encoder.encode_basestring_ascii  # json's own (C) string escaping, ensure_ascii as json.dumps


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _key(key: Any) -> str:
    """A dict key as ``json`` converts it (str, float, bool, None, int; anything else a TypeError)."""
    if isinstance(key, str):
        return key
    if isinstance(key, float):
        return _number(key)
    if key is True or key is False or key is None:
        return {True: "true", False: "false", None: "null"}[key]
    if isinstance(key, int):
        return int.__repr__(key)
    raise TypeError(f"keys must be str, int, float, bool or None, not {key.__class__.__name__}")


def _encode(value: Any, indent: str, out: list[str]) -> None:
    """``value`` as ``json.dumps(indent=1)`` lays it out, except that a list of numbers only (a table row)
    stays on one line: ``[1, 2.5, 3]``."""
    if isinstance(value, str):
        out.append(_STRING(value))
    elif value is None or value is True or value is False:
        out.append("null" if value is None else "true" if value else "false")
    elif _is_number(value):
        out.append(_number(value))
    elif isinstance(value, dict):
        if not value:
            out.append("{}")
            return
        inner = indent + " "
        out.append("{")
        sep = "\n"
        for key, item in value.items():
            out.append(f"{sep}{inner}{_STRING(_key(key))}: ")
            _encode(item, inner, out)
            sep = ",\n"
        out.append(f"\n{indent}}}")
    elif isinstance(value, (list, tuple)):
        if not value:
            out.append("[]")
        elif all(map(_is_number, value)):
            out.append("[" + ", ".join(map(_number, value)) + "]")
        else:
            inner = indent + " "
            out.append("[")
            sep = "\n"
            for item in value:
                out.append(sep + inner)
                _encode(item, inner, out)
                sep = ",\n"
            out.append(f"\n{indent}]")
    else:
        raise TypeError(f"Object of type {value.__class__.__name__} is not JSON serializable")


def json_text(data: Any) -> str:
    """``data`` as the project writes JSON: indented by one space, each list of numbers only (a table row) on
    one line, so a file stays readable. The layout of ``json.dumps(data, indent=1)`` with those rows joined,
    built here, not by a regex over json's text (which also rewrote a string that looked like a row), and
    faster: ``json`` indents only with its pure-Python encoder (60 kB of participant state, written every
    turn: 10 ms of CPU, 6 ms here). NaN and infinity are refused (``ValueError``): they are not JSON and
    other tools reject them."""
    out: list[str] = []
    _encode(data, "", out)
    return "".join(out)


def write_json_atomic(path: str | os.PathLike, data: Any) -> None:
    """Write ``data`` as :func:`json_text` with ``write_text_atomic``."""
    write_text_atomic(path, json_text(data) + "\n")


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path``, fsync it, rename it over ``path``, fsync the folder.

    A reader, or a crash at any moment, sees the old file or the new one, never half of one.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:  # name the file being written (a full disk fails in write(), which names none)
        if exc.filename is not None and exc.filename != str(tmp):
            raise
        raise OSError(exc.errno, exc.strerror, str(path)) from exc
    finally:
        try:
            tmp.unlink()
        except OSError:  # renamed (the usual case), or never created
            pass
    try:
        fd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


# ----------------------------------------------------------------------------------------------
# Versioned JSON files
# ----------------------------------------------------------------------------------------------


def canonical_sha256(payload: Any) -> str:
    """SHA-256 of ``payload`` as canonical JSON (sorted keys, no spaces); ValueError for NaN/infinity."""
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class JsonFormat:
    """A versioned JSON file format: ``{"format": name, "format_version": version, ...}``.

    Flat files spread :meth:`header` into their fields and :meth:`check` it on reading.
    Checksummed files are envelopes ``{"format", "format_version", "sha256", "payload"}``
    (:meth:`write` / :meth:`read`): a torn or edited file is refused, never half-used.
    ``title`` names the kind in "not a nao-trainer <title>"; ``noun`` starts the other messages
    ("<noun> format version 2, ..."); ``fix`` ends them.
    """

    name: str
    version: int
    title: str
    noun: str
    fix: str = ""

    def header(self) -> dict[str, Any]:
        return {"format": self.name, "format_version": self.version}

    def _tail(self) -> str:
        return f"; {self.fix}" if self.fix else ""

    def check(self, doc: Any, source: Any, error: type[Exception] = UserError) -> dict[str, Any]:
        """``doc`` itself when it is a dict of this format and version; ``error`` naming ``source`` otherwise."""
        if not isinstance(doc, dict) or doc.get("format") != self.name:
            found = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
            raise error(f"{source}: not a nao-trainer {self.title} (format={found!r})")
        if doc.get("format_version") != self.version:
            raise error(f"{source}: {self.noun} format version {doc.get('format_version')!r}, this nao-trainer "
                        f"reads {self.version}{self._tail()}")
        return doc

    def write(self, path: str | os.PathLike, payload: dict[str, Any]) -> None:
        """Write ``payload`` in a checksummed envelope, atomically."""
        write_json_atomic(path, {**self.header(), "sha256": canonical_sha256(payload), "payload": payload})

    def read(self, path: str | os.PathLike, error: type[UserError]) -> dict[str, Any]:
        """The verified payload of an envelope file; ``error`` naming the file and ``fix`` otherwise.

        Checks, in order: readable JSON, format and version, payload and checksum present, checksum.
        """
        path = Path(path)
        text = read_text(path, error, f"no such {self.noun} file", self.fix)
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise error(f"{path}:{exc.lineno}: {self.noun} file is not valid JSON ({exc.msg}): torn or corrupt"
                        f"{self._tail()}") from None
        except RecursionError:  # e.g. 100,000 nested '[' (issue 30, finding 5)
            raise error(f"{path}: {self.noun} file is nested too deeply to be one: crafted or corrupt"
                        f"{self._tail()}") from None
        self.check(doc, path, error)
        payload = doc.get("payload")
        if not isinstance(payload, dict) or not isinstance(doc.get("sha256"), str):
            raise error(f"{path}: {self.noun} file lacks its payload or checksum: torn or corrupt{self._tail()}")
        try:
            digest = canonical_sha256(payload)
        except ValueError as exc:
            raise error(f"{path}: {self.noun} payload holds invalid numbers ({exc}){self._tail()}") from None
        except RecursionError:
            raise error(f"{path}: {self.noun} payload is nested too deeply: crafted or corrupt{self._tail()}") from None
        if digest != doc["sha256"]:
            raise error(f"{path}: checksum mismatch (file altered, torn or corrupt){self._tail()}")
        return payload
