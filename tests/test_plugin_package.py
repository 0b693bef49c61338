"""A lab's own plug-ins from a separate distribution (tests/plugin_package/): found through Python entry points
(``importlib.metadata``, no pip), listed by ``nao-trainer plugins``, and a whole session played with the lab's
task, policy and EEG device; nothing of nao_trainer/ names them."""
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
from nao_trainer.errors import ConfigError
from nao_trainer.files import PROJECT_ROOT
from nao_trainer.session import config as session_config

PACKAGE = Path(__file__).parent / "plugin_package"  # an installed distribution: tiny_lab_plugins + its dist-info


def _env() -> dict[str, str]:
    """The environment of a process where the lab's package is installed (on the path, as site-packages is)."""
    path = os.pathsep.join([str(PACKAGE), str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")])
    return dict(os.environ, PYTHONPATH=path, QI_LOG_LEVEL="silent")


@pytest.fixture
def installed(monkeypatch):
    """The package installed in this process; everything it registered is forgotten after the test."""
    monkeypatch.syspath_prepend(str(PACKAGE))
    registry.reload_entry_points()
    yield
    registry.unregister("task", "backward")
    registry.unregister("policy", "alternate")
    registry.unregister("eeg_device", "tinyband")
    monkeypatch.undo()
    registry.reload_entry_points()
    # the policy section composed without `alternate` again: a later test in this process that reads
    # config.SECTIONS found policy.alternate_levels (seen under make test)
    session_config.refresh_policies()


def test_the_packages_plugins_are_found_through_entry_points(installed):
    assert "alternate" in registry.names("policy") and "tinyband" in registry.names("eeg_device")
    assert registry.spec("policy", "alternate").origin == "tiny-lab-plugins"
    from nao_trainer.policies.factory import offline_policy
    from nao_trainer.session.config import load_config

    config = load_config(None, {"policy.kind": "alternate", "policy.alternate_levels": [2, 4]})
    assert config.policy.own().alternate_levels == (2, 4) and not config.policy.persists
    offline = offline_policy(config.policy, 6)  # the offline form study power plays, through the registry
    assert [int(offline.table[t, 0].argmax()) + 1 for t in range(6)] == [2, 4, 2, 4, 2, 4]


def test_the_packages_task_is_built_from_a_config_and_judges_its_own_trials(installed):
    assert "backward" in registry.names("task") and registry.spec("task", "backward").origin == "tiny-lab-plugins"
    from nao_trainer.ports import Answer, Press
    from nao_trainer.session.config import load_config
    from nao_trainer.tasks.base import Task, check_columns

    config = load_config(None, {"task.name": "backward", "task.settings": {"seconds_per_letter": 1.5}})
    task = config.task.build_task()
    assert isinstance(task, Task) and check_columns(task) == ("letters", "expected", "correct_positions")
    trial = task.make_trial(3, np.random.default_rng(0))
    assert len(trial.stimuli) == 4 and trial.expected == trial.stimuli[::-1]
    assert task.response_timeout_s(trial, 2.0, 99.0) == 2.0 + 1.5 * 4  # the task's own setting, not the session's
    right = task.judge(trial, Answer(tuple(Press(c, c, 0.5 + i) for i, c in enumerate(trial.expected)), False))
    heard = task.judge(trial, Answer(tuple(Press(c, c, 0.5 + i) for i, c in enumerate(trial.stimuli)), False))
    assert right.success and right.fields["correct_positions"] == 4
    assert heard.success == (trial.stimuli == trial.expected)
    with pytest.raises(ConfigError, match="seconds_per_letter"):
        load_config(None, {"task.name": "backward", "task.settings": {"seconds_per_letter": -1}}).task.build_task()


def test_without_the_package_its_names_are_unknown():
    assert "alternate" not in registry.names("policy") and "tinyband" not in registry.names("eeg_device")
    assert "backward" not in registry.names("task")


def test_plugins_lists_the_packages_policy_and_device_with_their_settings():
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "plugins", "--json"], capture_output=True, text=True,
                         env=_env(), timeout=120)
    assert res.returncode == 0, res.stderr
    found = {(e["kind"], e["name"]): e for e in json.loads(res.stdout)}
    policy, device, task = found[("policy", "alternate")], found[("eeg_device", "tinyband")], found[("task", "backward")]
    assert policy["origin"] == device["origin"] == task["origin"] == "tiny-lab-plugins"
    assert [k["key"] for k in task["settings"]] == ["task.settings.seconds_per_letter", "task.settings.success_by_level"]
    assert policy["settings"] == [{"key": "policy.alternate_levels", "default": [1, 3],
                                   "rule": "a list of integers, checked by _levels", "doc": "the levels played in turn"}]
    assert [k["key"] for k in device["settings"]] == ["eeg.device_settings.max_std_uv"]


