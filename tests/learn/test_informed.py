"""The informed MDP across the gym environment, training and policy files."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import mdp, processes
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import DataError
from nao_trainer.learn import policy_files
from nao_trainer.policies import learned
from nao_trainer.learn.training import TrainingSpec, train_grid


def test_gym_env_shows_the_outcome_in_the_informed_state():
    pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env

    from nao_trainer.learn.gym_env import SequenceLearningEnv

    sim = UserSimulator.from_level_rates("t", [0.9, 0.7, 0.4, 0.1])
    env = SequenceLearningEnv(sim, mdp="informed")
    check_env(env, skip_render_check=True)
    assert env.observation_space.n == 217
    obs, info = env.reset(seed=1)
    assert obs == processes.START_FULL and not info["action_mask"][4:].any()
    for a in (1, 4, 0, 5, 3, 2):
        obs, r, *_, info = env.step(a)
        assert obs % 2 == int(info["success"]) and mdp.LEVEL[obs // 2] == info["level"]
    paper = SequenceLearningEnv(sim)
    paper.reset(seed=1)
    env.reset(seed=1)
    for a in (1, 4, 0, 5, 3, 2):  # same random numbers: same turns, the paper state hides the outcome
        o1, r1, *_ = paper.step(a)
        o2, r2, *_ = env.step(a)
        assert o2 // 2 == o1 and r1 == r2


@pytest.fixture(scope="module")
def informed_policies(tmp_path_factory):
    out = tmp_path_factory.mktemp("inf")
    from nao_trainer.learn import artifacts
    from nao_trainer.learn.training import write_outputs

    sims = [artifacts.load_simulator(c) for c in ("1", "2")]
    result = train_grid(sims, ["1", "2"], TrainingSpec(seeds=2, episodes=100, workers=1, process="informed"),
                        progress=False)
    write_outputs(result, out, "sim/models", "test")
    return out, result


def test_informed_policy_files_record_their_mdp_and_load_back(informed_policies):
    out, result = informed_policies
    path = out / policy_files.policy_filename("1", "qaug")
    payload = policy_files.read_policy_file(path, "informed")
    assert payload["mdp_definition"] == processes.INFORMED_DEFINITION and len(payload["states"]) == 217
    learner = policy_files.learner_from_payload(payload, path)
    assert learner.process == "informed" and learner.q.shape == (217, 6)
    assert result.q.shape[-2:] == (217, 6)


def test_an_informed_policy_is_refused_by_the_paper_mdp_and_the_live_session(informed_policies):
    out, _ = informed_policies
    path = out / policy_files.policy_filename("1", "performance")
    with pytest.raises(DataError, match="made for the informed MDP, not the paper MDP"):
        policy_files.read_policy_file(path)
    with pytest.raises(DataError, match="made for the informed MDP") as exc:
        learned.load_policy("usp:1:performance", learning=False, state_path=None, policies_dir=out)
    assert "\n" not in str(exc.value)
    with pytest.raises(DataError, match="made for the paper MDP, not the informed MDP"):
        policy_files.read_policy_file(policy_files.default_policies_dir() / policy_files.policy_filename("1", "qaug"), "informed")


def test_training_rejects_an_unknown_mdp():
    with pytest.raises(ValueError, match="mdp must be one of paper, informed"):
        TrainingSpec(process="pomdp")
    assert np.isfinite(TrainingSpec(process="informed").config.alpha)


def test_the_commands_list_the_same_mdps_as_the_core():
    from nao_trainer.cli import evaluate, sweep, train  # noqa: F401 - the parsers' choices

    assert evaluate.MDPS == sweep.MDPS == processes.NAMES
