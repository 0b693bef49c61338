"""``study next``: a participant's next session, with the arm's configuration and learning state.

The pseudonym comes from the registry, never typed into a bare ``run``; the arm, the session number,
the seed and the learning-state folder follow from it. The session itself is played by the session
layer's public entry point (``session.wiring.run_session``), called in :func:`play` only.

A per-participant lock file (``STUDY_DIR/locks/<pseudonym>.lock``, holding the pid and host) refuses a
second ``study next`` while the first runs; a lock left by a process that no longer exists is stale and
taken over, with a notice. With blinding on, the terminal shows a neutral label for the arm: lines naming
the policy, its phase or what it concluded are filtered (:class:`BlindStream`), the summary leaves out the
policy's conclusion, and the supervisor console (which shows the policy) is refused.
"""
from __future__ import annotations

import contextlib
import dataclasses
import datetime as dt
import hashlib
import io
import json
import os
import re
import socket
import sys
import uuid
from pathlib import Path
from typing import Any, Callable, Iterator, TextIO

from nao_trainer.errors import ConfigError, DataError, UserError
from nao_trainer.policies.participant_state import participant_template
from nao_trainer.ports import CommandQueue
from nao_trainer.session.config import StudyConfig
from nao_trainer.study.registry import (Study, _running_session, now_iso, open_study, participant_folders, pid_alive, read_lock,
                                       record_session)
from nao_trainer.session.resume import prepare_resume
from nao_trainer.session.turn import summary_data

BLIND_LABEL = "arm (blinded)"
#: Sessions that count towards the protocol's number (the others are kept on record).
DONE = ("completed", "time limit")
_REVEALING = re.compile(r"policy|posterior|user model|assessment|personalis|matched|cluster", re.IGNORECASE)
_PHASE_TAG = re.compile(r"\s+\[[^\]]*\]\s*$")


@dataclasses.dataclass(frozen=True)
class NextSession:
    """What ``study next`` is about to run."""

    pseudonym: str
    arm: str
    number: int
    config: StudyConfig
    warning: str  # outside the interval (empty when inside)
    resume: Any = None  # session.wiring.Resumption when an interrupted session is continued
    key: str = ""  # the session's key in the registry (idempotent: recorded once whatever retries)

    def label(self, blinded: bool) -> str:
        return BLIND_LABEL if blinded else f"arm {self.arm}"


def done_sessions(participant: dict[str, Any]) -> list[dict[str, Any]]:
    return [s for s in participant["sessions"] if s["status"] in DONE]


def session_seed(study: Study, pseudonym: str, number: int) -> int:
    """A reproducible seed per participant and session (from the study's salt, not the allocation's seed)."""
    text = f"{study.registry['session_salt']}:{pseudonym}:{number}"
    return int(hashlib.sha256(text.encode()).hexdigest()[:8], 16) % 2**31


def days_between(earlier: str, later: dt.datetime) -> float:
    return (later - dt.datetime.fromisoformat(earlier)).total_seconds() / 86400.0


def plan_next(study: Study, pseudonym: str, flags: dict[str, Any], now: dt.datetime | None = None) -> NextSession:
    """The participant's next session; ``DataError`` for unknown, withdrawn or completed participants."""
    study.check_study_config()
    p = study.participant(pseudonym)
    protocol = study.protocol
    if p["withdrawn"]:
        raise DataError(f"{pseudonym}: withdrew on {p['withdrawn']['time'][:10]}; no further sessions")
    done = done_sessions(p)
    if len(done) >= protocol.sessions.per_participant:
        raise DataError(f"{pseudonym}: has completed all {protocol.sessions.per_participant} sessions of the protocol")
    number = len(done) + 1
    warning = ""
    if done:
        now = now or dt.datetime.now(dt.timezone.utc).astimezone()
        gap = days_between(done[-1]["ended"], now)
        lo, hi = protocol.sessions.min_days, protocol.sessions.max_days
        if not lo <= gap <= hi:
            warning = (f"{pseudonym}'s session {number} comes {gap:.1f} days after session {number - 1}; the protocol "
                       f"allows {lo:g}-{hi:g} days (the session is recorded as outside the interval)")
    arm = protocol.arm(study.arm_of(pseudonym))
    extra = {**{k: v for k, v in flags.items() if v is not None},
             "participant.pseudonym": pseudonym, "session.output": str(study.sessions_dir.resolve()),
             "session.seed": session_seed(study, pseudonym, number)}
    if "policy.state_path" not in dict(arm.overrides):  # learning state per participant, across sessions
        extra["policy.state_path"] = participant_template(arm.policy)
    return NextSession(pseudonym, arm.name, number, protocol.arm_config(arm, extra), warning, key=uuid.uuid4().hex)


