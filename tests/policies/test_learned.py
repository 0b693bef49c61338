"""The live learned policy (policies.learned): learning in a session, its state file, what it refuses."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nao_trainer.core import mdp
from nao_trainer.core.qlearning import QConfig, QLearner
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.learn import artifacts, policy_files
from nao_trainer.learn.training import TrainingSpec, train_grid, write_outputs
from nao_trainer.policies import learned
from nao_trainer.ports import Transition

S0 = mdp.encode(*mdp.S0)


def simulators():
    return [
        UserSimulator.from_level_rates("cluster-1", [0.95, 0.8, 0.35, 0.06], [0.3, 0.4, 0.5, 0.6]),
        UserSimulator.from_level_rates("cluster-2", [0.99, 0.95, 0.65, 0.3], [0.6, 0.5, 0.4, 0.3]),
    ]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A models folder and the policies trained on it (tiny grid)."""
    models = tmp_path_factory.mktemp("models")
    artifacts.save_models(models, simulators(), [{"id": 1}, {"id": 2}], {"k": 2})
    policies = tmp_path_factory.mktemp("policies")
    result = train_grid(simulators(), ["1", "2"], TrainingSpec(seeds=2, episodes=30, workers=1), progress=False)
    write_outputs(result, policies, str(models), "test")
    return models, policies


def load(trained, spec="usp:1:qaug", learning=True, state_path=None):
    models, policies = trained
    return learned.load_policy(spec, learning, state_path, policies_dir=policies,
                           models_dir=models)


def random_learner(method="shaping") -> QLearner:
    rng = np.random.default_rng(4)
    return QLearner(method, QConfig(), rng.normal(size=(109, 6)), rng.random((109, 6)),
                    rng.integers(0, 9, (109, 6)), rng.integers(0, 99, 109))


def test_simulator_fingerprint_mismatch_is_refused(trained, tmp_path):
    models, policies = trained
    refit = tmp_path / "models"
    changed = UserSimulator.from_level_rates("cluster-1", [0.9, 0.8, 0.35, 0.06], [0.3, 0.4, 0.5, 0.6])
    artifacts.save_models(refit, [changed, simulators()[1]], [{"id": 1}, {"id": 2}], {"k": 2})
    with pytest.raises(DataError, match=r"usp_1_qaug.json: trained on user model 'cluster-1'.*fingerprint.*retrain"):
        learned.load_policy("usp:1:qaug", True, None, policies_dir=policies, models_dir=refit)
    # Cluster 2 did not change: its policy still loads.
    learned.load_policy("usp:2:qaug", False, None, policies_dir=policies, models_dir=refit)


def test_spec_parsing_and_default_method(trained):
    models, policies = trained
    default = json.loads((policies / "manifest.json").read_text())["default_method"]["1"]
    policy = load(trained, "usp:1", learning=False)
    assert policy.learner.method == default and policy.name.startswith(f"usp:1:{default}")
    with pytest.raises(ConfigError, match="unknown method 'sarsa'"):
        load(trained, "usp:1:sarsa")
    with pytest.raises(ConfigError, match="no policy for cluster '7'"):
        load(trained, "usp:7")
    with pytest.raises(ConfigError, match="needs a file"):  # checked when it saves (the path may come later)
        load(trained, "usp:1:qaug", learning=True, state_path=None).save()


