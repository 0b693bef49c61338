"""The Gymnasium environment of a simulated participant."""
from __future__ import annotations

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402

from nao_trainer.core import mdp  # noqa: E402
from nao_trainer.core.simulation import UserSimulator  # noqa: E402
from nao_trainer.learn.gym_env import ENV_ID, SequenceLearningEnv  # noqa: E402


@pytest.fixture
def sim() -> UserSimulator:
    base = UserSimulator.from_level_rates("t", [0.9, 0.7, 0.4, 0.1], [0.2, 0.4, 0.6, 0.8])
    eng = np.array(base.engagement)
    eng[:, 1] += 0.1  # success more engaging, so info["engagement"] shows the outcome
    return UserSimulator("t", base.p_success, eng, base.reaction_quantiles, base.completion_quantiles)


def _rollout(env, seed, actions):
    obs, info = env.reset(seed=seed)
    trace = [(obs, tuple(info["action_mask"]))]
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        trace.append((obs, r, term, trunc, info["engagement"], info["success"]))
    return trace


def test_passes_the_gymnasium_env_checker(sim):
    check_env(SequenceLearningEnv(sim), skip_render_check=True)
    check_env(gymnasium.make(ENV_ID, simulator=sim, render_mode="ansi").unwrapped)


def test_episode_follows_the_mdp_tables(sim):
    env = SequenceLearningEnv(sim, turns=25)
    obs, info = env.reset(seed=3)
    assert obs == mdp.START and info["action_mask"].tolist() == [True] * 4 + [False] * 2
    rng = np.random.default_rng(0)
    prev_obs, prev_success, total = obs, False, 0
    for turn in range(1, 26):
        a = int(rng.integers(4)) if prev_obs == mdp.START else int(rng.integers(6))
        obs, reward, terminated, truncated, info = env.step(a)
        assert obs == mdp.NEXT_STATE[prev_obs, a, int(prev_success)]
        assert reward == (mdp.LEVEL[obs] if info["success"] else -1)  # equation (1)
        assert info["engagement"] == sim.engagement[obs, int(info["success"])]
        assert info["action_mask"].all() and not truncated
        assert terminated == (turn == 25)
        prev_obs, prev_success = obs, info["success"]
        total += 1
    assert total == 25
    with pytest.raises(RuntimeError, match="reset"):
        env.step(0)


def test_seeding_is_reproducible(sim):
    actions = [1, 4, 2, 5, 3, 0, 5, 5] * 3
    a = _rollout(SequenceLearningEnv(sim), 42, actions)
    b = _rollout(SequenceLearningEnv(sim), 42, actions)
    c = _rollout(SequenceLearningEnv(sim), 43, actions)
    assert a == b and a != c


def test_success_rate_follows_the_simulator(sim):
    env = SequenceLearningEnv(sim, turns=400)
    env.reset(seed=0)
    wins = [env.step(3)[4]["success"] for _ in range(400)]  # L4 every turn: P = 0.1
    assert 0.05 < np.mean(wins) < 0.16


def test_feedback_action_in_start_is_played_as_level_1(sim):
    env = SequenceLearningEnv(sim)
    env.reset(seed=1)
    obs, _, _, _, info = env.step(mdp.ENCOURAGE)
    assert info["invalid_action"] and obs == mdp.encode(3, 0, 0)
    with pytest.raises(ValueError, match="action must be in 0..5, got 6"):
        env.step(6)


def test_loads_the_shipped_models_by_id():
    env = gymnasium.make(ENV_ID, simulator="3")
    obs, _ = env.reset(seed=0)
    assert obs == mdp.START
    assert env.unwrapped.simulator.name == "cluster-3"


def test_render_ansi(sim):
    env = SequenceLearningEnv(sim, render_mode="ansi")
    env.reset(seed=0)
    env.step(1)
    assert env.render().startswith("turn 1/25: L2 -> state (5, 0, 0)")
