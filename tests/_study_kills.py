"""SIGKILL and full-disk harness for the study commands (tests/study/test_kills.py runs a small sample;
benchmarks/bench_study_kills.py runs 50 kills per command and 20 disk fills and prints the counts).

Each trial builds a small study (2 participants enrolled, one session done), runs ONE command in a
subprocess and kills it with SIGKILL after a random delay in [0, 1.3 x the command's measured duration]
(or runs it under a random file-size limit, RLIMIT_FSIZE: every write past it fails with EFBIG, as on a
full disk). Then it checks what must hold whatever the moment:

* the study opens: ``study status`` exits 0 with no traceback;
* the command happened wholly or not at all (enrolments 2 or 3; protocol old or new, its copy restored;
  withdrawal recorded or not, nothing deleted before it is);
* every completed enrolment and turn is there: a killed ``study next`` is in the registry (running, or
  recorded by ``study repair``) with every turn its folder holds, and ``study next --resume`` accepts it
  or says in one line why a new session is needed;
* a refused command (disk full) said so in one line with exit 2.
"""
from __future__ import annotations

import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

TESTS = Path(__file__).resolve().parent
sys.path.insert(0, str(TESTS))
from _study_data import PROTOCOL, write_protocol  # noqa: E402

HANG = 180
COMMANDS = ("enrol", "amend", "withdraw", "next")


def _env() -> dict[str, str]:
    return dict(os.environ, QI_LOG_LEVEL="silent")


def cli(*args, limit: int | None = None) -> subprocess.CompletedProcess:
    def pre():
        if limit is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return subprocess.run([sys.executable, "-m", "nao_trainer", *map(str, args)], capture_output=True, text=True,
                          timeout=HANG, env=_env(), preexec_fn=pre)


def make_study(folder: Path, template: Path | None = None) -> Path:
    """A study with P001 (one session done) and P002; copied from ``template`` when given (fast)."""
    root = folder / "study"
    if template is not None:
        shutil.copytree(template.parent, folder, symlinks=True)
        return root
    folder.mkdir(parents=True, exist_ok=True)
    write_protocol(folder, PROTOCOL.replace("blinding: false", "blinding: true"))
    write_protocol(folder, PROTOCOL.replace("blinding: false", "blinding: true").replace("max: 7", "max: 10"),
                   "amended.yaml")
    assert cli("study", "init", folder / "protocol.yaml", "--out", root).returncode == 0
    for _ in range(2):
        assert cli("study", "enrol", root, "--consent-date", "2026-11-02", "--consent-version", "v1").returncode == 0
    res = cli("study", "next", root, "P001", "--no-keys", "--user-model", "1")
    assert res.returncode == 0, res.stderr
    return root


def command(root: Path, name: str) -> list[str]:
    return {"enrol": ["study", "enrol", root, "--consent-date", "2026-11-02", "--consent-version", "v1"],
            "amend": ["study", "amend", root, root.parent / "amended.yaml", "--reason", "holidays"],
            "withdraw": ["study", "withdraw", root, "P001", "--data", "delete"],
            "next": ["study", "next", root, "P002", "--no-keys", "--user-model", "1", "--turns", "6"]}[name]


@dataclass
class Tally:
    trials: int = 0
    killed_before_done: int = 0  # the kill landed while the command ran
    ok: int = 0
    refused_one_line: int = 0  # disk fills: exit 2, one line
    failures: list[str] = field(default_factory=list)


