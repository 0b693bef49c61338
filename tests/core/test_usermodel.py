"""User models [P1..P4, E1..E4], K-means with stable ids and MDS: reproduce the authors' tables."""
from __future__ import annotations

import numpy as np
import pytest

from _usermodels_data import import_published
from nao_trainer.core.usermodel import cluster_users, mds_projection, same_partition, user_models
from nao_trainer.errors import DataError


def _read_models(path, with_cluster: bool) -> dict[str, tuple[int, np.ndarray]]:
    lines = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
    if with_cluster:
        return {f[0]: (int(f[1]), np.array(f[2:], float)) for f in lines[1:]}
    return {f[0]: (-1, np.array(f[1:], float)) for f in lines}


@pytest.fixture(scope="module")
def models(dataset_root, tmp_path_factory):
    t = import_published(dataset_root, tmp_path_factory).table
    return user_models(t["session"], t["level"], t["success"], t["engagement"])


def test_user_models_equal_the_authors(models, derived_dir):
    ref = _read_models(derived_dir / "user_models.csv", with_cluster=False)
    assert set(models.sessions) == set(ref)
    for sid, (_, row) in ref.items():
        np.testing.assert_allclose(models.row(sid), row, atol=1e-6, err_msg=sid)
    assert not models.missing.any()


def test_kmeans_gives_the_authors_partition(models, derived_dir):
    ref = _read_models(derived_dir / "user_models_both.csv", with_cluster=True)
    clustering = cluster_users(models.features, k=3)
    authors = np.array([ref[s][0] for s in models.sessions])
    assert same_partition(clustering.labels, authors)
    assert sorted(clustering.sizes.tolist()) == [13, 16, 21]


def test_cluster_ids_are_stable_and_ordered_by_mean_success(models):
    a = cluster_users(models.features, k=3, seed=0)
    order = np.random.default_rng(5).permutation(len(models.sessions))
    b = cluster_users(models.features[order], k=3, seed=11)
    assert np.array_equal(a.labels[order], b.labels)  # same ids whatever the row order or seed
    assert np.all(np.diff(a.centers[:, :4].mean(axis=1)) > 0)
    for k in (1, 2, 3):
        np.testing.assert_allclose(a.centers[k - 1], models.features[a.labels == k].mean(axis=0))


def test_too_few_sessions_for_k_is_a_clear_error(models):
    with pytest.raises(DataError, match=r"4 sessions .* too few for K=3 clusters: import at least 6 sessions or lower k$"):
        cluster_users(models.features[:4], k=3)
    with pytest.raises(ValueError, match="k must be a positive integer, got 0"):
        cluster_users(models.features, k=0)


def test_missing_level_is_marked_and_imputed():
    session = ["a"] * 4 + ["b"] * 3
    level = [1, 2, 2, 3, 1, 2, 4]
    success = [1, 0, 1, 1, 1, 1, 0]
    engagement = [0.2, 0.4, np.nan, 0.7, 0.3, 0.5, 0.9]  # a turn without EEG still counts for P
    um = user_models(session, level, success, engagement)
    assert um.sessions == ("a", "b")
    np.testing.assert_allclose(um.features[0], [1, 0.5, 1, 0, 0.2, 0.4, 0.7, 0.9])  # level 4 from "b"
    np.testing.assert_allclose(um.features[1], [1, 1, 1, 0, 0.3, 0.5, 0.7, 0.9])  # level 3 from "a"
    assert um.missing[0].tolist() == [False, False, False, True, False, False, False, True]
    with pytest.raises(DataError, match="no session has data for user-model feature p2"):
        user_models(["a"], [1], [1], [0.1])
    with pytest.raises(ValueError, match="level must be in 1..4, got 5"):
        user_models(["a"], [5], [1], [0.1])


def test_same_partition_detects_differences():
    assert same_partition([1, 1, 2, 3], [3, 3, 1, 2])
    assert not same_partition([1, 1, 2, 3], [1, 2, 2, 3])
    assert not same_partition([1, 1], [1, 1, 1])


def test_mds_is_two_d_and_deterministic(models):
    a = mds_projection(models.features, seed=0)
    b = mds_projection(models.features, seed=0)
    assert a.shape == (len(models.sessions), 2) and np.array_equal(a, b)
    d_feat = np.linalg.norm(models.features[:, None] - models.features[None], axis=2)
    d_mds = np.linalg.norm(a[:, None] - a[None], axis=2)
    assert np.corrcoef(d_feat.ravel(), d_mds.ravel())[0, 1] > 0.8  # distances are preserved