def test_live_policy_learns_and_saves_after_every_observe(trained, tmp_path):
    state = tmp_path / "learner.json"
    policy = load(trained, "usp:2:shaping", state_path=state)
    before = policy.learner.q.copy()
    rng = np.random.default_rng(1)
    a = policy.act(mdp.START, rng)
    assert a in mdp.LEVEL_ACTIONS
    s1 = int(mdp.NEXT_STATE[mdp.START, a, 0])
    reference = QLearner("shaping", policy.learner.config, before.copy(), policy.learner.h.copy(),
                         policy.learner.h_counts.copy(), policy.learner.visits.copy())
    policy.observe(Transition(mdp.START, a, 2, 0.7, s1, False))
    reference.update(mdp.START, a, 2, 0.7, s1, False)
    saved = policy_files.read_policy_file(state)
    assert saved["live"]["turns_learned"] == 1
    assert np.array_equal(np.array(saved["q"]), reference.q)  # the same update as in training
    assert not np.array_equal(reference.q, before)
    a2 = policy.act(s1, rng)
    s2 = int(mdp.NEXT_STATE[s1, a2, 1])
    policy.observe(Transition(s1, a2, -1, None, s2, False))  # EEG dropped: plain reward, no H update
    reference.update(s1, a2, -1, None, s2, False)
    saved = policy_files.read_policy_file(state)
    assert saved["live"] == {**saved["live"], "turns_learned": 2, "turns_without_engagement": 1}
    assert np.array_equal(np.array(saved["q"]), reference.q)
    assert np.array_equal(np.array(saved["h_counts"]), reference.h_counts)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["learner.json"]  # atomic: no temp files
    policy.close()
    # The next session with the same state file resumes from it.
    resumed = load(trained, "usp:2:shaping", state_path=state)
    assert np.array_equal(resumed.learner.q, reference.q)
    assert resumed.payload["live"]["turns_learned"] == 2


def test_state_file_of_another_policy_or_torn_is_not_silently_reset(trained, tmp_path):
    state = tmp_path / "learner.json"
    policy = load(trained, "usp:2:shaping", state_path=state)
    policy.observe(Transition(mdp.START, 1, 2, 0.5, mdp.encode(5, 0, 0), False))
    with pytest.raises(DataError, match="learner.json: participant state made with another policy"):
        load(trained, "usp:1:shaping", state_path=state)
    state.write_text(state.read_text()[:100])
    with pytest.raises(DataError, match="learner.json:.*not valid JSON"):
        load(trained, "usp:2:shaping", state_path=state)


def test_frozen_policy_leaves_everything_unchanged(trained, tmp_path):
    state = tmp_path / "learner.json"
    policy = load(trained, "usp:1:qaug", learning=False, state_path=state)
    q, h, visits = policy.learner.q.copy(), policy.learner.h.copy(), policy.learner.visits.copy()
    rng = np.random.default_rng(2)
    s = mdp.START
    for t in range(25):
        a = policy.act(s, rng)
        assert mdp.ACTION_MASK[s, a]
        s2 = int(mdp.NEXT_STATE[s, a, t % 2])
        policy.observe(Transition(s, a, 1, 0.9, s2, t == 24))
        s = s2
    policy.close()
    assert np.array_equal(policy.learner.q, q) and np.array_equal(policy.learner.h, h)
    assert np.array_equal(policy.learner.visits, visits)
    assert not state.exists()


def test_unwritable_state_path_is_a_clear_error(trained, tmp_path):
    (tmp_path / "a_file").write_text("x")
    policy = load(trained, "usp:1:qaug", state_path=tmp_path / "a_file" / "state.json")
    with pytest.raises(DataError, match="state.json: cannot save the policy's state"):
        policy.observe(Transition(mdp.START, 0, 1, 0.5, mdp.encode(3, 0, 0), False))
    nested = tmp_path / "new" / "folder" / "state.json"  # missing folders are created
    load(trained, "usp:1:qaug", state_path=nested).observe(Transition(mdp.START, 0, 1, 0.5, mdp.encode(3, 0, 0), False))
    assert nested.exists()


def test_shipped_policies_match_the_shipped_user_models():
    """The policies in sim/policies were trained on the models in sim/models (retrain after a refit)."""
    if not (policy_files.DEFAULT_POLICIES_DIR / policy_files.MANIFEST).exists():
        pytest.skip("no shipped policies")
    manifest = policy_files.read_manifest(policy_files.DEFAULT_POLICIES_DIR)
    for cluster in manifest["default_method"]:
        policy = learned.load_policy(f"usp:{cluster}", False, None, policies_dir=policy_files.DEFAULT_POLICIES_DIR,
                                 models_dir=artifacts.DEFAULT_MODELS_DIR)
        assert abs(policy.probabilities(S0).sum() - 1) < 1e-9


