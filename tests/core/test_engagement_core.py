"""Engagement maths on synthetic signals: band powers, index, EWMA, quality, online estimator, normaliser."""
import numpy as np
import pytest

from nao_trainer.core import engagement as eng
from nao_trainer.core import phase

FS = 256.0


def _signal(rng, freqs_amps, seconds=4.0, fs=FS, n_ch=4, noise=2.0, offset=850.0):
    t = np.arange(int(seconds * fs)) / fs
    x = np.full((t.size, n_ch), offset) + rng.normal(0, noise, (t.size, n_ch))
    for f, a in freqs_amps:
        x += a * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 2 * np.pi, n_ch))
    return t, x


def test_relative_powers_locate_known_sinusoids():
    rng = np.random.default_rng(1)
    for f, col in ((6.0, 0), (10.0, 1), (20.0, 2)):
        _, x = _signal(rng, [(f, 20.0)])
        rel = eng.relative_band_powers(x[:512], FS)
        assert rel.shape == (4, 3)
        assert (rel[:, col] > 0.95).all(), (f, rel)
        assert (rel.sum(axis=1) <= 1 + 1e-12).all()


def test_relative_powers_match_scipy_welch():
    from scipy.signal import welch

    rng = np.random.default_rng(2)
    _, x = _signal(rng, [(7.0, 5.0), (11.0, 8.0), (22.0, 4.0)], noise=6.0)
    w = x[:512]
    f, p = welch(w, FS, window="hann", nperseg=256, noverlap=128, detrend="linear", axis=0)
    tot = p[(f >= 1) & (f < 40)].sum(axis=0)
    want = np.stack([p[(f >= lo) & (f < hi)].sum(axis=0) / tot for lo, hi in eng.BANDS.values()], axis=1)
    np.testing.assert_allclose(eng.relative_band_powers(w, FS), want, rtol=1e-9, atol=1e-12)


def test_beta_dominant_input_scores_higher_than_alpha_theta_dominant():
    rng = np.random.default_rng(3)
    _, beta = _signal(rng, [(20.0, 15.0), (10.0, 4.0), (6.0, 4.0)], noise=4.0)
    _, slow = _signal(rng, [(20.0, 4.0), (10.0, 15.0), (6.0, 15.0)], noise=4.0)
    scores = []
    for x in (beta, slow):
        rel = eng.relative_band_powers(x[:512], FS).mean(axis=0)
        scores.append(float(eng.engagement_index(*rel)))
    assert scores[0] > 1.0 > scores[1]


def test_engagement_index_nan_on_zero_denominator():
    out = eng.engagement_index(np.array([0.2, 0.0]), np.array([0.3, 0.0]), np.array([0.5, 0.4]))
    assert out[0] == pytest.approx(1.0) and np.isnan(out[1])


def test_ewma_hand_computed():
    y = np.array([1.0, 2.0, 3.0, 5.0])
    np.testing.assert_allclose(eng.ewma(y, 0.5), [1.0, 1.5, 2.25, 3.625])
    # continuing a stream from s0
    np.testing.assert_allclose(eng.ewma(np.array([4.0]), 0.75, s0=2.0), [0.75 * 2 + 0.25 * 4])
    # 2-D: columns independent
    np.testing.assert_allclose(eng.ewma(np.c_[y, 2 * y], 0.5)[:, 1], 2 * eng.ewma(y, 0.5))
    with pytest.raises(ValueError, match="a must be in"):
        eng.ewma(y, 1.0)


def test_streaming_ewma_equals_batch_and_skips_nan():
    rng = np.random.default_rng(4)
    y = rng.normal(size=50)
    s = eng.Ewma(0.8)
    np.testing.assert_allclose([s.update(v) for v in y], eng.ewma(y, 0.8))
    before = s.value
    assert np.isnan(s.update(float("nan"))) and s.value == before
    s.reset()
    assert s.update(3.0) == 3.0