def plan_resume(study: Study, pseudonym: str) -> NextSession:
    """Continue the participant's last session when it was interrupted (its folder, configuration, seed and
    learning state, through ``session.resume.prepare_resume``); ``DataError`` when there is none."""
    study.check_study_config()
    p = study.participant(pseudonym)
    if p["withdrawn"]:
        raise DataError(f"{pseudonym}: withdrew on {p['withdrawn']['time'][:10]}; no further sessions")
    last = p["sessions"][-1] if p["sessions"] else None
    if last is None or last["status"] in DONE or not last.get("folder"):
        raise DataError(f"{pseudonym}: no interrupted session to resume; run the next one without --resume")
    config, resumption = prepare_resume(study.sessions_dir / last["folder"])
    return NextSession(pseudonym, study.arm_of(pseudonym), int(last["number"]), config, "", resumption,
                       key=last["key"])


@contextlib.contextmanager
def participant_lock(study: Study, pseudonym: str, notice: TextIO | None = None) -> Iterator[None]:
    """Exclusive per participant: a second ``study next`` is refused while the first one's process lives.

    The lock file is written whole under a temporary name and hard-linked into place (``link`` fails when
    the lock exists): it never exists empty, even when the disk fills while it is written. A lock that
    cannot be read, or names no live process of this host, is stale and taken over."""
    folder = study.root / "locks"
    path = folder / f"{pseudonym}.lock"
    mine = {"pid": os.getpid(), "host": socket.gethostname(), "started": now_iso()}
    tmp = folder / f".{pseudonym}.lock.tmp-{os.getpid()}"
    try:
        folder.mkdir(exist_ok=True)
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(json.dumps(mine))
            fh.flush()
            os.fsync(fh.fileno())
        for _attempt in range(2):
            try:
                os.link(tmp, path)
                break
            except FileExistsError:
                held = read_lock(path)
                if held is not None and (held[1] != mine["host"] or pid_alive(held[0])):
                    raise ConfigError(f"{path}: a session of {pseudonym} is running (pid {held[0]} on {held[1]}); "
                                      "wait for it to end") from None
                if notice:
                    print(f"study next: a stale lock of {pseudonym} ("
                          f"{'unreadable' if held is None else f'pid {held[0]} no longer runs'}) is taken over",
                          file=notice, flush=True)
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
        else:
            raise ConfigError(f"{path}: cannot take the lock of {pseudonym}; remove the file if no session runs")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write the lock of {pseudonym} ({exc.strerror}); free disk space and "
                          "run the command again") from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()
    try:
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


class BlindStream(io.TextIOBase):
    """Progress lines without the arm: lines about the policy are dropped, phase tags and arm names hidden."""

    def __init__(self, out: TextIO, names: list[str]) -> None:
        self.out, self._buf = out, ""
        words = sorted({n for n in names if n}, key=len, reverse=True)
        self._names = re.compile(r"\b(" + "|".join(map(re.escape, words)) + r")\b") if words else None

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        self._buf += text
        while "\n" in self._buf:
            line, self._buf = self._buf.split("\n", 1)
            shown = self.filter(line)
            if shown is not None:
                self.out.write(shown + "\n")
        return len(text)

    def flush(self) -> None:
        self.out.flush()

    def filter(self, line: str) -> str | None:
        # The phase tag goes first: a turn line tagged "[assessment]" must be shown without its tag, not
        # dropped (every arm shows its turn lines, or their absence would name the arm).
        line = _PHASE_TAG.sub("", line) if line.lstrip().startswith("turn ") else line
        if _REVEALING.search(line):
            return None
        return self._names.sub(BLIND_LABEL, line) if self._names else line


