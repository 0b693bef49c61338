"""The right person: who a session is for, and one session per participant at a time.

**An entered pseudonym.** A session where a person answers (tactile or keyboard input) or a real
robot plays must run under a pseudonym someone entered for it: ``--pseudonym ID``, or a study file
written for the participant. The shipped study files (``config/``) name none (the demo's
``demo`` plays a simulated participant); a pseudonym that only comes from one of them does not
count. Without one the session is refused in one line (exit 2) before anything is written. A
simulated participant on the stand-in or the laptop without a pseudonym is called ``simulated``.

**One session at a time.** A session whose policy keeps the participant's state across sessions
(``policies.participant_state``) holds ``<state file>.lock`` (pid, host, start time) for its whole
length (``participant_lock``): a second session for the same participant state is refused in one
line while the first runs (both would learn from, and write, the same state: the last writer would
win). A lock left by a session that was killed (its pid no longer runs on this host) is taken over
with a notice; one from another host is refused (it cannot be judged from here).
"""
from __future__ import annotations

import json
import os
import socket
from contextlib import contextmanager, nullcontext
from datetime import datetime, timezone
from pathlib import Path
from typing import ContextManager, Iterator, TextIO

from nao_trainer.errors import ConfigError, UserError
from nao_trainer.files import PROJECT_ROOT
from nao_trainer.session.config import StudyConfig
from nao_trainer.session.config_rules import is_robot_address

#: The pseudonym of a simulated participant when none was given (``session.config.ParticipantSection``).
SIMULATED = "simulated"
#: Where the shipped study files live: a pseudonym only they give was not entered for anyone.
SHIPPED = PROJECT_ROOT / "config"
KEY = "participant.pseudonym"


def _entered(config: StudyConfig) -> bool:
    """Whether the pseudonym was given on the command line or by a study file that is not shipped."""
    if (config.overrides or {}).get(KEY) is not None:
        return True
    if config.values["participant"]["pseudonym"] is None:
        return False
    study = Path(config.sources[-1]).resolve()
    return not study.is_relative_to(SHIPPED.resolve())


def check_pseudonym(config: StudyConfig) -> None:
    """ConfigError in one line when a person answers or a real robot plays and nobody entered a
    pseudonym for the session (see the module docstring)."""
    person = config.answers.input != "simulated"
    robot = is_robot_address(config.robot.url)
    if (person or robot) and not _entered(config):
        who = f"{config.answers.input} answers" if person else f"the robot at {config.robot.url.rpartition('@')[2]}"
        shipped = "" if config.values["participant"]["pseudonym"] is None else \
            f" ({config.participant.pseudonym!r} comes from the shipped {Path(config.sources[-1]).name})"
        raise ConfigError(f"{KEY}: no pseudonym entered for this session with {who}{shipped}; "
                          "give --pseudonym ID (letters, digits, _ or -; never a real name)")


def lock_path(state_file: Path) -> Path:
    return Path(state_file).with_name(Path(state_file).name + ".lock")


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    return True


def session_lock(config: StudyConfig, progress: TextIO | None = None) -> ContextManager[Path | None]:
    """The lock of the participant state the session's policy keeps (none for a policy that keeps none)."""
    state = config.policy_state_file()  # None for a policy that keeps no participant state
    return nullcontext() if state is None else participant_lock(state, config.participant.pseudonym, progress)


@contextmanager
def participant_lock(state_file: Path, pseudonym: str, progress: TextIO | None = None) -> Iterator[Path]:
    """Hold the lock of ``pseudonym``'s ``state_file`` for the ``with`` block (module docstring);
    UserError in one line when another session holds it."""
    path = lock_path(state_file)
    host = socket.gethostname()
    mine = {"pid": os.getpid(), "host": host, "started": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{path.parent}: cannot create the participant's folder ({exc.strerror}); "
                        "make session.output (or policy.state_path) writable") from None
    for _attempt in range(2):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            holder = _holder(path)
            pid, where = holder.get("pid"), holder.get("host")
            if where == host and isinstance(pid, int) and not _running(pid):
                path.unlink(missing_ok=True)  # stale: the session that held it is gone
                if progress:
                    print(f"participant {pseudonym}: a lock left by session pid {pid} "
                          f"(started {holder.get('started')}), "
                          f"which no longer runs, was taken over ({path})", file=progress, flush=True)
                continue
            raise UserError(f"{path}: participant {pseudonym} is in another session (pid {pid} on {where}, started "
                            f"{holder.get('started')}); wait for it to end (remove the file only if that session is "
                            "gone)") from None
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(mine, fh)
        break
    else:
        raise UserError(f"{path}: cannot take the participant's lock; remove the file if no session runs")
    try:
        yield path
    finally:
        if _holder(path).get("pid") == mine["pid"]:
            path.unlink(missing_ok=True)


def _holder(path: Path) -> dict:
    """The lock's content ({} when unreadable: a torn lock is treated as held by an unknown session)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}
