"""Per-participant learning: the policy's state lives in the participant's folder and the next session continues it."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nao_trainer.errors import ConfigError
from nao_trainer.session.config import DEFAULT_CONFIG, load_config
from nao_trainer.session.record import read_events
from nao_trainer.session.wiring import RunOptions, run_session


def config(tmp_path: Path, **over):
    values = {"session.turns": 3, "timing.speed": 50.0, "session.output": str(tmp_path / "out"), "eeg.mode": "off",
              "session.practice": False, "participant.pseudonym": "P7", "policy.kind": "usp:2",
              "session.seed": 3}
    values.update({k.replace("__", "."): v for k, v in over.items()})
    return load_config(DEFAULT_CONFIG, values)  # policy.state_path: null, the default


def policy_event(result):
    return next(e for e in read_events(result.path) if e["event"] == "policy_state")


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "nao_trainer", "run", *args], capture_output=True, text=True,
                          env=dict(os.environ, QI_LOG_LEVEL="silent"), timeout=120, stdin=subprocess.DEVNULL)


def test_the_next_session_of_a_participant_continues_learning(tmp_path):
    cfg = config(tmp_path)
    state = tmp_path / "out" / "participants" / "P7" / "policy_state.json"
    assert cfg.policy_state_file() == state
    first = run_session(cfg, RunOptions(quiet=True))
    assert first.exit_code == 0 and state.exists()
    ev = policy_event(first)
    assert ev["loaded_from"] == "trained policy" and ev["saves_to"] == str(state) and ev["turns_learned"] == 0
    learned = json.loads(state.read_text())["payload"]["live"]["turns_learned"]
    assert learned == 3
    second = run_session(config(tmp_path, session__seed=9), RunOptions(quiet=True))
    ev = policy_event(second)
    assert ev["loaded_from"] == str(state) and ev["turns_learned"] == 3
    assert json.loads(state.read_text())["payload"]["live"]["turns_learned"] == 6
    # another participant starts from the trained policy
    other = run_session(config(tmp_path, participant__pseudonym="P8"), RunOptions(quiet=True))
    assert policy_event(other)["loaded_from"] == "trained policy"


def test_a_pseudonym_template_and_fresh_policy(tmp_path):
    template = str(tmp_path / "states" / "{pseudonym}-usp.json")
    cfg = config(tmp_path, policy__state_path=template)
    target = tmp_path / "states" / "P7-usp.json"
    assert cfg.policy_state_file() == target
    run_session(cfg, RunOptions(quiet=True))
    assert target.exists()
    fresh = run_session(cfg, RunOptions(quiet=True, fresh_policy=True))
    ev = policy_event(fresh)
    assert ev["loaded_from"] == "trained policy" and ev["fresh"] is True
    aside = list((tmp_path / "states").glob("P7-usp.json.replaced-*"))
    assert len(aside) == 1 and json.loads(aside[0].read_text())["payload"]["live"]["turns_learned"] == 3  # kept


def test_an_unknown_placeholder_is_refused_at_load(tmp_path):
    with pytest.raises(ConfigError, match=r"unknown placeholder \{name\}"):
        config(tmp_path, policy__state_path="{output}/{name}.json")


def test_corrupt_or_foreign_state_is_refused_in_one_line(tmp_path):
    out = tmp_path / "out"
    state = out / "participants" / "P7" / "policy_state.json"
    state.parent.mkdir(parents=True)
    state.write_text('{"format": "nao-trainer/user-specific-policy", "format_ver')
    res = cli("--out", str(out), "--pseudonym", "P7", "--turns", "2", "--speed", "50", "--eeg", "off",
              "--config", str(DEFAULT_CONFIG), "--policy", "usp:2")
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and str(state) in lines[0] and "Traceback" not in res.stderr
    # the state of another policy (cluster 1) under this participant
    from nao_trainer.learn.policy_files import DEFAULT_POLICIES_DIR, policy_filename

    state.write_text((DEFAULT_POLICIES_DIR / policy_filename("1", "performance")).read_text())
    res = cli("--out", str(out), "--pseudonym", "P7", "--turns", "2", "--speed", "50", "--eeg", "off",
              "--config", str(DEFAULT_CONFIG), "--policy", "usp:2:performance")
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and "another policy" in lines[0]
    assert not list(out.glob("P7_*"))  # refused before any session folder
