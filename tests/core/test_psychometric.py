"""The pooled psychometric user model: fitting recovers a known population, turns at one length
inform the others, and the span is where the curve crosses the rate."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import psychometric as ps


def simulate(rng, n, mu, tau, sigma, lapse, per_level=6):
    out = []
    for theta in rng.normal(mu, tau, n):
        p = ps.curve(ps.LENGTHS, theta, sigma, lapse)
        wins = rng.binomial(per_level, p)
        out.append(np.ravel(np.column_stack([wins, per_level - wins])))
    return np.array(out, dtype=float)


def test_fit_recovers_a_known_population():
    rng = np.random.default_rng(5)
    model = ps.fit(simulate(rng, 400, 6.5, 1.0, 1.2, 0.05, per_level=10))
    assert model.mu == pytest.approx(6.5, abs=0.3)
    assert model.sigma == pytest.approx(1.2, rel=0.35)
    assert model.tau <= 1.5 and model.lapse <= 0.1


def test_turns_at_one_length_inform_another():
    model = ps.PooledModel(mu=6.0, tau=1.5, sigma=1.0, lapse=0.02)
    prior = model.predictive(np.zeros(8))
    strong = model.predictive(np.array([0, 0, 6, 0, 0, 0, 0, 0]))  # six successes at length 5 only
    weak = model.predictive(np.array([0, 0, 0, 6, 0, 0, 0, 0]))  # six failures at length 5 only
    assert strong[3] > prior[3] > weak[3]  # ... move the prediction at length 9
    assert np.all(np.diff(prior) < 0)


def test_span_is_where_the_curve_crosses_the_rate():
    model = ps.PooledModel(mu=6.0, tau=0.25, sigma=1.0, lapse=0.0)
    counts = np.zeros(8)
    mean, lo, hi = model.span(counts, 0.5)
    assert lo <= mean <= hi and mean == pytest.approx(6.0, abs=0.05)
    mean75 = model.span(counts, 0.75)[0]
    assert ps.curve(np.array([mean75]), 6.0, 1.0, 0.0)[0] == pytest.approx(0.75, abs=0.02)
    with pytest.raises(ValueError, match="never succeeds"):
        ps.PooledModel(6.0, 1.0, 1.0, 0.3).span(counts, 0.75)
