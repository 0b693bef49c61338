"""Per-cluster user simulators fitted from data (paper section 5.1).

For each cluster of sessions this builds a :class:`~nao_trainer.core.simulation.UserSimulator`:

* **performance** ``P(success | state)``: maximum-likelihood rates ``N(success, s) / N(s)`` where the
  data has the state, and a regularised logistic regression over state features for all 108
  states. The paper used a small neural network; with 25 turns x ~15 sessions per cluster and
  only ~48 observed states, a linear-logit model generalises more predictably. Where the data's
  per-level success rates fall with length, the regression's table is made non-increasing in
  length (pool-adjacent-violators per (feedback, previous result)). The two are combined by
  shrinking each observed MLE towards the regression with ``prior_strength`` pseudo-turns.
* **engagement** ``Phi(state, outcome)``: scikit-learn's SVR (as the paper says) on the mean
  normalised engagement of each observed (state, outcome), clipped to [0, 1].
* **times**: the cluster's per-level empirical quantiles of reaction and completion time.

Reported per cluster: training RMSE (the simulator's P table vs the per-state MLE, also the
regression alone vs the MLE; the SVR vs the per-(state, outcome) means; unweighted over states)
and a cross-validated RMSE (the same quantities with models fitted on the other session folds,
errors weighted by the held-out turn counts).

scikit-learn is imported inside the functions.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.core.simulation import TIME_QUANTILES, UserSimulator
from nao_trainer.core.usermodel import Clustering, UserModels, cluster_users, user_models
from nao_trainer.errors import DataError
from nao_trainer.learn.effects import TestedEngagementModel, TestedPerformanceModel, TooFewTurns, effect_report

#: How states are turned into regression inputs (stored in the artifacts' metadata).
FEATURE_ENCODING = (
    "level one-hot (4), robot feedback one-hot (none/encouraging/challenging), "
    "previous result: failed flag, succeeded flag, |previous score|/4 (first turn: all 0); "
    "engagement model adds the outcome (0/1)"
)


def state_features(states: np.ndarray) -> np.ndarray:
    """Regression inputs of turn states (see ``FEATURE_ENCODING``), shape (n, 10)."""
    s = np.asarray(states, dtype=int)
    if s.size and (s.min() < 0 or s.max() >= mdp.N_TURN_STATES):
        raise ValueError(f"turn-state indices must be in 0..{mdp.N_TURN_STATES - 1}")
    prev = mdp.PREVIOUS[s]
    x = np.zeros((len(s), 10))
    x[np.arange(len(s)), mdp.LEVEL[s] - 1] = 1.0
    x[np.arange(len(s)), 4 + mdp.FEEDBACK[s]] = 1.0
    x[:, 7] = prev < 0
    x[:, 8] = prev > 0
    x[:, 9] = np.abs(prev) / 4.0
    return x


ALL_STATES = np.arange(mdp.N_TURN_STATES)


def _check_turns(states: np.ndarray, success: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    states = np.asarray(states, dtype=int)
    success = np.asarray(success)
    if states.shape != success.shape or states.ndim != 1:
        raise ValueError(f"states and success must be 1-D of equal length, got {states.shape} and {success.shape}")
    if len(states) == 0:
        raise ValueError("no turns to fit")
    if states.min() < 0 or states.max() >= mdp.N_TURN_STATES:
        bad = states[(states < 0) | (states >= mdp.N_TURN_STATES)][0]
        raise ValueError(f"turn-state index must be in 0..{mdp.N_TURN_STATES - 1}, got {bad}")
    return states, success.astype(float)


def _pav_non_increasing(y: np.ndarray) -> np.ndarray:
    """Least-squares non-increasing fit of a short vector (pool adjacent violators)."""
    blocks: list[list[float]] = []  # [sum, count]
    for v in y:
        blocks.append([float(v), 1.0])
        while len(blocks) > 1 and blocks[-2][0] / blocks[-2][1] < blocks[-1][0] / blocks[-1][1]:
            s, c = blocks.pop()
            blocks[-1][0] += s
            blocks[-1][1] += c
    return np.concatenate([np.full(int(c), s / c) for s, c in blocks])


class PerformanceModel:
    """P(success | state) over all 108 turn states (scikit-learn style: ``fit`` returns self).

    Parameters: ``prior_strength`` pseudo-turns of the regression added to each observed state's
    counts; ``C`` the inverse L2 strength of the logistic regression; ``monotone`` make the
    regression non-increasing in length when the data's per-level rates are.
    """

    def __init__(self, prior_strength: float = 2.0, C: float = 1.0, monotone: bool = True):
        self.prior_strength = prior_strength
        self.C = C
        self.monotone = monotone

    def fit(self, states: np.ndarray, success: np.ndarray) -> "PerformanceModel":
        from sklearn.linear_model import LogisticRegression

        if not (isinstance(self.prior_strength, (int, float)) and self.prior_strength >= 0):
            raise ValueError(f"prior_strength must be a number >= 0, got {self.prior_strength!r}")
        if not (isinstance(self.C, (int, float)) and self.C > 0):
            raise ValueError(f"C must be a number > 0, got {self.C!r}")
        states, y = _check_turns(states, success)
        self.counts_ = np.bincount(states, minlength=mdp.N_TURN_STATES).astype(float)
        self.wins_ = np.bincount(states, weights=y, minlength=mdp.N_TURN_STATES)
        seen = self.counts_ > 0
        self.mle_ = np.full(mdp.N_TURN_STATES, np.nan)
        self.mle_[seen] = self.wins_[seen] / self.counts_[seen]
        if np.all(y == y[0]):  # one class only: the regression has nothing to separate
            reg = np.full(mdp.N_TURN_STATES, y[0])
        else:
            lr = LogisticRegression(C=self.C, max_iter=1000).fit(state_features(states), y.astype(int))
            reg = lr.predict_proba(state_features(ALL_STATES))[:, 1]
        level_rates = np.array([y[mdp.LEVEL[states] == lv].mean() if np.any(mdp.LEVEL[states] == lv) else np.nan
                                for lv in (1, 2, 3, 4)])
        rates = level_rates[np.isfinite(level_rates)]
        self.monotone_applied_ = bool(self.monotone and np.all(np.diff(rates) <= 1e-12))
        if self.monotone_applied_:
            grid = reg.reshape(4, 27)  # [level, feedback*9 + previous]
            reg = np.column_stack([_pav_non_increasing(grid[:, j]) for j in range(27)]).reshape(-1)
        self.regression_ = reg
        k = float(self.prior_strength)
        self.table_ = (self.wins_ + k * reg) / (self.counts_ + k) if k > 0 else np.where(seen, self.mle_, reg)
        self.table_ = np.clip(self.table_, 0.0, 1.0)
        # Training errors against the observed per-state MLE (unweighted over states, as the paper).
        self.rmse_ = float(np.sqrt(np.mean((self.table_[seen] - self.mle_[seen]) ** 2)))
        self.rmse_regression_ = float(np.sqrt(np.mean((reg[seen] - self.mle_[seen]) ** 2)))
        return self

    def predict(self, states: np.ndarray) -> np.ndarray:
        return self.table_[np.asarray(states, dtype=int)]


class EngagementModel:
    """Phi(state, outcome) in [0, 1] by SVR on per-(state, outcome) mean engagement (paper 5.1).

    Turns whose engagement is NaN (no usable EEG) are left out. Parameters go to ``sklearn.svm.SVR``.
    """

    def __init__(self, C: float = 1.0, epsilon: float = 0.02, gamma: str | float = "scale"):
        self.C = C
        self.epsilon = epsilon
        self.gamma = gamma

    def fit(self, states: np.ndarray, success: np.ndarray, engagement: np.ndarray) -> "EngagementModel":
        from sklearn.svm import SVR

        states, y = _check_turns(states, success)
        e = np.asarray(engagement, dtype=float)
        if e.shape != states.shape:
            raise ValueError(f"engagement must have one value per turn, got shape {e.shape}")
        ok = np.isfinite(e)
        if not ok.any():
            raise DataError("no turn has an engagement value: cannot fit the engagement model")
        cell = states[ok] * 2 + y[ok].astype(int)
        n = np.bincount(cell, minlength=2 * mdp.N_TURN_STATES).astype(float)
        total = np.bincount(cell, weights=e[ok], minlength=2 * mdp.N_TURN_STATES)
        seen = np.flatnonzero(n > 0)
        self.counts_ = n.reshape(-1, 2)
        self.means_ = np.full(2 * mdp.N_TURN_STATES, np.nan)
        self.means_[seen] = total[seen] / n[seen]
        self.means_ = self.means_.reshape(-1, 2)
        x_seen = _engagement_features(seen)
        if len(seen) >= 2:
            svr = SVR(C=self.C, epsilon=self.epsilon, gamma=self.gamma).fit(x_seen, self.means_.reshape(-1)[seen])
            table = svr.predict(_engagement_features(np.arange(2 * mdp.N_TURN_STATES)))
        else:
            table = np.full(2 * mdp.N_TURN_STATES, self.means_.reshape(-1)[seen[0]])
        self.table_ = np.clip(table, 0.0, 1.0).reshape(-1, 2)
        self.rmse_ = float(np.sqrt(np.mean((self.table_.reshape(-1)[seen] - self.means_.reshape(-1)[seen]) ** 2)))
        return self

    def predict(self, states: np.ndarray, success: np.ndarray) -> np.ndarray:
        return self.table_[np.asarray(states, dtype=int), np.asarray(success, dtype=int)]


def _engagement_features(cells: np.ndarray) -> np.ndarray:
    states, outcome = np.divmod(np.asarray(cells, dtype=int), 2)
    return np.column_stack([state_features(states), outcome])


def time_quantiles(level: np.ndarray, seconds: np.ndarray, what: str) -> np.ndarray:
    """Per-level quantiles (4, len(TIME_QUANTILES)); a level without data uses all levels' data."""
    t = np.asarray(seconds, dtype=float)
    lv = np.asarray(level, dtype=int)
    ok = np.isfinite(t) & (t >= 0)
    if not ok.any():
        raise DataError(f"no valid {what} in the data: cannot fit time distributions")
    pooled = np.quantile(t[ok], TIME_QUANTILES)
    rows = [np.quantile(t[ok & (lv == l)], TIME_QUANTILES) if np.any(ok & (lv == l)) else pooled for l in (1, 2, 3, 4)]
    return np.maximum.accumulate(np.array(rows), axis=1)


