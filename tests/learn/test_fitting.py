"""Per-cluster simulators: valid tables, faithful to the data, reproducible, stored as plain JSON."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from _usermodels_data import import_published
from nao_trainer.learn import artifacts
from nao_trainer.core import mdp
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import DataError
from nao_trainer.learn.fitting import EngagementModel, FitOptions, PerformanceModel, Turns, fit_dataset, time_quantiles


@pytest.fixture(scope="module")
def data(dataset_root, tmp_path_factory):
    imported = import_published(dataset_root, tmp_path_factory)
    return imported.table, Turns.from_columns(imported.table.columns)


@pytest.fixture(scope="module")
def fit(data):
    return fit_dataset(data[1], FitOptions(), metadata={"compat": "authors2018"})


def test_simulated_level_success_is_within_003_of_the_data(fit, data):
    turns = data[1]
    by_session = dict(zip(fit.user_models.sessions, fit.clustering.labels))
    label = np.array([by_session[s] for s in turns.session])
    for c in fit.clusters:
        sub = turns.subset(label == c.id)
        # the simulator's P on the cluster's observed state visits, per level, against the data
        p = c.simulator.p_success[sub.state]
        for lv in (1, 2, 3, 4):
            m = sub.level == lv
            assert abs(p[m].mean() - sub.success[m].mean()) <= 0.03, (c.id, lv)
        np.testing.assert_allclose(c.simulated_level_success, [p[sub.level == lv].mean() for lv in (1, 2, 3, 4)])


def test_tables_are_valid_and_cover_every_state(fit):
    for c in fit.clusters:
        sim = c.simulator
        assert sim.p_success.shape == (108,) and sim.engagement.shape == (108, 2)
        assert 0 <= sim.p_success.min() and sim.p_success.max() <= 1
        assert 0 <= sim.engagement.min() and sim.engagement.max() <= 1
        assert np.all(np.diff(sim.reaction_quantiles, axis=1) >= 0)
        assert c.observed_states < 108  # most states never occur: the regression fills them
        assert np.isfinite([c.rmse_performance, c.rmse_engagement, c.cv_rmse_performance, c.cv_rmse_engagement]).all()
        assert c.rmse_engagement < 0.12 and c.rmse_performance < 0.2
        assert sim.metadata["paper_cluster"] in (1, 2, 3)
    # the paper's cluster 2 succeeds at level 4 far more often than its cluster 1
    by_paper = {c.simulator.metadata["paper_cluster"]: c for c in fit.clusters}
    assert by_paper[2].p[3] > 0.4 > 0.1 > by_paper[1].p[3]


def test_fit_is_reproducible(fit, data):
    again = fit_dataset(data[1], FitOptions(), metadata={"compat": "authors2018"})
    assert [c.simulator.fingerprint() for c in again.clusters] == [c.simulator.fingerprint() for c in fit.clusters]
    assert [c.cv_rmse_performance for c in again.clusters] == [c.cv_rmse_performance for c in fit.clusters]


def test_performance_model_uses_data_where_observed_and_stays_monotone():
    rng = np.random.default_rng(0)
    true = np.array([0.95, 0.8, 0.5, 0.2])
    states = np.array([mdp.encode(l, 0, 0) for l in rng.choice([3, 5, 7, 9], 800)])
    success = rng.random(800) < true[mdp.LEVEL[states] - 1]
    pm = PerformanceModel(prior_strength=0.0).fit(states, success)
    seen = pm.counts_ > 0
    np.testing.assert_allclose(pm.table_[seen], pm.mle_[seen])
    assert pm.monotone_applied_
    assert np.all(np.diff(pm.regression_.reshape(4, 27), axis=0) <= 1e-12)  # non-increasing in length
    shrunk = PerformanceModel(prior_strength=1000.0).fit(states, success)
    np.testing.assert_allclose(shrunk.table_[seen], shrunk.regression_[seen], atol=0.05)
    with pytest.raises(ValueError, match="prior_strength must be a number >= 0, got -1"):
        PerformanceModel(prior_strength=-1).fit(states, success)
    with pytest.raises(ValueError, match="turn-state index must be in 0..107, got 200"):
        PerformanceModel().fit(np.array([1, 200]), np.array([1, 0]))


def test_engagement_model_is_clipped_to_unit_interval():
    states = np.array([0, 0, 30, 30, 60, 60])
    em = EngagementModel().fit(states, np.array([1, 0, 1, 0, 1, 1]), np.array([1.3, 1.2, -0.4, -0.2, 0.5, np.nan]))
    assert em.table_.min() >= 0 and em.table_.max() <= 1
    assert em.counts_[60, 1] == 1  # the NaN turn is left out
    with pytest.raises(DataError, match="no turn has an engagement value"):
        EngagementModel().fit(states, np.ones(6), np.full(6, np.nan))


def test_time_quantiles_fall_back_to_all_levels():
    q = time_quantiles(np.array([1, 1, 2, 2]), np.array([1.0, 2.0, 3.0, 4.0]), "reaction time")
    assert q.shape == (4, 21) and q[0, 0] == 1 and q[0, -1] == 2 and q[3, 0] == 1 and q[3, -1] == 4
    with pytest.raises(DataError, match="no valid reaction time"):
        time_quantiles(np.array([1]), np.array([np.nan]), "reaction time")


# -- artifacts ---------------------------------------------------------------------------------------


def test_artifacts_round_trip_without_the_dataset(fit, tmp_path):
    rows = [c.summary() for c in fit.clusters]
    artifacts.save_models(tmp_path, [c.simulator for c in fit.clusters], rows, {"k": 3})
    assert artifacts.available_models(tmp_path) == ["1", "2", "3"]
    for c in fit.clusters:
        for spec in (str(c.id), f"cluster-{c.id}"):
            sim = artifacts.load_simulator(spec, tmp_path)
            assert sim.fingerprint() == c.simulator.fingerprint()
            np.testing.assert_array_equal(sim.p_success, c.simulator.p_success)
    by_path = artifacts.load_simulator(str(tmp_path / "cluster_2.json"))
    assert by_path.name == "cluster-2"
    assert b"pickle" not in (tmp_path / "cluster_2.json").read_bytes()
    with pytest.raises(DataError, match=r"unknown user model '9': .* has clusters 1, 2, 3"):
        artifacts.load_simulator("9", tmp_path)


def test_damaged_artifacts_are_refused_with_the_file_named(fit, tmp_path):
    artifacts.save_models(tmp_path, [fit.clusters[0].simulator], [fit.clusters[0].summary()], {})
    path = tmp_path / "cluster_1.json"
    data = json.loads(path.read_text())
    data["p_success"][3] = 0.123
    path.write_text(json.dumps(data))
    with pytest.raises(DataError, match="cluster_1.json: tables do not match their fingerprint"):
        artifacts.load_simulator("1", tmp_path)
    path.write_text("{\n  \"format\": ")
    with pytest.raises(DataError, match=r"cluster_1.json:2: not valid JSON"):
        artifacts.load_simulator("1", tmp_path)
    with pytest.raises(DataError, match="no user models here"):
        artifacts.load_simulator("1", tmp_path / "empty")


def test_shipped_models_load_and_match_a_fresh_fit(fit, data):
    manifest = artifacts.load_manifest(artifacts.DEFAULT_MODELS_DIR)
    assert manifest["compat"] == "authors2018" and manifest["k"] == 3
    assert manifest["dataset_fingerprint"] == data[0].fingerprint()
    for c in fit.clusters:
        shipped = artifacts.load_simulator(str(c.id), artifacts.DEFAULT_MODELS_DIR)
        assert isinstance(shipped, UserSimulator)
        np.testing.assert_allclose(shipped.p_success, c.simulator.p_success, atol=1e-6)
        np.testing.assert_allclose(shipped.engagement, c.simulator.engagement, atol=1e-6)


def test_shipped_model_folders_record_the_fingerprint_the_importer_gives(dataset_root, tmp_path_factory, data):
    """Each shipped folder of fitted models names the turn table it was fitted from. When the importer (or an
    engagement rule behind it) changes that table, this fails until the folder is refitted, so a stale
    ``dataset_fingerprint`` cannot ship again (issue 22)."""
    fingerprints = {"authors2018": data[0].fingerprint()}
    fingerprints[None] = import_published(dataset_root, tmp_path_factory, compat=None).table.fingerprint()
    for folder in (artifacts.DEFAULT_MODELS_DIR, artifacts.DEFAULT_MODELS_DIR.parent / "models-tested"):
        manifest = artifacts.load_manifest(folder)
        want = fingerprints[manifest["compat"]]
        fix = f"{folder} is stale: refit it as analysis/make_results.sh does (nao-trainer fit DATA --out ...)"
        assert manifest["dataset_fingerprint"] == want, fix
        for spec in artifacts.available_models(folder):
            assert artifacts.load_simulator(spec, folder).metadata["dataset_fingerprint"] == want, fix


def test_unwritable_output_is_a_one_line_user_error(fit, tmp_path):
    from nao_trainer.errors import UserError

    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(UserError, match="cannot write the user models .*choose another --out"):
        artifacts.save_models(blocker / "models", [fit.clusters[0].simulator], [fit.clusters[0].summary()], {})


def test_fingerprint_ignores_float_noise_but_not_a_real_change():
    sim = UserSimulator.from_level_rates("x", [0.9, 0.7, 0.4, 0.1], [0.3, 0.4, 0.5, 0.6])

    def variant(p_success=None, engagement=None):
        return UserSimulator("x", sim.p_success if p_success is None else p_success,
                             sim.engagement if engagement is None else engagement,
                             sim.reaction_quantiles, sim.completion_quantiles)

    noisy = variant(p_success=sim.p_success * (1 + 3e-15), engagement=np.nextafter(sim.engagement, 1.0))
    assert not np.array_equal(noisy.p_success, sim.p_success)
    assert noisy.fingerprint() == sim.fingerprint()
    changed = sim.p_success.copy()
    changed[5] += 1e-6
    assert variant(p_success=changed).fingerprint() != sim.fingerprint()
    near_zero = sim.engagement.copy()
    near_zero[0] = [0.0, 0.0]
    tiny = near_zero.copy()
    tiny[0] = [1e-17, 3e-16]
    assert variant(engagement=near_zero).fingerprint() == variant(engagement=tiny).fingerprint()


def test_too_few_engagement_turns_in_a_cluster_is_a_one_line_user_error():
    """A tiny study fitted with the tested-effects models: a DataError the CLI prints in one line, not a traceback."""
    import numpy as np

    from nao_trainer.errors import UserError
    from nao_trainer.learn.effects import TestedEngagementModel

    states = np.array([30, 31, 32, 33, 34])
    with pytest.raises(UserError, match=r"only 5 turns with engagement.*smaller --k"):
        TestedEngagementModel().fit(states, np.ones(5), np.full(5, 0.3))


@pytest.mark.parametrize("value", ["abc", [0.5, 0.5], {"x": 1}])
def test_a_user_model_with_text_in_its_tables_names_the_file(tmp_path, value):
    """Issue 17: a string in p_success gave a message without the file name. core names the values;
    the loader adds the fix (issue 16: no command words in core/)."""
    shipped = Path(__file__).resolve().parents[2] / "sim" / "participants" / "level2.json"
    data = json.loads(shipped.read_text())
    data["p_success"][3] = value
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DataError) as err:
        artifacts.load_simulator_file(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and "must hold numbers" in msg and "\n" not in msg
    assert msg.endswith("refit it with `nao-trainer fit`")
    with pytest.raises(ValueError) as core_err:
        UserSimulator.from_dict(data, source=str(path))
    assert "must hold numbers" in str(core_err.value) and "nao-trainer" not in str(core_err.value)
