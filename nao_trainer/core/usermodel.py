"""User models and user clusters (paper section 4.3).

Pure: no I/O. A *user model* is one session's vector ``UM = [P1..P4, E1..E4]``: the success rate
and the mean normalised engagement at each difficulty level. Sessions are grouped with K-means
(K = 3 in the paper) on the 8 raw features and projected to 2-D with metric MDS for plots.

Cluster ids are made stable (K-means labels are arbitrary): clusters are numbered 1..K by
increasing mean success rate (mean of P1..P4), ties broken by mean engagement. With the
published data this gives: id 1 = the paper's Cluster 1 (fails above level 2), id 2 = the
paper's Cluster 3, id 3 = the paper's Cluster 2 (succeeds at level 4, engagement rising).

scikit-learn is imported inside the functions that need it (importing ``sklearn.manifold`` alone
takes seconds).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nao_trainer.errors import DataError
from nao_trainer.core.task import LEVELS

FEATURE_NAMES: tuple[str, ...] = ("p1", "p2", "p3", "p4", "e1", "e2", "e3", "e4")


@dataclass(frozen=True)
class UserModels:
    """One row of ``[P1..P4, E1..E4]`` per session (``features[i]`` belongs to ``sessions[i]``).

    ``missing[i, j]`` marks a level the session never played; such cells hold the column mean
    over the sessions that did play it, so clustering sees a neutral value rather than a hole.
    """

    sessions: tuple[str, ...]
    features: np.ndarray  # (n, 8)
    missing: np.ndarray  # (n, 8) bool

    def row(self, session: str) -> np.ndarray:
        return self.features[self.sessions.index(session)]


def user_models(
    session: Sequence[str] | np.ndarray,
    level: np.ndarray,
    success: np.ndarray,
    engagement: np.ndarray,
) -> UserModels:
    """Compute the user models from per-turn columns (one entry per turn).

    ``engagement`` may hold NaN for turns without a usable EEG estimate; they are left out of
    the level's mean engagement but still count for its success rate.
    """
    session = np.asarray(session, dtype=str)
    level = np.asarray(level, dtype=int)
    success = np.asarray(success, dtype=float)
    engagement = np.asarray(engagement, dtype=float)
    n = len(session)
    if not (len(level) == len(success) == len(engagement) == n):
        raise ValueError("session, level, success and engagement must have the same length")
    bad = ~np.isin(level, LEVELS)
    if bad.any():
        raise ValueError(f"level must be in 1..4, got {int(level[bad][0])}")
    names, idx = np.unique(session, return_inverse=True)
    m = len(names)
    # Vectorised group sums over (session, level) cells.
    cell = idx * 4 + (level - 1)
    turns = np.bincount(cell, minlength=4 * m).reshape(m, 4)
    wins = np.bincount(cell, weights=success, minlength=4 * m).reshape(m, 4)
    has_e = np.isfinite(engagement)
    e_n = np.bincount(cell[has_e], minlength=4 * m).reshape(m, 4)
    e_sum = np.bincount(cell[has_e], weights=engagement[has_e], minlength=4 * m).reshape(m, 4)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = wins / turns
        e = e_sum / e_n
    features = np.hstack([p, e])
    missing = ~np.isfinite(features)
    if missing.all(axis=0).any():
        col = FEATURE_NAMES[int(np.flatnonzero(missing.all(axis=0))[0])]
        raise DataError(f"no session has data for user-model feature {col}: cannot build user models")
    col_mean = np.nanmean(np.where(missing, np.nan, features), axis=0)
    features = np.where(missing, col_mean, features)
    return UserModels(tuple(names.tolist()), features, missing)


class TooFewSessions(DataError):
    """Too few sessions (or distinct user models) for ``k`` clusters; the message names the value ``k``
    (a command adds its own option with ``naming``)."""

    def __init__(self, sessions: int, distinct: int, k: int, k_name: str = "k") -> None:
        self.sessions, self.distinct, self.k = sessions, distinct, k
        super().__init__(f"{sessions} sessions ({distinct} distinct user models) are too few for K={k} clusters: "
                         f"import at least {2 * k} sessions or lower {k_name}")

    def naming(self, k_name: str) -> "TooFewSessions":
        """The same error, naming the option that sets ``k`` (e.g. ``--k``)."""
        return TooFewSessions(self.sessions, self.distinct, self.k, k_name)


@dataclass(frozen=True)
class Clustering:
    """K-means result with stable ids. ``labels[i]`` in 1..K is the cluster of session i."""

    labels: np.ndarray  # (n,) ints 1..K
    centers: np.ndarray  # (K, 8); centers[k-1] is cluster k's mean user model
    sizes: np.ndarray  # (K,)
    inertia: float

    @property
    def k(self) -> int:
        return len(self.sizes)


def cluster_users(features: np.ndarray, k: int = 3, n_init: int = 200, seed: int = 0) -> Clustering:
    """K-means on the raw user-model features with many restarts (best inertia wins).

    Few restarts miss the best-inertia partition of the published data; 200 restarts of 50
    points cost well under a second. Raises DataError when there are too few sessions.
    """
    from sklearn.cluster import KMeans

    x = np.asarray(features, dtype=float)
    if x.ndim != 2 or not np.all(np.isfinite(x)):
        raise ValueError("features must be a finite 2-D array (sessions x features)")
    if not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"k must be a positive integer, got {k!r}")
    n_distinct = len(np.unique(x, axis=0))
    if len(x) < 2 * k or n_distinct < k:
        raise TooFewSessions(len(x), n_distinct, k)
    km = KMeans(n_clusters=k, n_init=n_init, random_state=seed).fit(x)
    raw = km.labels_
    centers = np.array([x[raw == c].mean(axis=0) for c in range(k)])
    order = np.lexsort((centers[:, 4:].mean(axis=1), centers[:, :4].mean(axis=1)))
    rank = np.empty(k, dtype=int)
    rank[order] = np.arange(k)
    labels = rank[raw] + 1
    return Clustering(
        labels=labels,
        centers=centers[order],
        sizes=np.bincount(labels - 1, minlength=k),
        inertia=float(km.inertia_),
    )


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """True when two labelings group the items identically (up to renaming the labels)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return False
    pairs = np.unique(np.stack([a, b]), axis=1)
    return len(pairs.T) == len(np.unique(a)) == len(np.unique(b))


def mds_projection(features: np.ndarray, seed: int = 0) -> np.ndarray:
    """2-D metric MDS of the user models (Euclidean distances), for the scatter of Figure 5.

    scikit-learn 1.9 changed MDS: ``metric_mds=True`` selects metric MDS and ``init`` must be
    named; the classical-MDS start makes the result deterministic. Older versions take
    ``metric=True`` and a seeded random start.
    """
    from sklearn.manifold import MDS

    x = np.asarray(features, dtype=float)
    if len(x) < 3:
        return np.column_stack([np.arange(len(x), dtype=float), np.zeros(len(x))])
    try:
        mds = MDS(n_components=2, metric_mds=True, init="classical_mds", n_init=1, random_state=seed)
    except TypeError:  # scikit-learn < 1.9
        mds = MDS(n_components=2, metric=True, n_init=4, random_state=seed)
    return np.asarray(mds.fit_transform(x), dtype=float)
