from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import objective


def test_score_is_equation_one_in_expectation():
    u = objective.SCORE.utility(np.array([0.5, 0.5, 1.0, 0.0]))
    assert u.tolist() == [0.0, 0.5, 3.0, -1.0]


def test_target_is_minus_squared_distance_and_coefficients_agree():
    o = objective.parse("target:0.75")
    assert str(o) == "target:0.75"
    p = np.array([[0.75, 0.5, 1.0, 0.0]])
    assert o.utility(p)[0].tolist() == pytest.approx([0.0, -0.0625, -0.0625, -0.5625])
    for obj in (o, objective.SCORE):
        cf = obj.coefficients(4)
        assert np.allclose(cf[:, 0] + cf[:, 1] * p + cf[:, 2] * p ** 2, obj.utility(p))


@pytest.mark.parametrize("bad", ["target:1.5", "target:x", "loss", "target:0"])
def test_bad_objectives_name_the_text(bad):
    with pytest.raises(ValueError, match="target|objective"):
        objective.parse(bad)


def test_defaults():
    assert objective.parse(None) is objective.SCORE
    assert objective.parse("target").rate == 0.75