@pytest.mark.slow
def test_a_session_runs_with_the_packages_task_policy_and_eeg_device(tmp_path):
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--task", "backward", "--policy", "alternate",
                          "--eeg", "simulated", "--eeg-device", "tinyband", "--turns", "3", "--speed", "50", "--seed",
                          "3", "--out", str(tmp_path)], capture_output=True, text=True, env=_env(), timeout=300)
    assert res.returncode == 0, res.stderr
    (folder,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    rows = list(csv.DictReader((folder / "turns.csv").open()))
    assert [int(r["level"]) for r in rows] == [1, 3, 1]  # the lab's policy chose every level
    assert list(rows[0])[-3:] == ["letters", "expected", "correct_positions"]  # the lab's task's own row fields
    for r in rows:  # each trial is the task's: 2 or 4 letters, judged against their reverse
        assert len(r["letters"]) == {1: 2, 3: 4}[int(r["level"])] and r["expected"] == r["letters"][::-1]
        assert (r["success"] == "True") == (r["response"] == r["expected"])
    assert "longest backward span:" in res.stdout  # the task's own capacity line in the summary
    assert "backwards" in (folder / "robot_transcript.jsonl").read_text()  # its own words ("Level 1: 2 letters, ...")
    info = json.loads((folder / "session.json").read_text())
    assert info["policy"] == "alternate" and info["status"] == "completed"
    assert info["eeg_stream"]["name"] == "TinyBand" and info["eeg_stream"]["source_id"].startswith("tinyband-sim")
    assert info["config"]["values"]["eeg"]["device"] == "tinyband"


def test_nothing_in_nao_trainer_names_the_packages_plugins():
    for path in (PROJECT_ROOT / "nao_trainer").rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        assert "tiny_lab_plugins" not in text and "tinyband" not in text and "alternate_levels" not in text, path
        assert "BackwardTask" not in text and "correct_positions" not in text, path


WRONG_FIELDS = '''\
from tiny_lab_plugins.backward import BackwardTask


class WrongFields(BackwardTask):
    """The lab's task, its console table naming a field its rows do not record."""

    name = "wrongfields"
    table_fields = {"letters": "letters", "reaction_ms": "reaction"}
'''


def test_a_plugin_task_whose_table_fields_its_rows_do_not_record_is_refused_in_one_line(
        installed, tmp_path, monkeypatch, capsys):
    """Issue 26: ``nao-trainer run`` with a lab's task whose ``table_fields`` names a field not among its
    columns: the config-error exit code, one line naming the task and the field, no traceback, no session."""
    from nao_trainer.cli import main

    (tmp_path / "lab").mkdir()
    (tmp_path / "lab" / "wrong_fields_lab.py").write_text(WRONG_FIELDS)
    monkeypatch.syspath_prepend(str(tmp_path / "lab"))
    registry.register("task", "wrongfields", "wrong_fields_lab:WrongFields", origin="tests")
    try:
        code = main(["run", "--task", "wrongfields", "--policy", "alternate", "--robot", "mock", "--input", "simulated",
                     "--eeg", "off", "--turns", "2", "--speed", "200", "--no-practice", "--seed", "3", "--no-keys",
                     "--out", str(tmp_path / "sessions")])
    finally:
        registry.unregister("task", "wrongfields")
    out, err = capsys.readouterr()
    assert code == ConfigError.exit_code == 2, (out, err)
    assert "Traceback" not in out + err and len(err.strip().splitlines()) == 1, err
    assert "task 'wrongfields'" in err and "['reaction_ms']" in err, err
    assert not (tmp_path / "sessions").exists()  # refused before the robot connects or a folder is made
