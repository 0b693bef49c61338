"""Staircases converge where the theory says (Levitt 1971): n successes up, one failure down
settles where p^n = 1/2."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import baselines


@pytest.mark.parametrize("rule,rate", [("1u1d", 0.5), ("2d1u", 0.5 ** 0.5), ("3d1u", 0.5 ** (1 / 3))])
def test_staircases_converge_to_their_rate_on_a_known_user(rule, rate):
    # a known user on a fine ladder: success falls smoothly from 0.99 to 0.01 over 200 steps
    steps = np.arange(1, 201)
    ladder = 0.01 + 0.98 / (1.0 + np.exp((steps - 100) / 8.0))
    got = baselines.staircase_success_rate(rule, ladder, 4000, np.random.default_rng(1), start=60)
    assert got == pytest.approx(rate, abs=0.015)


def test_the_three_down_rule_plays_levels_and_moves_after_three_successes():
    from nao_trainer.core import processes

    st = baselines.Staircase("3d1u", 2)
    st.reset(1, processes.get("informed"))
    obs = np.array([1])
    levels = []
    for t in range(5):
        levels.append(int(st.act(obs, t, np.random.default_rng(0))[0]) + 1)
        st.observe(obs, np.array([levels[-1] - 1]), np.array([float(levels[-1])]))  # a success: +level
    assert levels == [2, 2, 2, 3, 3]  # turn 0 knows nothing; three successes known by turn 3