def test_lagged_authors_form():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    # S0=Y0; S1=.1*Y0+.9*S0; S2=.1*Y1+.9*S1; S3=.1*Y2+.9*S2
    s = [1.0]
    for i in range(1, 4):
        s.append(0.1 * y[i - 1] + 0.9 * s[-1])
    np.testing.assert_allclose(eng.lagged_ewma_authors2018(y), s, rtol=0, atol=1e-15)


def test_quality_flags_each_failure():
    rng = np.random.default_rng(5)
    _, x = _signal(rng, [(10.0, 15.0)], seconds=2.0, n_ch=6, noise=5.0)
    x[:, 0] = 850.0 + rng.normal(0, 0.1, x.shape[0])  # flat
    x[100:160, 1] = 1682.8  # clipped at the rail for 60 samples
    x[:, 2] += rng.normal(0, 300, x.shape[0])  # implausible
    x[10, 3] = np.nan
    clean, reasons = eng.window_quality(x, FS)
    assert reasons == ["flat", "saturated", "implausible amplitude", "non-finite", "", ""]
    assert clean.tolist() == [False, False, False, False, True, True]
    # explicit rails catch a single touch of the rail
    y = x[:, 4:6].copy()
    y[5, 0] = 1000.0
    _, r = eng.window_quality(y, FS, eng.QualityThresholds(rail_low=-1000.0, rail_high=1000.0))
    assert r == ["saturated", ""]


def test_quality_keeps_coarsely_quantised_real_like_eeg():
    # the Muse's 12-bit raw values step by ~1.6 uV and repeat; that is not saturation
    rng = np.random.default_rng(6)
    _, x = _signal(rng, [(10.0, 10.0), (20.0, 5.0)], seconds=2.0, noise=8.0)
    x = np.round(x / 1.645) * 1.645
    clean, _ = eng.window_quality(x, 220.0)
    assert clean.all()


def _stream(oe, t, x, chunk=12):
    out = []
    for i in range(0, t.size, chunk):
        out += oe.push(x[i : i + chunk], t[i : i + chunk])
    return out


def test_online_windows_every_hop_and_chunking_does_not_matter():
    rng = np.random.default_rng(7)
    t, x = _signal(rng, [(20.0, 15.0), (10.0, 5.0)], seconds=5.0, n_ch=5)
    a = _stream(eng.OnlineEngagement(FS, 5), t, x, chunk=12)
    b = _stream(eng.OnlineEngagement(FS, 5), t, x, chunk=500)
    assert len(a) == len(b) == int((5.0 - 2.0) / 0.25) + 1
    assert [w.t_end for w in a] == [w.t_end for w in b]
    np.testing.assert_allclose([w.index_raw for w in a], [w.index_raw for w in b])
    assert all(w.usable and w.clean_fraction == 1.0 for w in a)
    # same numbers as the batch functions on the last window
    rel = eng.relative_band_powers(x[-512:], FS).mean(axis=0)
    assert a[-1].index_raw == pytest.approx(float(eng.engagement_index(*rel)))
    np.testing.assert_allclose([w.index_smoothed for w in a], eng.ewma(np.array([w.index_raw for w in a]), 0.9))


def test_online_beta_vs_slow_and_bad_channels():
    rng = np.random.default_rng(8)
    t, beta = _signal(rng, [(20.0, 15.0), (10.0, 4.0), (6.0, 4.0)], seconds=4.0)
    _, slow = _signal(rng, [(20.0, 4.0), (10.0, 15.0), (6.0, 15.0)], seconds=4.0)
    e_beta = [w.index_raw for w in _stream(eng.OnlineEngagement(FS, 4), t, beta)]
    e_slow = [w.index_raw for w in _stream(eng.OnlineEngagement(FS, 4), t, slow)]
    assert min(e_beta) > max(e_slow)
    bad = beta.copy()
    bad[:, :3] = 850.0  # three flat channels: only one left, fewer than 2 needed
    oe = eng.OnlineEngagement(FS, 4, channel_names=["TP9", "AF7", "AF8", "TP10"])
    res = _stream(oe, t, bad)
    assert all(w.index_raw is None and w.clean_fraction == 0.25 for w in res)
    assert "1 clean channels < 2 needed (TP9 flat, AF7 flat, AF8 flat)" == res[0].reason


