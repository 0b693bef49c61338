"""The data loop end to end, as a user runs it: sessions -> import -> fit -> train -> a session with the policy.

Eight sessions sped up x50 with a simulated Muse, four from each of two clearly different simulated
participants (strong: succeeds at every level, high engagement; weak: fails from level 2 on, low
engagement). They must come out of `fit --k 2` as the two clusters; `train` then learns a policy per
cluster and `run` plays a session with it against the fitted user model.
"""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

STUDY = """\
study: {{name: loop-{group}}}
robot: {{url: mock}}
session: {{turns: 8, practice: false}}
timing: {{speed: 50}}
answers: {{input: simulated}}
participant_model: {{success_by_level: {p}, engagement_by_level: {e}}}
policy: {{kind: schedule, schedule: [L1, L2, L3, L4]}}
eeg: {{mode: simulated, xdf: false, processing: {{window_s: 0.25, hop_s: 0.05}}}}  # session.xdf: tested elsewhere
"""
GROUPS = {"strong": ([0.98, 0.95, 0.9, 0.85], [0.85, 0.85, 0.9, 0.9]),
          "weak": ([0.9, 0.45, 0.1, 0.02], [0.15, 0.15, 0.1, 0.1])}


def _env(**extra: str) -> dict[str, str]:
    return dict(os.environ, QI_LOG_LEVEL="silent", **extra)


def _cli(*args: str, env=None, timeout: float = 120) -> subprocess.CompletedProcess:
    res = subprocess.run([sys.executable, "-m", "nao_trainer", *args], capture_output=True, text=True,
                         env=env or _env(), timeout=timeout)
    assert res.returncode == 0, f"nao-trainer {' '.join(args)} failed ({res.returncode}): {res.stderr[-2000:]}"
    assert "Traceback" not in res.stderr
    return res


@pytest.mark.slow
def test_sessions_import_fit_train_and_play_a_trained_policy(tmp_path):
    study = tmp_path / "study"
    for group, (p, e) in GROUPS.items():
        (tmp_path / f"{group}.yaml").write_text(STUDY.format(group=group, p=p, e=e))
    for batch in ((1, 2), (3, 4)):  # the sessions mostly wait (speech, answers): four run side by side
        runs = [subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", "--config", str(tmp_path / f"{g}.yaml"),
                                  "--pseudonym", f"{g}{i}", "--seed", str(i + (10 if g == "weak" else 0)),
                                  "--out", str(study), "--quiet", "--no-keys"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
                for g in GROUPS for i in batch]
        for proc in runs:
            _out, err = proc.communicate(timeout=120)
            assert proc.returncode == 0, err[-2000:]
    sessions = sorted(p.name for p in study.iterdir() if (p / "session.json").exists())
    assert len(sessions) == 8 and all((study / s / "session.json").exists() for s in sessions)
    assert not any((study / s / "session.xdf").exists() for s in sessions)  # eeg.xdf: false is obeyed

    _cli("import", str(study), "--out", str(tmp_path / "turns.csv"))
    with open(tmp_path / "turns.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 64 and {r["success"] for r in rows} <= {"0", "1"}
    assert {r["pseudonym"] for r in rows} == {f"{g}{i}" for g in GROUPS for i in range(1, 5)}

    # the study folder itself (import inside fit), figures included (issue 17: the figure step read only the
    # published layout); its participants are simulated, which fit refuses unless told
    refused = subprocess.run([sys.executable, "-m", "nao_trainer", "fit", str(study), "--out", str(tmp_path / "m0"),
                              "--k", "2", "--no-figures"], capture_output=True, text=True, env=_env(), timeout=120)
    assert refused.returncode == 2 and "8 of 8 sessions had a simulated participant" in refused.stderr
    fit = _cli("fit", str(study), "--out", str(tmp_path / "models"), "--k", "2", "--json", "--no-cache",
               "--include-simulated")
    assert (tmp_path / "models" / "users.png").stat().st_size > 0 and (tmp_path / "models" / "clusters.png").exists()
    report = json.loads(fit.stdout)
    assert report["inputs"] == ["simulated"] and report["simulated_sessions"] == 8
    groups = [{s.split("_")[0].rstrip("1234") for s in c["sessions"]} for c in report["clusters"]]
    assert sorted(map(sorted, groups)) == [["strong"], ["weak"]], report["clusters"]
    strong = next(c["id"] for c, g in zip(report["clusters"], groups) if g == {"strong"})
    assert [c["size"] for c in report["clusters"]] == [4, 4]

    _cli("train", "--models", str(tmp_path / "models"), "--out", str(tmp_path / "policies"), "--seeds", "1",
         "--episodes", "300", "--turns", "8", "--methods", "performance", "--no-plots")
    env = _env(NAO_TRAINER_MODELS=str(tmp_path / "models"), NAO_TRAINER_POLICIES=str(tmp_path / "policies"))
    _cli("run", "--config", str(tmp_path / "strong.yaml"), "--user-model", str(strong), "--policy",
         f"usp:{strong}", "--pseudonym", "trained", "--out", str(tmp_path / "next"), "--quiet", "--no-keys", env=env)
    (folder,) = [p for p in (tmp_path / "next").iterdir() if (p / "session.json").exists()]
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "completed" and info["policy"] == f"usp:{strong}"
    assert info["user_model"] == f"cluster-{strong}"
    with open(folder / "turns.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 8
    # ... and the new session is data again: it imports beside the first eight
    _cli("import", str(tmp_path), "--out", str(tmp_path / "again.csv"))
    with open(tmp_path / "again.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 72
