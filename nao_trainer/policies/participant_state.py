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

import logging
import os
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