def check(root: Path, name: str, before_turns: int = 0) -> str:
    """'' when the study is whole after a killed or starved command, else what is wrong."""
    res = cli("study", "status", root)
    if res.returncode != 0 or "Traceback" in res.stderr:
        return f"status fails: {res.stderr.strip()[-300:]}"
    out = res.stdout
    if name == "enrol" and not ("enrolled 2 of" in out or "enrolled 3 of" in out):
        return f"enrolment torn: {out[:200]}"
    if name == "amend":
        text = (root / "protocol.yaml").read_text()
        if "amendment(s)" not in out or ("max: 10" in text) != ("1 amendment(s)" in out):
            return "protocol copy and registry disagree"
    if name == "withdraw":
        withdrawn = "withdrawn: P001" in out
        folders = list((root / "sessions").glob("P001_*"))
        if not withdrawn and not folders:
            return "P001's data deleted but no withdrawal recorded"
    if name == "next":
        rep = cli("study", "repair", root)
        if rep.returncode != 0:
            return f"repair fails: {rep.stderr.strip()[-300:]}"
        out = cli("study", "status", root).stdout
        folders = sorted((root / "sessions").glob("P002_*"))
        rows = [line for line in out.splitlines() if line.startswith("P002 ")]
        if folders and not rows:
            return "a P002 session folder is on disk but not in the registry"
        if len(rows) > 1 + 0:
            return f"P002's session recorded twice: {rows}"
        if folders and (folders[0] / "turns.csv").is_file():
            on_disk = max(0, len((folders[0] / "turns.csv").read_text().splitlines()) - 1)
            shown = rows[0].split()[4] if rows else "-"
            if shown not in (str(on_disk), "-"):
                return f"P002: {on_disk} turns on disk, status shows {shown}"
        res = cli("study", "next", root, "P002", "--resume", "--no-keys")
        if "Traceback" in res.stderr or (res.returncode != 0 and len(res.stderr.strip().splitlines()) != 1):
            return f"resume: {res.stderr.strip()[-300:]}"
    return ""


def duration(template: Path, work: Path, name: str) -> float:
    root = make_study(work / "measure", template)
    t0 = time.monotonic()
    res = cli(*command(root, name))
    assert res.returncode == 0, res.stderr
    shutil.rmtree(work / "measure")
    return time.monotonic() - t0


def kill_trial(template: Path, work: Path, name: str, delay: float, tally: Tally) -> None:
    trial = work / f"{name}-{tally.trials}"
    root = make_study(trial, template)
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", *map(str, command(root, name))],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env())
    time.sleep(delay)
    tally.killed_before_done += proc.poll() is None
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    tally.trials += 1
    problem = check(root, name)
    if problem:
        tally.failures.append(f"{name} killed at {delay:.2f} s: {problem}")
    else:
        tally.ok += 1
    shutil.rmtree(trial, ignore_errors=True)


def disk_trial(template: Path, work: Path, name: str, limit: int, tally: Tally) -> None:
    trial = work / f"{name}-disk-{tally.trials}"
    root = make_study(trial, template)
    res = cli(*command(root, name), limit=limit)
    tally.trials += 1
    if res.returncode != 0:
        if "Traceback" in res.stderr or len(res.stderr.strip().splitlines()) != 1:
            tally.failures.append(f"{name} under a {limit}-byte limit: not one line: {res.stderr.strip()[-400:]}")
            shutil.rmtree(trial, ignore_errors=True)
            return
        tally.refused_one_line += 1
    problem = check(root, name)
    if problem:
        tally.failures.append(f"{name} under a {limit}-byte limit: {problem}")
    else:
        tally.ok += 1
    shutil.rmtree(trial, ignore_errors=True)


def run(work: Path, kills: int, fills: int, seed: int, out=sys.stdout) -> dict[str, tuple[Tally, Tally]]:
    rng = random.Random(seed)
    template = make_study(work / "template")
    results = {}
    for name in COMMANDS:
        span = duration(template, work, name)
        killed, filled = Tally(), Tally()
        for _ in range(kills):
            kill_trial(template, work, name, rng.uniform(0, 1.3 * span), killed)
        for _ in range(fills):  # limits from below the registry's next page to past a session's files
            disk_trial(template, work, name, rng.choice([0, 512, 4096, 8192, 16384, 65536, 200_000]), filled)
        results[name] = (killed, filled)
        print(f"{name:8s} ({span:.2f} s): {killed.trials} kills ({killed.killed_before_done} while running): "
              f"{killed.ok} whole, {len(killed.failures)} broken; {filled.trials} disk fills: {filled.ok} whole "
              f"({filled.refused_one_line} refused in one line), {len(filled.failures)} broken", file=out, flush=True)
        for f in killed.failures + filled.failures:
            print(f"  {f}", file=out, flush=True)
    return results
