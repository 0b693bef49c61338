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


SHIPPED_LIKE = ps.PooledModel(mu=7.0, tau=1.5, sigma=1.2, lapse=0.05)


def test_a_strong_session_has_a_longer_span_than_a_weak_one():
    strong = ps.session_span(SHIPPED_LIKE, ps.level_counts([1] * 6 + [2] * 6 + [3] * 6 + [4] * 6,
                                                           [True] * 18 + [True] * 5 + [False]))
    weak = ps.session_span(SHIPPED_LIKE, ps.level_counts([1] * 6 + [2] * 6 + [3] * 6 + [4] * 6,
                                                         [True] * 5 + [False] + [True] * 2 + [False] * 4
                                                         + [False] * 12))
    assert strong.median > weak.median + 1.0
    for span in (strong, weak):
        assert span.lo < span.median < span.hi and span.rate == 0.75 and span.level == 0.9
        assert 1.0 < span.median < 13.0


def test_no_turns_give_the_prior_span_and_turns_narrow_it():
    prior = ps.session_span(SHIPPED_LIKE, np.zeros(8))
    from statistics import NormalDist

    shift = 1.2 * NormalDist().inv_cdf(0.75 / 0.95)
    z = NormalDist().inv_cdf(0.95)
    assert prior.median == pytest.approx(7.0 - shift, abs=0.02)  # the prior's median theta, shifted
    assert prior.lo == pytest.approx(7.0 - shift - z * 1.5, abs=0.05)
    assert prior.hi == pytest.approx(7.0 - shift + z * 1.5, abs=0.05)
    many = ps.session_span(SHIPPED_LIKE, np.array([6, 0, 6, 0, 4, 2, 1, 5]) * 3)
    assert many.hi - many.lo < prior.hi - prior.lo


def test_the_median_is_where_the_posterior_curve_crosses_the_rate():
    model = ps.PooledModel(mu=6.0, tau=0.25, sigma=1.0, lapse=0.0)
    span = ps.session_span(model, np.zeros(8), rate=0.5)
    assert span.median == pytest.approx(6.0, abs=0.02)
    with pytest.raises(ValueError, match="never succeeds"):
        ps.session_span(ps.PooledModel(6.0, 1.0, 1.0, 0.3), np.zeros(8))
    with pytest.raises(ValueError, match="level 5"):
        ps.level_counts([5], [True])
    assert list(ps.level_counts([1, 1, 4], [True, False, False])) == [1, 1, 0, 0, 0, 0, 0, 1]


def test_the_marginal_as_a_matrix_product_equals_the_log_sum_exp_also_where_terms_underflow():
    rng = np.random.default_rng(2)
    counts = simulate(rng, 30, 6.0, 1.5, 1.0, 0.05, per_level=8)
    lp = -0.5 * ((ps.THETA[None, None, :] - ps._MU[:, None, None]) / ps._TAU[None, :, None]) ** 2
    lp = lp - ps._logsumexp(lp, 2)[..., None]
    ll = ps._log_lik(counts, 1.2, 0.05)
    # A likelihood peaked at theta 14: under the prior (mu 3, tau 0.25) every term of its integral is below
    # exp(-745), where a float underflows to 0 (no counts on this grid go that far: the fallback is a guard).
    ll[0] = -1000.0 * (ps.THETA - 14.0) ** 2
    exact = ps._logsumexp(ll[:, None, None, :] + lp[None], 3)
    fast = ps._marginal(ll, lp)
    top = ll.max(axis=1, keepdims=True)
    with np.errstate(divide="ignore"):
        assert not np.all(np.isfinite(np.log(np.exp(ll - top) @ np.exp(lp).reshape(-1, lp.shape[-1]).T)))
    assert np.all(np.isfinite(fast))
    np.testing.assert_allclose(fast, exact, rtol=1e-10, atol=1e-9)