# ------------------------------------------------------------------------------------------------
# Turn data and whole-dataset fitting
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Turns:
    """The per-turn columns fitting needs (a view of the importer's turn table)."""

    session: np.ndarray  # str
    state: np.ndarray  # int, turn-state index
    success: np.ndarray  # bool
    engagement: np.ndarray  # float, normalised; NaN when unknown
    reaction_time: np.ndarray  # float seconds
    completion_time: np.ndarray  # float seconds

    @property
    def level(self) -> np.ndarray:
        return mdp.LEVEL[self.state]

    @classmethod
    def from_columns(cls, cols: Any) -> "Turns":
        """From a mapping of columns such as ``data.turn_table.TurnTable`` (names as its CSV header)."""
        return cls(
            session=np.asarray(cols["session"], dtype=str),
            state=np.asarray(cols["state"], dtype=int),
            success=np.asarray(cols["success"], dtype=int).astype(bool),
            engagement=np.asarray(cols["engagement"], dtype=float),
            reaction_time=np.asarray(cols["reaction_time"], dtype=float),
            completion_time=np.asarray(cols["completion_time"], dtype=float),
        )

    def subset(self, mask: np.ndarray) -> "Turns":
        return Turns(*(getattr(self, f)[mask] for f in self.__dataclass_fields__))