def play(study: Study, plan: NextSession, options: Any, progress: TextIO,
         record: Callable[[dict[str, Any]], None] | None = None) -> Any:
    """Run the planned session through the session layer and record it in the registry (``record``: where an
    entry goes, default the study folder's registry; ``study.remote`` passes its outbox and server)."""
    from nao_trainer.session.wiring import run_session

    record = record or (lambda entry: record_session(study.root, plan.pseudonym, entry))

    blinded = study.protocol.blinding
    check_blinding(study, plan, options)
    names = [a.name for a in study.protocol.arms] + [a.policy for a in study.protocol.arms]
    stream = BlindStream(progress, names) if blinded else progress
    console = None
    with contextlib.ExitStack() as stack:
        if blinded:  # policies print to stderr themselves (e.g. "returns after 1 session(s)"): filtered too
            stack.enter_context(contextlib.redirect_stderr(BlindStream(sys.stderr, names)))
            stack.enter_context(contextlib.redirect_stdout(BlindStream(sys.stdout, names)))
            if options.console:
                options, console = stack.enter_context(blinded_console(plan, options, progress))
        before = set(study.sessions_dir.glob(f"{plan.pseudonym}_*"))
        register_start(study, plan, record)
        try:
            result = run_session(plan.config, options, progress=stream, resume=plan.resume)
        except UserError as exc:  # e.g. the robot lost for good: a folder written is still recorded
            for folder in sorted(set(study.sessions_dir.glob(f"{plan.pseudonym}_*")) - before):
                _record(study, plan, folder, "error", exc.exit_code, record)
            raise
        if console is not None:
            console.hub.notify("summary", {**summary_data(result), "policy_summary": ""})
    if result.path is not None:
        _record(study, plan, result.path, result.status, result.exit_code, record)
    return dataclasses.replace(result, policy_summary="") if blinded else result


def register_start(study: Study, plan: NextSession, record: Callable[[dict[str, Any]], None]) -> None:
    """The session is in the registry before it starts (``running``, with this process and host): a
    session killed at any moment is listed, counted when its folder says it completed, and resumable."""
    record({
        "key": plan.key, "pseudonym": plan.pseudonym, "number": plan.number, "folder": plan.resume.folder.name if plan.resume else None,
        "status": "running", "exit_code": None, "started": now_iso(), "ended": None,
        "outside_interval": bool(plan.warning), "protocol_sha256": study.protocol.sha256,
        "host": socket.gethostname(), "pid": os.getpid(), "files": None})


def file_checksums(folder: Path) -> dict[str, str]:
    """SHA-256 of each regular file of a session folder (the registry references the files by these)."""
    out = {}
    for f in sorted(folder.rglob("*")):
        if f.is_file() and not f.is_symlink():
            h = hashlib.sha256()
            with open(f, "rb") as fh:
                for chunk in iter(lambda: fh.read(1 << 20), b""):
                    h.update(chunk)
            out[str(f.relative_to(folder))] = h.hexdigest()
    return out


def _record(study: Study, plan: NextSession, folder: Path, status: str, exit_code: int,
            record: Callable[[dict[str, Any]], None]) -> None:
    info = _session_info(folder)
    record({
        "key": plan.key, "pseudonym": plan.pseudonym, "number": plan.number, "folder": folder.name, "status": info.get("status") or status,
        "exit_code": info.get("exit_code", exit_code), "started": info.get("started"),
        "ended": info.get("ended") or now_iso(), "outside_interval": bool(plan.warning),
        "protocol_sha256": study.protocol.sha256, "host": socket.gethostname(), "pid": None,
        "files": file_checksums(folder)})


