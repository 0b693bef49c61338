"""The auditory n-back task (issue 26 item 3): its rules, its simulated observer and a run through the whole chain."""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nao_trainer import registry
from nao_trainer.ports import Answer, Press
from nao_trainer.tasks.base import Task, check_columns
from nao_trainer.tasks.nback import NBackSettings, NBackTask, rules


def test_stream_has_exactly_its_targets_and_no_accidental_match():
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 4):
        stream, targets = rules.make_stream(rng, n)
        assert len(stream) == 20 + n and sum(targets) == 6
        assert all((stream[i] == stream[i - n]) == targets[i] for i in range(n, len(stream)))
        assert not any(targets[:n])


def test_d_prime_log_linear_correction_is_finite_at_perfect_rates():
    # 6/6 hits, 0/16 false alarms: H = 6.5/7, F = 0.5/17 (Hautus 1995) -> z(H) - z(F) = 3.355
    assert rules.d_prime(6, 0, 0, 16) == pytest.approx(3.3547, abs=1e-3)
    assert rules.d_prime(3, 3, 8, 8) == pytest.approx(0.0, abs=1e-9)  # chance
    assert rules.d_prime(0, 6, 16, 0) == pytest.approx(-3.3547, abs=1e-3)


def test_success_is_fewer_than_three_errors():
    assert rules.Outcome(6, 0, 2, 14).success and not rules.Outcome(5, 1, 2, 14).success


def test_presses_are_matched_to_the_stimulus_they_follow():
    onsets = (3.0, 6.0, 9.0, 12.0)
    assert rules.responded(onsets, 3.0, (2.0, 3.4, 3.9, 9.5, 16.0)) == (True, False, True, False)


def test_exact_block_success_matches_the_observer_it_is_computed_for():
    task = NBackTask()
    rng = np.random.default_rng(1)
    for level, p in zip(task.levels, task.level_success()):
        wins = [task.simulated_answer(task.make_trial(level, rng), rng, 0.5)[0] for _ in range(3000)]
        assert np.mean(wins) == pytest.approx(p, abs=0.03), level
    assert list(task.level_success()) == sorted(task.level_success(), reverse=True)  # harder with load


def test_judge_counts_hits_and_false_alarms_from_press_times():
    task = NBackTask()
    trial = task.make_trial(2, np.random.default_rng(4))
    trial.data["onsets"][:] = [3.0 * (i + 1) for i in range(len(trial.stimuli))]
    success, letters, times, _ = task.simulated_answer(trial, np.random.default_rng(5), 0.5)
    judged = task.judge(trial, Answer(tuple(Press("A", "A", t) for t in times), False))
    assert judged.success == success and judged.fields["hits"] + judged.fields["misses"] == 6
    assert set(judged.fields) == set(check_columns(task))


def test_nback_is_a_registered_task_with_its_settings():
    task = registry.make("task", "nback", NBackSettings(fillers=8))
    assert isinstance(task, Task) and len(task.make_trial(3, np.random.default_rng(0)).stimuli) == 11


def test_resume_checks_a_recorded_block_by_the_tasks_rules():
    from nao_trainer.session.record import row_problem

    task = NBackTask(NBackSettings(fillers=8))
    row = {"turn": "1", "level": "2", "n": "2", "stimuli": "GGTGWCWCCP", "targets": "0001001100", "hits": "2",
           "misses": "1", "false_alarms": "1", "correct_rejections": "6", "success": "True", "score": "2",
           "signed_score": "2"}
    assert row_problem(row, task) is None
    assert "not those of a success" in row_problem({**row, "score": "3"}, task)  # an edited score
    assert "do not add up" in row_problem({**row, "hits": "3"}, task)
    assert "3 errors" in row_problem({**row, "false_alarms": "2", "correct_rejections": "5"}, task)
    assert "do not agree" in row_problem(row, NBackTask())  # a stream of 10 letters is not a default 2-back block


