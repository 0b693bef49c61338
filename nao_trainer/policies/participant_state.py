"""Where a participant's learning state lives, and how a replaced one is kept.

A learning policy keeps a participant's state in ``<output>/participants/<pseudonym>/<file>``
(``state_file``; ``<file>`` is the policy's declared ``state_filename``: ``personalised.json`` for the
personalised policy, ``bayes.json`` for the Bayes planner, ``policy_state.json`` for a learned one). ``policy.state_path`` may name another file, with
``{pseudonym}`` and ``{output}``, or be ``{session}`` to keep it in the session folder (nothing
carried over). ``--fresh-policy`` never deletes a state file: ``set_aside`` renames it to
``<file>.replaced-<UTC time>``. ``open_saved`` is the start-up every persisted policy shares (nothing
saved, set aside, or read and checked, with ``check_owner`` refusing another participant's file).
Standard library only: the configuration imports this module and ``nao-trainer --help`` stays fast.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

from nao_trainer.errors import DataError
from nao_trainer.policies.plugin import SESSION_FOLDER, declaration


def state_filename(kind: str) -> str:
    """The name of the state file of a policy ``kind`` ("personalised", "usp:2", ...): its declaration's."""
    return declaration(kind).state_filename


def state_file(kind: str, state_path: str | None, pseudonym: str, output: Path) -> Path | None:
    """Where a policy of ``kind`` keeps the participant ``pseudonym``'s state across sessions.

    ``state_path`` None: ``<output>/participants/<pseudonym>/<state_filename(kind)>``; a template
    with ``{pseudonym}`` and ``{output}`` names another file; ``"{session}"`` gives None (the
    policy saves into the session folder once it exists, ``session_state_file``).
    """
    if state_path == SESSION_FOLDER:
        return None
    template = state_path or participant_template(kind)
    return Path(template.format(pseudonym=pseudonym, output=output)).expanduser().resolve()


def participant_template(kind: str) -> str:
    """``{output}/participants/{pseudonym}/<state_filename(kind)>``: the default ``policy.state_path``
    of a policy ``kind``, as a template (a study arm whose base file keeps the state per session sets it)."""
    return str(participant_dir(Path("{output}"), "{pseudonym}") / state_filename(kind))


def participant_dir(output: Path, pseudonym: str) -> Path:
    """The folder of the participant ``pseudonym``'s learning state under ``output`` (the default place)."""
    return Path(output) / "participants" / pseudonym


def session_state_file(kind: str, folder: Path) -> Path:
    """The state file of a policy that keeps its state in the session ``folder``."""
    return Path(folder) / state_filename(kind)


def set_aside(path: Path) -> Path:
    """``--fresh-policy``: rename ``path`` to ``<name>.replaced-<UTC time>[_n]`` (never deleted); the new name."""
    path = Path(path)
    stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
    target = path.with_name(f"{path.name}.replaced-{stamp}")
    n = 2
    while target.exists():
        target = path.with_name(f"{path.name}.replaced-{stamp}_{n}")
        n += 1
    os.replace(path, target)
    return target


def check_owner(path: Path, saved: dict[str, Any], pseudonym: str | None, fix: str) -> None:
    """DataError in one line when the state at ``path`` names another participant than ``pseudonym``
    (a file copied between participants' folders). A file that names no one (older files) passes."""
    owner = saved.get("pseudonym")
    if pseudonym is not None and owner is not None and owner != pseudonym:
        raise DataError(f"{path}: the participant state of {owner!r}, not of {pseudonym!r} (copied from another "
                        f"participant's folder?); {fix}")


def open_saved(path: Path | None, fresh: bool, read: Callable[[Path], dict[str, Any]], kind: str,
               log: logging.Logger) -> dict[str, Any] | None:
    """The participant's saved state at ``path`` for a policy ``kind`` starting up: None when there is
    none (or ``path`` is None: kept in the session folder); with ``fresh`` (``--fresh-policy``) the file
    is set aside and None returned; otherwise ``read(path)``, which checks it and raises DataError."""
    if path is None or not Path(path).exists():
        return None
    if fresh:
        kept = set_aside(Path(path))
        log.warning("policy %s: starting fresh from the prior; the previous state was moved to %s", kind, kept)
        return None
    return read(Path(path))


#: What every refusal of a participant's state file says to do.
FRESH = "start afresh with --fresh-policy (the old file is kept beside it)"


@dataclass(frozen=True)
class ParticipantState:
    """The participant file of one persisting policy: the one save, read, owner and fingerprint check.

    ``read_file(path)`` reads and verifies the file's format (checksum, version; DataError in one line);
    ``owner(saved)`` is the pseudonym it names (None: an older file, which passes); ``fingerprint(saved)``
    what it was made with (models, prior, objective, trained policy), compared with the running policy's,
    refused with ``made_with`` in the message when it differs."""

    read_file: Callable[[Path], dict[str, Any]]
    write_file: Callable[[Path, dict[str, Any]], None]
    fingerprint: Callable[[dict[str, Any]], Any]
    made_with: str  # "another prior or objective", "other user models or policies", ...
    owner: Callable[[dict[str, Any]], Any] = field(default=lambda saved: saved.get("pseudonym"))
    fix: str = FRESH
    saved_what: str = "the participant's state"  # in "cannot save ..."
    save_fix: str = "make session.output writable"

    def save(self, path: Path | None, payload: dict[str, Any]) -> None:
        """Write ``payload`` atomically to ``path`` (nothing when None: the session folder does not exist yet)."""
        if path is None:
            return
        try:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            self.write_file(Path(path), payload)
        except OSError as exc:
            raise DataError(f"{path}: cannot save {self.saved_what} ({exc.strerror or exc}); {self.save_fix}") from None

    def read(self, path: Path, fingerprint: Any, pseudonym: str | None,
             described: Callable[[dict[str, Any]], str] | None = None) -> dict[str, Any]:
        """The saved state at ``path``, checked: its format, its owner, its fingerprint (``described(saved)``:
        what the file says it was made with, for the message)."""
        saved = self.read_file(Path(path))
        check_owner(path, {"pseudonym": self.owner(saved)}, pseudonym, self.fix)
        if fingerprint is not None and self.fingerprint(saved) != fingerprint:
            shown = _short(self.fingerprint(saved)), _short(fingerprint)
            made = f"{described(saved)}, " if described and described(saved) else ""
            raise DataError(f"{path}: participant state made with {self.made_with} ({made}fingerprint {shown[0]}, "
                            f"now {shown[1]}); use what it was made with, or {self.fix}")
        return saved

    def open(self, path: Path | None, fresh: bool, fingerprint: Any, pseudonym: str | None, kind: str,
             log: logging.Logger, described: Callable[[dict[str, Any]], str] | None = None) -> dict[str, Any] | None:
        """``open_saved`` with this file's ``read``."""
        return open_saved(path, fresh, lambda f: self.read(f, fingerprint, pseudonym, described), kind, log)


def digest(saved: dict[str, Any], keys: tuple[str, ...]) -> str:
    """A fingerprint of ``keys`` of a saved state (what it was made with), for a file that stores them whole."""
    text = json.dumps({k: saved.get(k) for k in keys}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _short(value: Any) -> str:
    text = value if isinstance(value, str) else repr(value)
    return text[:12] + "..." if len(text) > 15 else text
