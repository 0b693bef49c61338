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
