"""UserSimulator: the resting engagement a simulated participant shows before any turn."""
import numpy as np
import pytest

from nao_trainer.core.simulation import UserSimulator


def test_rest_engagement_is_the_models_lowest_unless_the_file_says():
    sim = UserSimulator.from_level_rates("x", [0.9, 0.8, 0.5, 0.2], [0.45, 0.6, 0.7, 0.55])
    assert sim.rest_engagement() == pytest.approx(0.45)
    given = UserSimulator.from_dict({**sim.to_dict(), "metadata": {"rest_engagement": 0.8}})
    assert given.rest_engagement() == 0.8 and given.fingerprint() == sim.fingerprint()  # metadata: not a table
    for bad in (1.5, "high", True):
        with pytest.raises(ValueError, match="metadata.rest_engagement must be a number in \\[0, 1\\]"):
            UserSimulator.from_dict({**sim.to_dict(), "metadata": {"rest_engagement": bad}})


def test_the_demo_participant_rests_at_its_least_engaging_level():
    from nao_trainer.learn.artifacts import load_simulator
    from nao_trainer.session.config import PROJECT_ROOT

    sim = load_simulator(str(PROJECT_ROOT / "sim" / "participants" / "level4.json"))
    assert sim.rest_engagement() == pytest.approx(float(np.min(sim.engagement)))
    assert sim.rest_engagement() == pytest.approx(sim.engagement_of(81, True))  # level 4 (state 81: L4)