def test_online_gap_restarts_and_is_reported():
    rng = np.random.default_rng(9)
    t, x = _signal(rng, [(20.0, 15.0)], seconds=6.0)
    t2 = t.copy()
    t2[768:] += 3.0  # 3 s of samples missing after 3 s
    oe = eng.OnlineEngagement(FS, 4)
    res = _stream(oe, t2, x)
    gaps = [w for w in res if w.reason.startswith("gap")]
    assert len(gaps) == 1 and gaps[0].reason == "gap 3.00 s" and gaps[0].clean_fraction == 0.0
    assert oe.gaps == [(pytest.approx(t[767]), pytest.approx(t2[768]))]
    after = [w for w in res if w.t_end > t2[768]]
    # the buffer restarted: the first window after the gap ends 2 s (one window) after it
    assert after[0].t_end - t2[768] == pytest.approx(2.0 - 1 / FS) and after[0].usable


def test_normaliser_rule():
    n = phase.EngagementNormaliser()
    assert np.isnan(n.update(0.5))  # no scale yet: no invented number
    n.fit_baseline(np.linspace(0.0, 1.0, 101))
    assert n.lo_ == pytest.approx(0.05) and n.hi_ == pytest.approx(0.95) and n.scale_from_ == "baseline"
    assert n.normalise(np.array([0.05, 0.5, 2.0])).tolist() == pytest.approx([0.0, 0.5, 1.0])
    for _ in range(200):
        n.update(3.0)  # the task's own values make the range: a constant 3 is widened, not the baseline's
    assert n.scale_from_ == "task" and (n.lo_, n.hi_) == pytest.approx((3.0 - 0.45, 3.0 + 0.45))
    with pytest.raises(ValueError, match="lo_q"):
        phase.EngagementNormaliser(lo_q=90, hi_q=10)


def test_normaliser_scales_over_the_task_when_rest_sits_far_above():
    """A resting baseline far above the task (the demo's old collapse, or a real headband): the task's
    values are spread over [0, 1] by their own range, and the baseline's position says where rest is."""
    rng = np.random.default_rng(4)
    n = phase.EngagementNormaliser().fit_baseline(rng.normal(0.78, 0.02, 40))
    turns = [rng.normal(level, 0.02, 8) for level in (0.40, 0.59, 0.48, 0.40, 0.59, 0.40, 0.48, 0.40)]
    means = np.array([n.extend(t).mean() for t in turns])
    assert means[1:].max() - means[1:].min() >= 0.5 and ((means > 0.02) & (means < 0.98)).sum() >= 4
    assert means[4] > means[6] > means[5]  # ordered like the engagement behind them
    assert n.baseline_position > 1.5  # rest lies far above the task's range (reported, not in the range)
    # the old rule (baseline in the range) would have pinned them near 0
    old = np.percentile(np.concatenate([n.baseline, n.history]), [5, 95])
    assert np.clip((np.concatenate(turns[1:]) - old[0]) / (old[1] - old[0]), 0, 1).mean() < 0.3 < means[1:].mean()


def test_normaliser_does_not_stretch_noise():
    """An unchanging engagement (5-95 % noise span ~20 % of its level, like the demo's short windows) stays near the middle."""
    rng = np.random.default_rng(5)
    n = phase.EngagementNormaliser().fit_baseline(rng.normal(0.4, 0.026, 20))
    for _ in range(25):
        v = n.extend(rng.normal(0.4, 0.026, 8))
    assert n.hi_ - n.lo_ == pytest.approx(phase.MIN_REL_SPAN * np.median(n.history))
    assert 0.25 < v.mean() < 0.75
    wide = phase.EngagementNormaliser(min_rel_span=0.0).fit_baseline([0.4] * 5)
    wide.extend(rng.normal(0.4, 0.026, 200))
    assert wide.hi_ - wide.lo_ < 0.1  # without the floor the noise alone would fill [0, 1]
    with pytest.raises(ValueError, match="min_rel_span"):
        phase.EngagementNormaliser(min_rel_span=-1)