def _stamp_time(name: str) -> dt.datetime | None:
    m = re.search(r"_(\d{8}-\d{6})(?:_\d+)?$", name)
    return dt.datetime.strptime(m.group(1), "%Y%m%d-%H%M%S") if m else None


def pending_sessions(study: Study, pseudonym: str | None = None) -> list[dict[str, Any]]:
    """What the registry does not yet say about sessions on disk (nothing is written here):

    * a ``running`` session whose process is gone (killed): its folder (the first of the participant's
      unrecorded folders created after it started) and its status from the folder's ``session.json``
      (``completed`` counts; otherwise ``interrupted``, resumable with ``study next --resume``);
    * a session folder of an enrolled participant that no session references (an orphan): adopted.

    Returns the session entries to record (``study repair`` and ``study next`` record them)."""
    host = socket.gethostname()
    out = []
    for p in study.participants:
        if pseudonym is not None and p["pseudonym"] != pseudonym:
            continue
        if _running_session(study.root, p["pseudonym"]):
            continue  # its session runs: the folder it is writing is not an orphan
        known = {s["folder"] for s in p["sessions"] if s.get("folder")}
        free = [f for f in participant_folders(study, p["pseudonym"]) if f.name not in known]
        number = max([s["number"] for s in p["sessions"]], default=0)
        for s in p["sessions"]:
            if s["status"] != "running" or (s.get("host") == host and s.get("pid") and pid_alive(s["pid"])):
                continue
            if s.get("host") not in (None, host):
                continue  # another site's laptop: it records its own session when it is back
            folder = s.get("folder")
            if folder is None:
                start = dt.datetime.fromisoformat(s["started"]).astimezone().replace(tzinfo=None, microsecond=0)
                after = [f for f in free if (_stamp_time(f.name) or start) >= start]
                if after:
                    folder = after[0].name
                    free.remove(after[0])
            out.append(_adopted(study, s, folder))
        for f in free:
            number += 1
            out.append(_adopted(study, {"key": f.name, "number": number, "pseudonym": p["pseudonym"],
                                        "outside_interval": False, "protocol_sha256": study.protocol.sha256}, f.name))
    return out


def _adopted(study: Study, s: dict[str, Any], folder: str | None) -> dict[str, Any]:
    info = _session_info(study.sessions_dir / folder) if folder else {}
    status = info.get("status") if info.get("status") in DONE else "interrupted"
    return {**s, "folder": folder, "status": status, "exit_code": info.get("exit_code"),
            "started": s.get("started") or info.get("started"), "ended": info.get("ended") or s.get("started")
            or now_iso(), "pid": None, "host": s.get("host") or socket.gethostname(),
            "files": file_checksums(study.sessions_dir / folder) if folder else None}


def repair(root: Path, pseudonym: str | None = None) -> list[dict[str, Any]]:
    """Record what :func:`pending_sessions` found; returns the entries recorded."""
    study = open_study(root)
    found = pending_sessions(study, pseudonym)
    for entry in found:
        record_session(study.root, entry["pseudonym"], entry)
    return found


def check_blinding(study: Study, plan: NextSession, options: Any) -> None:
    """The session layer's own console shows the policy: a blinded study serves its own (``--console``)."""
    if study.protocol.blinding and plan.config.console.enabled:
        raise ConfigError(f"{plan.config.sources[-1]}: console.enabled is true, but that console shows the policy "
                          "and this protocol is blinded; set console.enabled: false and give `study next --console` "
                          "(a console without the arm)")