def _run_session(tmp_path, *extra):
    import subprocess
    import sys

    out = tmp_path / "sessions"
    cmd = [sys.executable, "-m", "nao_trainer", "run", "--user-model", "1", "--turns", "3", "--speed", "50", "--eeg", "off",
           "--out", str(out), "--quiet", "--no-practice", "--seed", "5", *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    (folder,) = out.iterdir()
    return folder


def test_session_with_a_shipped_policy_keeps_learning(tmp_path):
    """`nao-trainer run --policy usp:1:performance` plays a real (stand-in) session and learns from it."""
    if not (policy_files.DEFAULT_POLICIES_DIR / policy_files.MANIFEST).exists():
        pytest.skip("no shipped policies")
    folder = _run_session(tmp_path, "--policy", "usp:1:performance")
    state = policy_files.read_policy_file(folder / "policy_state.json")
    shipped = policy_files.read_policy_file(policy_files.DEFAULT_POLICIES_DIR / policy_files.policy_filename("1", "performance"))
    assert state["live"]["turns_learned"] == 3
    assert np.array(state["visits"]).sum() == np.array(shipped["visits"]).sum() + 3
    assert not np.array_equal(np.array(state["q"]), np.array(shipped["q"]))
    frozen = _run_session(tmp_path / "frozen", "--policy", "usp:1:performance", "--no-learning")
    assert not (frozen / "policy_state.json").exists()


def test_a_crash_while_saving_leaves_the_previous_state_intact(trained, tmp_path, monkeypatch):
    state = tmp_path / "learner.json"
    policy = load(trained, "usp:1:shaping", state_path=state)
    policy.observe(Transition(mdp.START, 1, 2, 0.5, mdp.encode(5, 0, 0), False))
    before = state.read_bytes()

    def crash(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(policy_files.os, "replace", crash)
    with pytest.raises(DataError, match="cannot save the policy's state"):
        policy.observe(Transition(mdp.encode(5, 0, 0), 2, -1, 0.4, mdp.encode(7, 0, 2), False))
    assert state.read_bytes() == before  # the last complete state, still valid
    assert policy_files.read_policy_file(state)["live"]["turns_learned"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["learner.json"]


def test_a_learning_policy_gets_its_state_path_when_it_first_saves(trained, tmp_path):
    from nao_trainer.errors import ConfigError

    policy = load(trained, "usp:1:shaping", state_path=None)  # loaded before the session folder exists
    step = Transition(mdp.START, 1, 2, 0.5, mdp.encode(5, 0, 0), False)
    with pytest.raises(ConfigError, match="policy.state_path: a learning policy needs a file"):
        policy.observe(step)
    policy.bind_state_dir(tmp_path)
    policy.observe(step)
    assert policy_files.read_policy_file(tmp_path / "policy_state.json")["live"]["turns_learned"] >= 1
    configured = load(trained, "usp:1:shaping", state_path=tmp_path / "own.json")
    configured.bind_state_dir(tmp_path / "elsewhere")  # a configured state file is kept
    assert configured.state_path == tmp_path / "own.json"


def test_a_resumed_policy_is_loaded_once_per_session(tmp_path):
    """The policy is loaded (and its resume message printed) once, before the robot connects."""
    import subprocess
    import sys

    if not (policy_files.DEFAULT_POLICIES_DIR / policy_files.MANIFEST).exists():
        pytest.skip("no shipped policies")
    state = tmp_path / "p_state.json"
    study = tmp_path / "study.yaml"
    study.write_text(f"policy:\n  kind: usp:1:performance\n  state_path: {state}\n")
    cmd = [sys.executable, "-m", "nao_trainer", "run", "--config", str(study), "--user-model", "1", "--turns", "2",
           "--speed", "50", "--out", str(tmp_path / "out"), "--quiet", "--no-practice", "--seed", "5"]
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    assert "resuming" not in first.stderr
    second = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert second.returncode == 0, second.stderr
    resumed = [ln for ln in second.stderr.splitlines() if "resuming from" in ln]
    assert resumed == [f"policy usp:1:performance: resuming from {state} (2 live turns learned)"], second.stderr
    assert policy_files.read_policy_file(state)["live"]["turns_learned"] == 4