@dataclass
class ClusterFit:
    """One cluster's simulator and its fit quality."""

    id: int
    sessions: tuple[str, ...]
    simulator: UserSimulator
    p: np.ndarray  # (4,) cluster mean success per level (mean of its user models)
    e: np.ndarray  # (4,) cluster mean engagement per level
    rmse_performance: float
    rmse_performance_regression: float
    rmse_engagement: float
    cv_rmse_performance: float
    cv_rmse_engagement: float
    data_level_success: np.ndarray  # (4,) turn-weighted success per level in the data
    simulated_level_success: np.ndarray  # (4,) expected success per level on the data's state visits
    observed_states: int

    def summary(self) -> dict[str, Any]:
        """The JSON row of ``nao-trainer fit --json`` (null where a value does not exist, e.g. CV of one session)."""
        return {
            "id": self.id,
            "name": self.simulator.name,
            "size": len(self.sessions),
            "p": [_num(v) for v in self.p],
            "e": [_num(v) for v in self.e],
            "rmse_performance": _num(self.rmse_performance),
            "rmse_performance_regression": _num(self.rmse_performance_regression),
            "rmse_engagement": _num(self.rmse_engagement),
            "cv_rmse_performance": _num(self.cv_rmse_performance),
            "cv_rmse_engagement": _num(self.cv_rmse_engagement),
            "data_level_success": [_num(v) for v in self.data_level_success],
            "simulated_level_success": [_num(v) for v in self.simulated_level_success],
            "observed_states": self.observed_states,
            "paper_cluster": self.simulator.metadata.get("paper_cluster"),
            "fingerprint": self.simulator.fingerprint(),
            "sessions": list(self.sessions),
        }