STUDY = """\
study: {name: nback-test}
task:
  name: nback
  settings: {fillers: 8, targets: 3}
participant: {pseudonym: nb}
robot: {url: mock}
session: {turns: 3, practice: false}
timing: {speed: 10}
answers: {input: simulated}
policy: {kind: schedule, schedule: [L1, L2, L3]}
eeg: {mode: simulated, processing: {window_s: 0.5, hop_s: 0.1}}
"""


def test_run_task_nback_plays_the_chain_and_writes_its_own_fields(tmp_path):
    study = tmp_path / "nback.yaml"
    study.write_text(STUDY)
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--config", str(study), "--out", str(tmp_path),
                          "--quiet", "--no-keys"], capture_output=True, text=True,
                         env=dict(os.environ, QI_LOG_LEVEL="silent"), timeout=300)
    assert res.returncode == 0, res.stderr
    (folder,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    with (folder / "turns.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["level"] for r in rows] == ["1", "2", "3"] and "sequence" not in rows[0]
    events = [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]
    plans = [e for e in events if e["event"] == "simulated_plan"]
    # The observer presses its planned reaction time after each letter's place on the grid (0.15 s or less at
    # speed 10), the judge goes by the letter's actual onset: at speed 40 (0.04 s) a letter said late on a loaded
    # machine took the press meant for it as the previous letter's (seen once, two suites side by side).
    for row, plan in zip(rows, plans):  # the observer's presses went over qi and were judged as planned
        assert int(row["hits"]) + int(row["misses"]) == 3 and len(row["stimuli"]) == 8 + int(row["n"])
        assert row["success"] == str(plan["success"])
    stimuli = [e for e in events if e["event"] == "say" and e["what"] == "stimulus"]
    assert len(stimuli) == sum(len(r["stimuli"]) for r in rows)
    assert "d′ by level" in res.stdout and "letters" not in res.stdout
    # every stimulus is a marker in session.xdf (the Markers stream), at the time the monitor stamped it
    from nao_trainer.eeg import xdf

    if not xdf.available():
        pytest.skip("labrecorder not installed: session.xdf not written")
    pyxdf = pytest.importorskip("pyxdf")
    streams, _ = pyxdf.load_xdf(str(folder / "session.xdf"), synchronize_clocks=False, dejitter_timestamps=False)
    (markers,) = [s for s in streams if s["info"]["name"][0] == "Markers"]
    names = [v[0] for v in markers["time_series"]]
    for row in rows:
        said = [f"turn_{row['turn']}_stimulus_{i}" for i in range(1, len(row["stimuli"]) + 1)]
        assert [n for n in names if n.startswith(f"turn_{row['turn']}_stimulus_")] == said
    with open(folder / "eeg" / "events.csv", newline="") as fh:
        stamped = {r["event"]: float(r["lsl_time"]) for r in csv.DictReader(fh)}
    for name, t in zip(names, markers["time_stamps"]):
        if "_stimulus_" in name:
            assert abs(t - stamped[name]) < 2e-6, name


def test_run_task_nback_with_the_personalised_policy_matches_the_tasks_own_users(tmp_path):
    """Issue 26: the session hands its task to the policy; the personalised policy of an n-back session assesses
    and matches the n-back observers (Task.simulated_users), not the user models fitted on the sequence task."""
    study = tmp_path / "nback.yaml"
    study.write_text(STUDY.replace("policy: {kind: schedule, schedule: [L1, L2, L3]}",
                                   "policy: {kind: personalised, state_path: '{session}'}")
                     .replace("eeg: {mode: simulated, processing: {window_s: 0.5, hop_s: 0.1}}", 'eeg: {mode: "off"}'))
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--config", str(study), "--out", str(tmp_path),
                          "--turns", "2", "--speed", "100", "--quiet", "--no-keys"], capture_output=True, text=True,
                         env=dict(os.environ, QI_LOG_LEVEL="silent"), timeout=300)
    assert res.returncode == 0, res.stderr
    (folder,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    state = json.loads((folder / "personalised.json").read_text())["payload"]
    names = [name for name, _ in NBackTask().simulated_users()]
    assert state["models"] == names
    events = [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]
    (first, *_) = [e for e in events if e["event"] == "policy_status"]
    assert set(first["posterior"]) == set(names)
    assert "matched user model nback-" in res.stdout
