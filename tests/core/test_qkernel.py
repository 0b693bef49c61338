"""The compiled learner (core.qkernel) against the numpy learner, and the informed MDP in the learners."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import mdp, processes, qkernel
from nao_trainer.core.batch import BatchLearner
from nao_trainer.core.qlearning import METHODS, QConfig, QLearner
from nao_trainer.core.simulation import UserSimulator

# numba found, not imported: collected by every worker, the import is paid where the tests run
pytestmark = pytest.mark.skipif(not qkernel.available(), reason="the compiled learner needs numba")


def _users():
    rng = np.random.default_rng(3)
    sims = [UserSimulator.from_level_rates(n, r, [0.3, 0.5, 0.6, 0.4]) for n, r in
            (("a", [0.95, 0.8, 0.4, 0.1]), ("b", [0.99, 0.9, 0.7, 0.5]))]
    p = np.stack([np.clip(s.p_success * rng.uniform(0.8, 1.1, 108), 0, 1) for s in sims])
    e = np.stack([np.clip(s.engagement * rng.uniform(0.5, 1.5, (108, 2)), 0, 1) for s in sims])
    return np.repeat(p, 3, axis=0), np.repeat(e, 3, axis=0), list(METHODS) * 2


@pytest.mark.parametrize("process", processes.NAMES)
def test_compiled_kernel_is_bit_identical_to_numpy(process):
    p, e, methods = _users()
    cfg = QConfig(n_half=20.0)  # cools fast: many near-deterministic choices, the hard case for equality
    runs = [BatchLearner(p, e, methods, cfg, process, engine).run(400, 25, [np.random.default_rng(i) for i in range(6)],
                                                                   block=64)
            for engine in ("numpy", "numba")]
    for key in ("q", "h", "h_counts", "visits", "episode_score", "episode_engagement"):
        assert np.array_equal(getattr(runs[0], key), getattr(runs[1], key)), key
    assert runs[0].q.shape == (6, processes.get(process).n_states, 6)


def test_informed_batch_equals_a_single_agent_step_by_step():
    p, e, methods = _users()
    proc = processes.get("informed")
    episodes, turns = 60, 25
    res = BatchLearner(p[:3], e[:3], methods[:3], process="informed", engine="numba").run(
        episodes, turns, [np.random.default_rng(i) for i in range(3)])
    for i, method in enumerate(methods[:3]):
        ql = QLearner(method, process="informed")
        u = np.random.default_rng(i).random((episodes, turns, 2))
        for k in range(episodes):
            x = proc.start
            for t in range(turns):
                a = ql.choose(x, u[k, t, 0])
                s2 = int(processes.NEXT_TURN[x, a])
                o2 = int(u[k, t, 1] < p[i, s2])
                x2 = 2 * s2 + o2
                ql.update(x, a, float(mdp.SCORE[s2, o2]), e[i, s2, o2], x2,
                          t == turns - 1)
                x = x2
        assert np.array_equal(ql.q, res.q[i]) and np.array_equal(ql.visits, res.visits[i]), method


def test_engine_choice_is_checked():
    p, e, methods = _users()
    with pytest.raises(ValueError, match="engine must be one of"):
        BatchLearner(p, e, methods, engine="gpu")