def _num(value: float) -> float | None:
    """A JSON number rounded to 6 decimals, or None for NaN/infinity (not JSON)."""
    value = float(value)
    return round(value, 6) if np.isfinite(value) else None


@dataclass
class FitOptions:
    """Knobs of ``fit_dataset`` (defaults are what the shipped models use)."""

    k: int = 3
    seed: int = 0
    n_init: int = 200
    cv_folds: int = 5
    prior_strength: float = 2.0
    logistic_C: float = 1.0
    svr_C: float = 1.0
    svr_epsilon: float = 0.02


@dataclass
class FitResult:
    user_models: UserModels
    clustering: Clustering
    clusters: list[ClusterFit]
    options: FitOptions
    metadata: dict[str, Any] = field(default_factory=dict)


def _level_success(turns: Turns, p: np.ndarray | None = None) -> np.ndarray:
    vals = turns.success.astype(float) if p is None else p[turns.state]
    lv = turns.level
    return np.array([vals[lv == l].mean() if np.any(lv == l) else np.nan for l in (1, 2, 3, 4)])


def _session_folds(sessions: np.ndarray, folds: int, rng: np.random.Generator) -> list[np.ndarray]:
    names = np.unique(sessions)
    order = rng.permutation(len(names))
    return [np.isin(sessions, names[order[i::folds]]) for i in range(min(folds, len(names)))]


def _fit_tables(turns: Turns, options: FitOptions, tested: bool) -> tuple[np.ndarray, np.ndarray, Any, Any]:
    """(P table, engagement table, performance model, engagement model) of the chosen fit."""
    if tested:
        pm = TestedPerformanceModel().fit(turns.state, turns.success)
        em = TestedEngagementModel().fit(turns.state, turns.success, turns.engagement)
    else:
        pm = PerformanceModel(options.prior_strength, options.logistic_C).fit(turns.state, turns.success)
        em = EngagementModel(options.svr_C, options.svr_epsilon).fit(turns.state, turns.success, turns.engagement)
    return pm.table_, em.table_, pm, em


