"""The right person (session.participant): an entered pseudonym, one session per participant, a state of one's own."""
from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from nao_trainer.errors import ConfigError, DataError, UserError
from nao_trainer.files import PROJECT_ROOT
from nao_trainer.session.config import DEFAULT_CONFIG, load_config
from nao_trainer.session.participant import SIMULATED, check_pseudonym, lock_path, participant_lock
from nao_trainer.session.wiring import RunOptions, run_session

STUDIES = PROJECT_ROOT / "config" / "studies"


def one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text
    return text


def test_no_shipped_file_but_the_simulated_demo_names_a_participant():
    assert yaml.safe_load(DEFAULT_CONFIG.read_text())["participant"]["pseudonym"] is None
    for path in STUDIES.glob("*.yaml"):
        pseudonym = (yaml.safe_load(path.read_text()).get("participant") or {}).get("pseudonym")
        study = load_config(path)
        assert pseudonym is None or (study.answers.input == "simulated" and study.robot.url == "mock"), path


@pytest.mark.parametrize("study, over", [
    (STUDIES / "paper-2018.yaml", {"answers.input": "keyboard", "robot.url": "mock"}),  # a person answers
    (STUDIES / "paper-2018.yaml", {"answers.input": "simulated", "robot.url": "tcp://127.0.0.1:9559"}),  # a real robot
    (STUDIES / "demo.yaml", {"answers.input": "keyboard", "eeg.mode": "off"}),  # "demo" was entered for nobody
    (DEFAULT_CONFIG, {"answers.input": "tactile", "robot.url": "tcp://127.0.0.1:9559"}),
])
def test_a_person_or_a_real_robot_needs_an_entered_pseudonym(study, over):
    with pytest.raises(ConfigError) as exc:
        check_pseudonym(load_config(study, over))
    assert one_line(exc).startswith("participant.pseudonym: no pseudonym entered")
    assert "--pseudonym ID" in str(exc.value)
    entered = load_config(study, {**over, "participant.pseudonym": "P07"})
    check_pseudonym(entered)
    assert entered.participant.pseudonym == "P07"


def test_a_study_file_written_for_the_participant_names_them(tmp_path):
    study = tmp_path / "p12.yaml"
    study.write_text("study: {name: mine}\nparticipant: {pseudonym: P12}\nanswers: {input: keyboard}\n")
    check_pseudonym(load_config(study))
    assert load_config(study).participant.pseudonym == "P12"


def test_a_simulated_participant_without_a_pseudonym_is_called_simulated():
    config = load_config(STUDIES / "paper-2018.yaml", {"answers.input": "simulated", "robot.url": "mock"})
    check_pseudonym(config)
    assert config.participant.pseudonym == SIMULATED
    check_pseudonym(load_config(STUDIES / "demo.yaml"))
    assert load_config(STUDIES / "demo.yaml").participant.pseudonym == "demo"


def test_the_refusal_comes_before_anything_is_written(tmp_path):
    config = load_config(STUDIES / "paper-2018.yaml", {"answers.input": "keyboard", "robot.url": "mock",
                                                       "session.output": str(tmp_path / "out")})
    with pytest.raises(ConfigError):
        run_session(config, RunOptions(quiet=True))
    assert not (tmp_path / "out").exists()


def config(tmp_path: Path, pseudonym: str = "P7", **over):
    values = {"session.turns": 2, "timing.speed": 50.0, "session.output": str(tmp_path / "out"), "eeg.mode": "off",
              "session.practice": False, "participant.pseudonym": pseudonym, "policy.kind": "usp:2", "session.seed": 3}
    values.update({k.replace("__", "."): v for k, v in over.items()})
    return load_config(DEFAULT_CONFIG, values)


def test_a_second_session_of_the_participant_is_refused_while_the_first_runs(tmp_path):
    out = tmp_path / "out"
    state = config(tmp_path).policy_state_file()
    assert state == out / "participants" / "P7" / "policy_state.json"
    with participant_lock(state, "P7") as held:
        assert held == lock_path(state) and json.loads(held.read_text())["pid"] > 0
        with pytest.raises(UserError) as exc:
            run_session(config(tmp_path), RunOptions(quiet=True))
        assert one_line(exc).startswith(f"{held}: participant P7 is in another session (pid ")
        assert not list(out.glob("P7_*")) and not state.exists()  # nothing played, nothing learned
        assert run_session(config(tmp_path, "P8"), RunOptions(quiet=True)).exit_code == 0  # another participant may run
    assert not held.exists()  # released
    assert run_session(config(tmp_path), RunOptions(quiet=True)).exit_code == 0
    assert state.exists() and not lock_path(state).exists()


def test_a_lock_left_by_a_killed_session_is_taken_over_with_a_notice(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    state = tmp_path / "participants" / "P7" / "policy_state.json"
    state.parent.mkdir(parents=True)
    stale = lock_path(state)
    stale.write_text(json.dumps({"pid": dead.pid, "host": __import__("socket").gethostname(),
                                 "started": "2026-01-01T00:00:00+00:00"}))
    notice = io.StringIO()
    with participant_lock(state, "P7", notice) as held:
        assert json.loads(held.read_text())["pid"] != dead.pid
    assert f"a lock left by session pid {dead.pid}" in notice.getvalue() and notice.getvalue().count("\n") == 1
    # a lock held on another machine cannot be judged: refused
    stale.write_text(json.dumps({"pid": dead.pid, "host": "another-host", "started": "2026-01-01T00:00:00+00:00"}))
    with pytest.raises(UserError, match="on another-host"):
        with participant_lock(state, "P7"):
            pass


def test_a_state_file_copied_from_another_participant_is_refused(tmp_path):
    assert run_session(config(tmp_path), RunOptions(quiet=True)).exit_code == 0
    participants = tmp_path / "out" / "participants"
    state = participants / "P7" / "policy_state.json"
    assert json.loads(state.read_text())["payload"]["live"]["pseudonym"] == "P7"
    (participants / "P8").mkdir()
    shutil.copy(state, participants / "P8" / "policy_state.json")
    with pytest.raises(DataError) as exc:
        run_session(config(tmp_path, "P8"), RunOptions(quiet=True))
    assert "of 'P7', not of 'P8'" in one_line(exc) and "--fresh-policy" in str(exc.value)
    fresh = run_session(config(tmp_path, "P8"), RunOptions(quiet=True, fresh_policy=True))
    assert fresh.exit_code == 0  # the copy is set aside, P8 starts from the trained policy
    assert json.loads((participants / "P8" / "policy_state.json").read_text())["payload"]["live"]["pseudonym"] == "P8"


def test_torn_or_mismatched_state_names_fresh_policy_never_retrain_or_delete(tmp_path):
    out = tmp_path / "out"
    state = out / "participants" / "P7" / "policy_state.json"
    state.parent.mkdir(parents=True)
    state.write_text('{"format": "nao-trainer/user-specific-policy", "format_ver')
    with pytest.raises(DataError) as exc:
        run_session(config(tmp_path), RunOptions(quiet=True))
    assert "--fresh-policy" in one_line(exc) and "retrain" not in str(exc.value)
    from nao_trainer.learn.policy_files import DEFAULT_POLICIES_DIR, policy_filename

    state.write_text((DEFAULT_POLICIES_DIR / policy_filename("1", "performance")).read_text())  # another policy
    with pytest.raises(DataError) as exc:
        run_session(config(tmp_path, policy__kind="usp:2:performance"), RunOptions(quiet=True))
    assert "another policy" in one_line(exc) and "--fresh-policy" in str(exc.value) and "delete" not in str(exc.value)
