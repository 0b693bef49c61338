"""Policy files and manifests (learn.policy_files): round trip, torn or foreign files refused in one line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nao_trainer.learn import artifacts

from nao_trainer.learn import policy_files
from nao_trainer.core import mdp
from nao_trainer.core.qlearning import QConfig, QLearner
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.ports import Transition
from nao_trainer.learn.training import TrainingSpec, train_grid, write_outputs

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


def test_policy_file_round_trip(tmp_path):
    ql = random_learner()
    sim = simulators()[0]
    path = tmp_path / "p.json"
    policy_files.save_policy_file(path, policy_files.make_payload(ql, "1", sim, {"episodes": 5}))
    payload = policy_files.read_policy_file(path)
    back = policy_files.learner_from_payload(payload, path)
    assert back.method == "shaping" and back.config == ql.config
    for key in ("q", "h", "h_counts", "visits"):
        assert np.array_equal(getattr(back, key), getattr(ql, key))
    assert payload["simulator"]["fingerprint"] == sim.fingerprint()
    assert payload["states"][S0] == "(5, 1, -2)" and payload["actions"][4] == "RF1"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp file left


def _rewrite(path, edit):
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))


def test_torn_and_corrupt_files_are_detected(tmp_path):
    path = tmp_path / "p.json"
    policy_files.save_policy_file(path, policy_files.make_payload(random_learner(), "1", simulators()[0], {}))
    text = path.read_text()
    torn = tmp_path / "torn.json"
    torn.write_text(text[: len(text) // 2])
    with pytest.raises(DataError, match=r"torn.json:\d+: policy file is not valid JSON.*torn or corrupt"):
        policy_files.read_policy_file(torn)
    empty = tmp_path / "empty.json"
    empty.write_text("")
    with pytest.raises(DataError, match="not valid JSON"):
        policy_files.read_policy_file(empty)
    altered = tmp_path / "altered.json"
    altered.write_text(text)
    _rewrite(altered, lambda d: d["payload"]["q"][S0].__setitem__(2, 99.0))
    with pytest.raises(DataError, match="altered.json: checksum mismatch"):
        policy_files.read_policy_file(altered)
    with pytest.raises(DataError, match="no such policy file.*nao-trainer train"):
        policy_files.read_policy_file(tmp_path / "missing.json")


def test_other_state_action_definition_is_refused(tmp_path):
    payload = policy_files.make_payload(random_learner(), "1", simulators()[0], {})
    payload["mdp_definition"] = payload["mdp_definition"].replace("PR in -4..4", "PR in -3..3")
    policy_files.save_policy_file(tmp_path / "def.json", payload)  # valid checksum, other definition
    with pytest.raises(DataError, match="another state/action definition.*nao-trainer train"):
        policy_files.read_policy_file(tmp_path / "def.json")
    payload = policy_files.make_payload(random_learner(), "1", simulators()[0], {})
    payload["actions"] = ["L1", "L2", "L3", "L4", "RF2", "RF1"]
    policy_files.save_policy_file(tmp_path / "act.json", payload)
    with pytest.raises(DataError, match="actions"):
        policy_files.read_policy_file(tmp_path / "act.json")


def test_a_broken_policy_manifest_is_a_one_line_error(tmp_path):
    (tmp_path / policy_files.MANIFEST).mkdir()
    with pytest.raises(DataError, match=r"manifest.json: cannot read \(Is a directory\)"):
        policy_files.read_manifest(tmp_path)
    (tmp_path / policy_files.MANIFEST).rmdir()
    (tmp_path / policy_files.MANIFEST).write_text(json.dumps({"format": policy_files.MANIFEST_FORMAT, "format_version": 1,
                                                     "default_method": []}))
    with pytest.raises(DataError, match="unknown version or shape"):
        policy_files.read_manifest(tmp_path)