def cross_validate(turns: Turns, options: FitOptions, rng: np.random.Generator,
                   tested: bool = False) -> tuple[float, float]:
    """(performance, engagement) RMSE of models fitted on the other session folds.

    Performance: fitted P(s) vs the held-out fold's per-state success rate; engagement: fitted
    Phi(s, o) vs the held-out per-(state, outcome) mean; both weighted by held-out turn counts.
    NaN when the cluster has fewer than 2 sessions.
    """
    folds = _session_folds(turns.session, options.cv_folds, rng)
    if len(folds) < 2:
        return float("nan"), float("nan")
    perf_sq = perf_n = eng_sq = eng_n = 0.0
    for test in folds:
        train, held = turns.subset(~test), turns.subset(test)
        p_table = (_fit_tables(train, options, True)[0] if tested else
                   PerformanceModel(options.prior_strength, options.logistic_C).fit(train.state, train.success).table_)
        held_pm = PerformanceModel(0.0).fit(held.state, held.success)
        seen = held_pm.counts_ > 0
        perf_sq += float(np.sum(held_pm.counts_[seen] * (p_table[seen] - held_pm.mle_[seen]) ** 2))
        perf_n += float(held_pm.counts_[seen].sum())
        if np.isfinite(train.engagement).any() and np.isfinite(held.engagement).any():
            if tested:
                try:
                    e_table = TestedEngagementModel().fit(train.state, train.success, train.engagement).table_
                except TooFewTurns:  # a fold too small to fit: it adds nothing to the engagement RMSE
                    continue
            else:
                e_table = EngagementModel(options.svr_C, options.svr_epsilon).fit(
                    train.state, train.success, train.engagement).table_
            cell_n, cell_mean = _cell_means(held)
            ok = cell_n > 0
            eng_sq += float(np.sum(cell_n[ok] * (e_table.reshape(-1)[ok] - cell_mean[ok]) ** 2))
            eng_n += float(cell_n[ok].sum())
    return float(np.sqrt(perf_sq / perf_n)), float(np.sqrt(eng_sq / eng_n)) if eng_n else float("nan")


def _cell_means(turns: Turns) -> tuple[np.ndarray, np.ndarray]:
    ok = np.isfinite(turns.engagement)
    cell = turns.state[ok] * 2 + turns.success[ok].astype(int)
    n = np.bincount(cell, minlength=2 * mdp.N_TURN_STATES).astype(float)
    total = np.bincount(cell, weights=turns.engagement[ok], minlength=2 * mdp.N_TURN_STATES)
    with np.errstate(invalid="ignore", divide="ignore"):
        return n, total / n


