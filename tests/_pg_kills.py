"""SIGKILL `nao-trainer study enrol` against a PostgreSQL registry at random moments (two sites taking
turns) and check after each kill that the registry is whole: every stratum's allocation positions
0..n-1 with no gap or repeat, each site's pseudonym numbers contiguous from its range's start, and the
site's next number one past them. Used by tests/study/test_pg_registry.py (a few kills) and
benchmarks/bench_study_kills.py --registry postgresql (50)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL = ROOT / "config" / "protocols" / "example-3arm.yaml"


@dataclass
class Result:
    trials: int = 0
    enrolled: int = 0
    failures: list[str] = field(default_factory=list)


def _cli(env, *args):
    return subprocess.run([sys.executable, "-m", "nao_trainer", "study", *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=120)


def _new_study(cluster, work: Path, env) -> tuple[Path, dict[str, str], str]:
    from nao_trainer.study import pg

    db = "k_" + uuid.uuid4().hex[:10]
    with pg.connect(cluster.url(), autocommit=True) as c:
        c.execute(f"CREATE DATABASE {db}")
    study = work / db
    done = _cli(env, "init", PROTOCOL, "--out", study, "--registry", cluster.url(db))
    assert done.returncode == 0, done.stderr
    roles = {}
    lines = Path(env["PGPASSFILE"]).read_text().splitlines()
    for site in ("north", "south"):
        out = _cli(env, "site", "add", study, site).stdout
        roles[site] = out.split("role ")[1].split(";")[0]
        lines.append(f"*:*:*:{roles[site]}:{out.strip().rsplit(' ', 1)[1]}")
    Path(env["PGPASSFILE"]).write_text("\n".join(lines) + "\n")
    return study, roles, db


def check(cluster, db: str) -> list[str]:
    from nao_trainer.study import pg

    problems = []
    with pg.connect(cluster.url(db), autocommit=True) as c:
        rows = c.execute("SELECT stratum, allocation_index FROM participants ORDER BY stratum, allocation_index")
        per: dict[str, list[int]] = {}
        for stratum, index in rows:
            per.setdefault(stratum, []).append(index)
        for stratum, got in per.items():
            if got != list(range(len(got))):
                problems.append(f"{db}: stratum {stratum!r}: positions {got}")
        for name, first, nxt in c.execute("SELECT name, first_number, next_number FROM sites"):
            numbers = [r[0] for r in c.execute("SELECT number FROM participants WHERE site = %s ORDER BY number",
                                               (name,))]
            if numbers != list(range(first, nxt)):
                problems.append(f"{db}: site {name}: numbers {numbers}, next {nxt}")
    return problems


def run(cluster, work: Path, kills: int, seed: int) -> Result:
    """``kills`` enrolments killed at a moment drawn uniformly within a whole enrolment's time."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "QI_LOG_LEVEL": "silent", "PGUSER": "postgres",
           "PGPASSFILE": str(work / "pgpass")}
    (work / "pgpass").write_text(f"*:*:*:postgres:{cluster.password}\n")
    (work / "pgpass").chmod(0o600)
    saved = os.environ.get("PGPASSFILE")
    os.environ["PGPASSFILE"] = env["PGPASSFILE"]  # this process's own connections (the checks)
    try:
        return _kills(cluster, work, kills, seed, env)
    finally:
        if saved is None:
            os.environ.pop("PGPASSFILE", None)
        else:
            os.environ["PGPASSFILE"] = saved


def _kills(cluster, work: Path, kills: int, seed: int, env: dict[str, str]) -> Result:
    rng = np.random.default_rng(seed)
    study, roles, db = _new_study(cluster, work, env)
    t0 = time.monotonic()
    _cli({**env, "PGUSER": roles["north"]}, "enrol", study, "--consent-date", "2026-12-01", "--consent-version", "v1")
    whole = time.monotonic() - t0
    result = Result(enrolled=1)
    for i in range(kills):
        site = ("north", "south")[i % 2]
        proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "study", "enrol", str(study), "--consent-date",
                                 "2026-12-01", "--consent-version", "v1"], env={**env, "PGUSER": roles[site]},
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            proc.wait(timeout=float(rng.uniform(0, whole)))
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        out, err = proc.communicate()
        result.trials += 1
        result.failures += check(cluster, db)
        if "target_n" in err:  # the study is full: a new one
            study, roles, db = _new_study(cluster, work, env)
        elif proc.returncode not in (0, -signal.SIGKILL):
            result.failures.append(f"enrol exit {proc.returncode}: {err.strip()}")
        result.enrolled += "enrolled" in out
    return result


# --- study next and study record on a site's laptop -------------------------------------------------------

def _session_study(cluster, work: Path, env) -> tuple[Path, str, str]:
    """A study of tests/_study_data's small protocol (stand-in robot, simulated answers) with site north."""
    sys.path.insert(0, str(ROOT / "tests"))
    from _study_data import write_protocol

    from nao_trainer.study import pg

    db = "n_" + uuid.uuid4().hex[:10]
    with pg.connect(cluster.url(), autocommit=True) as c:
        c.execute(f"CREATE DATABASE {db}")
    folder = work / db
    folder.mkdir(parents=True)
    study = folder / "study"
    done = _cli(env, "init", write_protocol(folder), "--out", study, "--registry", cluster.url(db))
    assert done.returncode == 0, done.stderr
    out = _cli(env, "site", "add", study, "north").stdout
    role = out.split("role ")[1].split(";")[0]
    lines = Path(env["PGPASSFILE"]).read_text().splitlines() + [f"*:*:*:{role}:{out.strip().rsplit(' ', 1)[1]}"]
    Path(env["PGPASSFILE"]).write_text("\n".join(lines) + "\n")
    return study, role, db


