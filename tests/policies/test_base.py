"""The guidance rule (policies.base): one formula for the learned and the personalised policy."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import mdp
from nao_trainer.policies.base import Guidance


def test_off_without_weight_or_overrides():
    s = mdp.encode(5, 0, 2)
    assert Guidance(0.0).bonus(s, np.array([1.0, 2.0])) is None
    g = Guidance(1.0)
    assert not g.active(s) and g.bonus(s, np.array([1.0, 2.0])) is None
    g.record(s, 3)
    off = Guidance(0.0, g.counts)
    assert off.bonus(s, np.array([1.0, 2.0])) is None and g.active(s)


def test_per_action_and_per_choice_share_scaled_by_the_spread():
    s = mdp.encode(5, 0, 2)
    g = Guidance(2.0)
    for a in (1, 1, 1, 3):
        g.record(s, a)
    values = np.array([0.0, 4.0, 1.0])  # spread 4: + 1 = 5
    per_action = g.bonus(s, values)
    assert per_action == pytest.approx(2.0 * np.array([0, 0.75, 0, 0.25, 0, 0]) * 5.0)
    plays = [np.eye(6)[1], np.full(6, 1 / 6)]  # a choice that always plays action 1, one that plays anything
    per_choice = g.bonus(s, values, plays)
    assert per_choice == pytest.approx([2.0 * 0.75 * 5.0, 2.0 * (1 / 6) * 5.0])


def test_the_counts_travel_as_pairs():
    g = Guidance(1.0)
    g.record(mdp.START, 2)
    g.record(mdp.START, 2)
    g.record(7, 0)
    again = Guidance.from_pairs(1.0, g.pairs())
    assert g.pairs() == {f"{mdp.START},2": 2, "7,0": 1} and np.array_equal(again.counts, g.counts)
