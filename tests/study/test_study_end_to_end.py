"""A whole study from the command line: init, 12 enrolments, 24 sessions through `study next`, status,
analyse, power and a BIDS export that the official validator accepts.

Sessions run against the NAO stand-in (real qi on loopback) with simulated participants of four
abilities, 6 turns sped up x50, EEG off except for two participants (a simulated Muse on LSL). Six
participants' sessions run side by side (different participants may; the registry is locked per write).
"""
from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from nao_trainer.files import PROJECT_ROOT

BASE = """\
study: {name: e2e}
robot: {url: mock}
session: {turns: 6, practice: false}
timing: {speed: 50}
answers: {input: simulated}
eeg: {mode: "off", xdf: false, processing: {window_s: 0.25, hop_s: 0.05}}
"""
PROTOCOL = """\
protocol: {name: e2e-3arm, description: personalised vs level 2 vs random difficulty}
study_config: base.yaml
arms:
  - {name: personalised, policy: personalised}
  - {name: level2, policy: schedule, overrides: {policy.schedule: [L2]}}
  - {name: random, policy: random}
sessions: {per_participant: 2, interval_days: {min: 0, max: 7}}
target_n: 12
allocation: {method: blocked, block_size: 6, seed: 2026}
blinding: true
outcomes: {primary: score, secondary: [engagement, success_rate, span]}
analysis: {model: "outcome ~ arm + session + (1|participant)", reference_arm: level2}
"""
ABILITIES = ("sim/participants/level2.json", "sim/participants/level4.json", "1", "3")
WITH_EEG = ("P001", "P002")


def validator() -> Path | None:
    """The official BIDS validator installed by .ci/run (npm, project-local), or NAO_TRAINER_BIDS_VALIDATOR."""
    given = os.environ.get("NAO_TRAINER_BIDS_VALIDATOR")
    path = Path(given) if given else PROJECT_ROOT / ".tools" / "bids-validator" / "node_modules" / ".bin" / "bids-validator"
    return path if path.exists() and shutil.which("node") else None


def _env() -> dict[str, str]:
    return dict(os.environ, QI_LOG_LEVEL="silent")


def _cli(*args: object, timeout: float = 180) -> subprocess.CompletedProcess:
    res = subprocess.run([sys.executable, "-m", "nao_trainer", *map(str, args)], capture_output=True, text=True,
                         env=_env(), timeout=timeout)
    assert "Traceback" not in res.stderr, res.stderr[-3000:]
    return res


def _next(study: Path, pseudonym: str, i: int) -> subprocess.Popen:
    flags = ["--user-model", ABILITIES[i % len(ABILITIES)], "--no-keys"]
    if pseudonym in WITH_EEG:
        flags += ["--eeg", "simulated"]
    return subprocess.Popen([sys.executable, "-m", "nao_trainer", "study", "next", str(study), pseudonym, *flags],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())