def test_aggregate_phase_quality_and_reason():
    ws = [eng.WindowResult(0.25 * i, 1.0 + i, 1.0 + i, 1.0) for i in range(1, 9)]
    agg = phase.aggregate_phase(ws, 0.0, 2.0, 0.25)
    assert agg.index == pytest.approx(np.mean(np.arange(2, 10))) and agg.quality == 1.0
    half = [w if i % 2 else eng.WindowResult(w.t_end, None, None, 0.25, "x") for i, w in enumerate(ws)]
    agg = phase.aggregate_phase(half, 0.0, 2.0, 0.25, min_quality=0.6)
    assert agg.index is None and agg.quality == 0.5 and "50% clean" in agg.reason
    empty = phase.aggregate_phase([], 0.0, 2.0, 0.25)
    assert empty.index is None and empty.quality == 0.0 and "no EEG windows" in empty.reason


def test_summarise_phase_normalises_with_the_baseline_and_says_why_not():
    def windows(t0, values):
        return [eng.WindowResult(t0 + 0.25 * (i + 1), v, v, 1.0) for i, v in enumerate(values)]

    args = dict(hop_s=0.25, min_quality=0.5)
    n = phase.EngagementNormaliser()
    first = phase.summarise_phase(windows(0.0, [1.0, 2.0]), 0.0, 0.5, n, baseline=False, had_baseline=False, **args)
    assert first.engagement is None and first.index == 1.5 and "no baseline phase" in first.reason
    base = phase.summarise_phase(windows(1.0, np.linspace(1.0, 3.0, 8)), 1.0, 3.0, n, baseline=True,
                                 had_baseline=True, **args)
    assert n.baseline_n_ == 8 and base.engagement == pytest.approx(float(np.mean(base.normalised)))
    listen = phase.summarise_phase(windows(3.0, [3.0, 3.0]), 3.0, 3.5, n, baseline=False, had_baseline=True, **args)
    assert listen.engagement == 1.0 and listen.reason == "" and len(n.history) == 2  # baseline scale until 5
    lost = phase.summarise_phase([], 4.0, 5.0, n, baseline=False, had_baseline=True, lost_s=1.0, **args)
    assert lost.engagement is None and lost.reason.startswith("stream lost for 1.0 s of the phase (no clean signal")
    gone = phase.summarise_phase([], 5.0, 6.0, n, baseline=False, had_baseline=True, unavailable="", **args)
    assert gone.reason == "EEG unavailable: no stream"


def test_input_validation_names_the_bad_value():
    with pytest.raises(ValueError, match=r"x must be \(n_samples, n_channels\), got shape \(2, 3, 4\)"):
        eng.relative_band_powers(np.zeros((2, 3, 4)), FS)
    with pytest.raises(ValueError, match="fs must be > 0, got 0"):
        eng.relative_band_powers(np.zeros((64, 2)), 0)
    with pytest.raises(ValueError, match="at least 8 samples, got 5"):
        eng.relative_band_powers(np.zeros((5, 2)), FS)
    const = eng.relative_band_powers(np.full((256, 2), 850.0), FS)
    assert np.isnan(const).all()  # no power at all: no relative power, not zero
    oe = eng.OnlineEngagement(FS, 4)
    with pytest.raises(ValueError, match=r"samples must be \(n, 4\), got shape \(12, 5\)"):
        oe.push(np.zeros((12, 5)), np.arange(12) / FS)
    with pytest.raises(ValueError, match="11 timestamps for 12 samples"):
        oe.push(np.zeros((12, 4)), np.arange(11) / FS)
    with pytest.raises(ValueError, match="hop_s <= window_s"):
        eng.OnlineEngagement(FS, 4, window_s=1.0, hop_s=2.0)
    with pytest.raises(ValueError, match="min_clean_channels must be in 1..4, got 5"):
        eng.OnlineEngagement(FS, 4, min_clean_channels=5)