def check_sessions(cluster, db: str, study: Path) -> list[str]:
    """After `study record` ran whole: nothing left in the outbox, no session left `running`, no session
    number counted twice, every session folder on the laptop recorded once, with its folder's status."""
    import json

    from nao_trainer.study import pg

    problems = []
    if list((study / "outbox").glob("*.json")):
        problems.append(f"{db}: the outbox still holds {sorted(p.name for p in (study / 'outbox').glob('*.json'))}")
    with pg.connect(cluster.url(db), autocommit=True) as c:
        rows = c.execute("SELECT key, pseudonym, number, folder, status FROM sessions").fetchall()
    if any(r[4] == "running" for r in rows):
        problems.append(f"{db}: sessions left running: {[r for r in rows if r[4] == 'running']}")
    counted = [(r[1], r[2]) for r in rows if r[4] in ("completed", "time limit")]
    if len(counted) != len(set(counted)):
        problems.append(f"{db}: a session number counted twice: {sorted(counted)}")
    by_folder: dict[str, list] = {}
    for r in rows:
        if r[3]:
            by_folder.setdefault(r[3], []).append(r)
    for folder in sorted((study / "sessions").glob("P*_*")):
        got = by_folder.get(folder.name, [])
        if len(got) != 1:
            problems.append(f"{db}: folder {folder.name} recorded {len(got)} times")
            continue
        try:
            status = json.loads((folder / "session.json").read_text()).get("status")
        except (OSError, ValueError):
            status = None
        if status in ("completed", "time limit") and got[0][4] != status:
            problems.append(f"{db}: {folder.name} says {status}, the registry {got[0][4]}")
    return problems


def run_sessions(cluster, work: Path, kills: int, seed: int) -> Result:
    """``kills`` rounds: `study next` SIGKILLed at a moment drawn within a whole session's time, then `study
    record` SIGKILLed at a moment within its own time, then `study record` run whole and the registry checked
    (:func:`check_sessions`). ``enrolled`` counts the sessions that ended before their kill."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "QI_LOG_LEVEL": "silent", "PGUSER": "postgres",
           "PGPASSFILE": str(work / "pgpass")}
    (work / "pgpass").write_text(f"*:*:*:postgres:{cluster.password}\n")
    (work / "pgpass").chmod(0o600)
    saved = os.environ.get("PGPASSFILE")
    os.environ["PGPASSFILE"] = env["PGPASSFILE"]
    try:
        return _session_kills(cluster, work, kills, seed, env)
    finally:
        if saved is None:
            os.environ.pop("PGPASSFILE", None)
        else:
            os.environ["PGPASSFILE"] = saved


def _session_kills(cluster, work: Path, kills: int, seed: int, env: dict[str, str]) -> Result:
    from nao_trainer.study import pg

    rng = np.random.default_rng(seed)
    state: dict = {}

    def new_study() -> None:
        study, role, db = _session_study(cluster, work, env)
        state.update(study=study, db=db, site={**env, "PGUSER": role})

    def participant() -> str:
        """A participant with a session to run (enrolled when none is left; a new study when it is full)."""
        with pg.connect(cluster.url(state["db"]), autocommit=True) as c:
            rows = c.execute("SELECT p.pseudonym, count(s.key) FILTER (WHERE s.status IN ('completed', "
                             "'time limit')) FROM participants p LEFT JOIN sessions s ON s.pseudonym = p.pseudonym "
                             "GROUP BY p.pseudonym ORDER BY p.pseudonym").fetchall()
        for pseudonym, done in rows:
            if done < 2:
                return pseudonym
        res = _cli(state["site"], "enrol", state["study"], "--consent-date", "2026-12-01", "--consent-version", "v1")
        if res.returncode != 0 and "target_n" in res.stderr:
            new_study()
            return participant()
        assert res.returncode == 0, res.stderr
        return res.stdout.split(":")[0]

    def nxt() -> list:
        pseudonym = participant()  # first: it may move on to a new study
        return ["next", state["study"], pseudonym, "--no-keys", "--user-model", "1"]

    new_study()
    t0 = time.monotonic()
    res = _cli(state["site"], *nxt())
    assert res.returncode == 0, res.stderr
    whole = time.monotonic() - t0
    t0 = time.monotonic()
    _cli(state["site"], "record", state["study"])
    record_time = time.monotonic() - t0
    result = Result()
    for _ in range(kills):
        for args, span in ((nxt(), whole), (["record", state["study"]], record_time)):
            proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "study", *map(str, args)], env=state["site"],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            try:
                proc.wait(timeout=float(rng.uniform(0, 1.3 * span)))
                result.enrolled += args[0] == "next" and proc.returncode == 0
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGKILL)
                proc.wait()
            _out, err = proc.communicate()
            if "Traceback" in err or proc.returncode not in (0, -signal.SIGKILL):
                result.failures.append(f"{args[0]} exit {proc.returncode}: {err.strip()[-300:]}")
        done = _cli(state["site"], "record", state["study"])
        if done.returncode != 0 or "Traceback" in done.stderr:
            result.failures.append(f"record after the kills: exit {done.returncode}: {done.stderr.strip()[-300:]}")
        result.trials += 1
        result.failures += check_sessions(cluster, state["db"], state["study"])
    return result