@pytest.mark.slow
def test_a_three_arm_study_from_init_to_bids(tmp_path):
    (tmp_path / "base.yaml").write_text(BASE)
    (tmp_path / "protocol.yaml").write_text(PROTOCOL)
    study = tmp_path / "study"
    assert _cli("study", "init", tmp_path / "protocol.yaml", "--out", study).returncode == 0
    for _ in range(12):
        res = _cli("study", "enrol", study, "--consent-date", "2026-11-20", "--consent-version", "2.1")
        assert res.returncode == 0 and "concealed" in res.stdout, res.stderr
    from nao_trainer.study.registry import open_study

    opened = open_study(study)
    arms = [opened.arm_of(f"P{i:03d}") for i in range(1, 13)]  # sealed: read with the study key
    assert Counter(arms) == {"personalised": 4, "level2": 4, "random": 4}
    registry = opened.registry

    people = [f"P{i:03d}" for i in range(1, 13)]
    outputs = []
    for session in (1, 2):
        for batch in range(0, 12, 6):  # the sessions mostly wait (speech, answers): six run side by side
            procs = [(p, _next(study, p, people.index(p))) for p in people[batch:batch + 6]]
            for p, proc in procs:
                out, err = proc.communicate(timeout=240)
                assert proc.returncode == 0, f"study next {p} session {session}: {err[-3000:]}"
                outputs.append(out + err)
                assert f"{p}, session {session} of 2, arm (blinded)" in err
    for text in outputs:  # blinded: no arm name, policy or its phases on the terminal
        low = text.lower()
        assert not any(w in low for w in ("personalised", "level2", "random", "assessment", "posterior", "schedule"))
    res = _cli("study", "next", study, "P001", "--no-keys")
    assert res.returncode == 2 and "completed all 2 sessions" in res.stderr

    res = _cli("study", "status", study)
    assert res.returncode == 0, res.stderr
    assert "enrolled 12 of 12; withdrawn 0; complete 12" in res.stdout and "sessions done: 24" in res.stdout
    rows = [line.split() for line in res.stdout.splitlines() if line.startswith("P0")]
    assert len(rows) == 24 and all(r[1] == "blinded" and r[3] == "completed" and r[4] == "6" for r in rows)
    eeg_turns = {r[0]: int(r[5]) for r in rows}
    assert all(eeg_turns[p] > 0 for p in WITH_EEG) and eeg_turns["P003"] == 0

    res = _cli("study", "analyse", study)
    assert res.returncode == 2 and "study unblind" in res.stderr  # blinded: the statistician unblinds first
    res = _cli("study", "unblind", study, "--reason", "final analysis", "--who", "statistician")
    assert res.returncode == 0 and [line.split("\t") for line in res.stdout.splitlines()[1:]] == \
        [[p, a] for p, a in zip([f"P{i:03d}" for i in range(1, 13)], arms)]
    res = _cli("study", "analyse", study)
    assert res.returncode == 0, res.stderr
    sha = registry["protocol"]["sha256"]
    assert sha in res.stdout and "PRIMARY" in res.stdout and "EXPLORATORY" in res.stdout
    with open(study / "analysis" / "estimates.csv", newline="") as fh:
        est = list(csv.DictReader(fh))
    primary = {r["term"]: r for r in est if r["role"] == "primary"}
    assert {"arm[personalised]", "arm[random]", "session"} <= set(primary)
    for r in primary.values():
        assert float(r["ci_low"]) <= float(r["estimate"]) <= float(r["ci_high"]) and r["n_sessions"] == "24"
    assert (study / "analysis" / "score.png").stat().st_size > 10_000
    span = {r["term"]: r for r in est if r["role"] == "secondary" and r["outcome"] == "span"}  # issue 21: an outcome
    assert {"arm[personalised]", "arm[random]", "session"} <= set(span) and span["session"]["n_sessions"] == "24"
    with open(study / "analysis" / "sessions.csv", newline="") as fh:
        spans = [float(r["span"]) for r in csv.DictReader(fh)]
    assert len(spans) == 24 and all(3 <= s <= 12 for s in spans)  # letters, at 75 % (a score study)

    res = _cli("study", "power", tmp_path / "protocol.yaml", "--users", "clusters", "--n", "6,12,24", "--reps", "20",
               "--out", tmp_path / "power")
    assert res.returncode == 0, res.stderr
    power = json.loads((tmp_path / "power" / "power.json").read_text())
    assert power["ns"] == [6, 12, 24] and "score: random vs level2" in power["power"]
    assert all(0 <= p <= 1 for v in power["power"].values() for p in v)
    assert "N=24: 20 studies simulated" in res.stderr and (tmp_path / "power" / "power.png").exists()
    assert not any(k.startswith("span:") for k in power["power"]) and "span: not simulated" in power["notes"][0]

    bids = tmp_path / "bids"
    res = _cli("study", "export", study, "--bids", bids)
    assert res.returncode == 0, res.stderr
    assert "12 participants, 24 sessions of behaviour, 4 with EEG" in res.stdout
    with open(bids / "participants.tsv", newline="") as fh:
        table = list(csv.DictReader(fh, delimiter="\t"))
    assert {r["participant_id"]: r["arm"] for r in table} == {f"sub-{p}": a for p, a in zip(people, arms)}
    assert sha in (bids / "dataset_description.json").read_text()
    assert (bids / "sub-P001" / "ses-02" / "eeg" / "sub-P001_ses-02_task-sequencelearning_events.tsv").exists()
    assert not (bids / "sub-P003" / "ses-01" / "eeg").exists()
    beh = json.loads((bids / "sub-P003" / "ses-01" / "beh" / "sub-P003_ses-01_task-sequencelearning_beh.json")
                     .read_text())
    with open(bids / "sub-P003" / "ses-01" / "beh" / "sub-P003_ses-01_task-sequencelearning_beh.tsv") as fh:
        header = fh.readline().rstrip("\n").split("\t")
    assert all(c in beh and beh[c]["Description"] for c in header)
    published = tmp_path / "published"  # the authors' layout: their tools (and ours) read it
    res = _cli("study", "export", study, "--published", published)
    assert res.returncode == 0 and "12 users, 24 sessions, 4 with raw EEG" in res.stdout, res.stderr
    res = _cli("import", published, "--out", tmp_path / "turns.csv")
    assert res.returncode == 0, res.stderr
    with open(tmp_path / "turns.csv", newline="") as fh:
        imported = list(csv.DictReader(fh))
    assert len(imported) == 24 * 6 and {r["pseudonym"] for r in imported} == {f"user_{i}" for i in range(1, 13)}
    assert (published / "user_1" / "session_2" / "robot_1").stat().st_size > 0  # raw EEG of the listening phase

    tool = validator()
    if tool is None:
        pytest.skip("the BIDS validator is not installed (.ci/run installs it with npm into .tools/)")
    res = subprocess.run([str(tool), str(bids), "--json"], capture_output=True, text=True, timeout=300)
    report = json.loads(res.stdout)
    errors = report["issues"]["errors"]
    assert not errors, [(e["key"], e.get("reason")) for e in errors]