class BlindObserver:
    """Passes the session's events to the console without what names the arm: the policy's name, status,
    probabilities, the turn's phase and the policy's conclusion."""

    HIDDEN = ("phase", "probabilities", "policy_summary")

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def notify(self, kind: str, data: dict) -> None:
        if kind == "policy":
            return
        shown = {k: (BLIND_LABEL if k == "policy" else v) for k, v in data.items() if k not in self.HIDDEN}
        self.inner.notify(kind, shown)


@contextlib.contextmanager
def blinded_console(plan: NextSession, options: Any, progress: TextIO) -> Iterator[tuple[Any, Any]]:
    """A supervisor console fed through :class:`BlindObserver`; yields the run options that use it and
    the console (stopped on leaving).

    Steering (pause, resume, stop, override, repeat, mark invalid, notes) works as usual through the
    command queue. The page lacks the live EEG contact panel (the monitor is inside the session layer).
    """
    from nao_trainer.session.wiring import LOOPBACK

    try:
        from nao_trainer.console.launch import open_console
    except ImportError as exc:
        raise ConfigError(f"--console needs the console extra ({exc}); pip install -e '.[console]'") from None
    bind = options.console_bind or plan.config.console.bind
    if bind not in LOOPBACK and not options.console_bind:
        raise ConfigError(f"console.bind {bind!r}: the console serves only this machine unless --console-bind "
                          "ADDRESS is given on the command line")
    commands = options.commands or CommandQueue()
    port = options.console_port if options.console_port is not None else plan.config.console.port
    # TLS beyond loopback and the printed link follow the session's own console (console.launch)
    console = open_console(commands, bind, port, lambda *_, **__: None, progress, options.console_insecure,
                           options.console_tls)
    print("console: the arm is not shown", file=progress, flush=True)
    try:
        yield dataclasses.replace(options, console=False, console_port=None, console_bind=None, commands=commands,
                                  observer=BlindObserver(console.hub)), console
    finally:
        console.stop()


def _session_info(folder: Path) -> dict[str, Any]:
    try:
        return json.loads((folder / "session.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def run_next(root: Path, pseudonym: str, flags: dict[str, Any], options: Any,
             progress: TextIO | None = None, resume: bool = False) -> tuple[NextSession, Any]:
    """``study next``: plan, lock, warn, play, record. Returns the plan and the session result."""
    progress = progress or sys.stderr
    study = open_study(root)
    study.participant(pseudonym)
    for entry in repair(root, pseudonym):  # a killed session of this participant: recorded first
        print(f"study next: {pseudonym}'s session {entry['number']} ({entry['folder'] or 'no folder'}) was "
              f"interrupted; recorded as {entry['status']}", file=progress, flush=True)
    study = open_study(root)
    if resume:
        given = [k for k, v in flags.items() if v is not None]
        if given:
            raise ConfigError(f"--resume continues a session with its own configuration; drop the flags for "
                              f"{', '.join(given)}")
    plan = plan_resume(study, pseudonym) if resume else plan_next(study, pseudonym, flags)
    check_blinding(study, plan, options)
    with participant_lock(study, pseudonym, progress):
        # Planned again under the lock: a session of this participant that ended between the first plan and
        # the lock counts, so this one gets the next number (or is refused), never the same one twice.
        for entry in repair(root, pseudonym):  # a killed session of this participant: recorded first
            print(f"study next: {pseudonym}'s session {entry['number']} ({entry['folder'] or 'no folder'}) was "
                  f"interrupted; recorded as {entry['status']}", file=progress, flush=True)
        study = open_study(root)
        plan = plan_resume(study, pseudonym) if resume else plan_next(study, pseudonym, flags)
        if plan.warning:
            print(f"warning: {plan.warning}", file=progress, flush=True)
        resumed = "" if plan.resume is None else " (resumed)"
        print(f"study {study.protocol.name}: {pseudonym}, session {plan.number} of "
              f"{study.protocol.sessions.per_participant}{resumed}, {plan.label(study.protocol.blinding)}",
              file=progress, flush=True)
        return plan, play(study, plan, options, progress)