def fit_cluster(turns: Turns, cluster_id: int, options: FitOptions, rng: np.random.Generator,
                p: np.ndarray, e: np.ndarray, metadata: dict[str, Any]) -> ClusterFit:
    """Fit one cluster's simulator from its turns (see the module docstring).

    ``metadata["compat"] == "authors2018"``: the full state regression above (how the shipped models
    were made); otherwise effects beyond the level only where the data supports them
    (``learn.effects``).
    """
    tested = metadata.get("compat") != "authors2018"
    p_table, e_table, pm, em = _fit_tables(turns, options, tested)
    cv_p, cv_e = cross_validate(turns, options, rng, tested)
    extra: dict[str, Any] = {}
    if tested:
        extra = {"effects": effect_report(pm, em), "model": "tested effects (learn.effects)"}
        mle = PerformanceModel(0.0).fit(turns.state, turns.success)
        seen = mle.counts_ > 0
        pm.rmse_ = float(np.sqrt(np.mean((p_table[seen] - mle.mle_[seen]) ** 2)))
        pm.rmse_regression_ = pm.rmse_
        pm.monotone_applied_ = False
        pm.counts_ = mle.counts_
        cell_n, cell_mean = _cell_means(turns)
        ok = cell_n > 0
        em.rmse_ = float(np.sqrt(np.mean((e_table.reshape(-1)[ok] - cell_mean[ok]) ** 2)))
    sim = UserSimulator(
        name=f"cluster-{cluster_id}",
        p_success=p_table,
        engagement=e_table,
        reaction_quantiles=time_quantiles(turns.level, turns.reaction_time, "reaction time"),
        completion_quantiles=time_quantiles(turns.level, turns.completion_time, "completion time"),
        metadata={**metadata, "cluster": cluster_id, "sessions": int(len(np.unique(turns.session))),
                  "turns": int(len(turns.state)), "monotone_in_length": pm.monotone_applied_, **extra},
    )
    return ClusterFit(
        id=cluster_id,
        sessions=tuple(np.unique(turns.session).tolist()),
        simulator=sim,
        p=p,
        e=e,
        rmse_performance=pm.rmse_,
        rmse_performance_regression=pm.rmse_regression_,
        rmse_engagement=em.rmse_,
        cv_rmse_performance=cv_p,
        cv_rmse_engagement=cv_e,
        data_level_success=_level_success(turns),
        simulated_level_success=_level_success(turns, p_table),
        observed_states=int(np.sum(pm.counts_ > 0)),
    )


#: Our stable cluster id -> the paper's cluster number (argued in core.usermodel's docstring);
#: only attached when the fit runs in the authors' compatibility mode with K = 3.
PAPER_CLUSTERS = {1: 1, 2: 3, 3: 2}


def fit_dataset(turns: Turns, options: FitOptions | None = None, metadata: dict[str, Any] | None = None,
                progress: Callable[[str], None] | None = None) -> FitResult:
    """User models, K-means clusters and one simulator per cluster from a turn table.

    Runs with one BLAS/OpenMP thread: K-means and the regressions then sum in one fixed order, so
    a refit on the same machine writes identical files whatever the core count.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        return _fit_dataset(turns, options, metadata, progress)


def _fit_dataset(turns: Turns, options: FitOptions | None, metadata: dict[str, Any] | None,
                 progress: Callable[[str], None] | None) -> FitResult:
    options = options or FitOptions()
    metadata = dict(metadata or {})
    say = progress or (lambda _msg: None)
    rng = np.random.default_rng(options.seed)
    um = user_models(turns.session, turns.level, turns.success, turns.engagement)
    say(f"user models: {len(um.sessions)} sessions")
    clustering = cluster_users(um.features, options.k, options.n_init, options.seed)
    say(f"K-means K={options.k}: sizes {clustering.sizes.tolist()}, inertia {clustering.inertia:.6f}")
    by_session = dict(zip(um.sessions, clustering.labels))
    session_label = np.array([by_session[s] for s in turns.session])
    clusters = []
    for cid in range(1, clustering.k + 1):
        meta = dict(metadata)
        if metadata.get("compat") == "authors2018" and clustering.k == 3:
            meta["paper_cluster"] = PAPER_CLUSTERS[cid]
        center = clustering.centers[cid - 1]
        members = turns.subset(session_label == cid)
        clusters.append(fit_cluster(members, cid, options, rng, center[:4], center[4:], meta))
        c = clusters[-1]
        say(f"cluster {cid}: {len(c.sessions)} sessions, RMSE performance {c.rmse_performance:.3f} "
            f"(CV {c.cv_rmse_performance:.3f}), engagement {c.rmse_engagement:.3f} (CV {c.cv_rmse_engagement:.3f})")
    return FitResult(um, clustering, clusters, options, metadata)


# ------------------------------------------------------------------------------------------------
# The whole `nao-trainer fit` pipeline (files in, artifacts and figures out)
# ------------------------------------------------------------------------------------------------
