"""User simulators that keep a feedback or previous-outcome effect only where the data supports it.

This is the default fit (``nao-trainer fit`` without ``--compat``); ``--compat authors2018`` keeps
the full state regression of ``learn.fitting`` (how the shipped ``sim/models`` were made).

Criterion (documented in docs/explanation/evaluation.md). Within one cluster's turns:

* **success** is modelled by a logistic regression on the level (4 one-hot columns) plus the
  candidate effects that pass a likelihood-ratio test against the level-only model: ``feedback``
  (encouraging / challenging vs none, 2 df) and ``previous`` (previous turn failed / succeeded and
  its |score| / 4, 3 df). Each test is at ``alpha / 2`` (Bonferroni over the two candidates);
  the kept effects are refitted together. Unpenalised fits (the test needs the likelihood).
* **engagement** per (state, outcome) is least squares on the level plus the candidate effects
  ``outcome`` (1 df), ``feedback`` (2 df) and ``previous`` (3 df) that pass a nested F-test at
  ``alpha / 3``; turns without engagement are left out.

Turns of one session are not independent, so these tests are, if anything, too ready to keep an
effect; an effect they drop is one the data cannot tell from noise. When per-level success rates
fall with the level in the data, the table is made non-increasing in length per (feedback,
previous) column, as in ``learn.fitting``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nao_trainer.core import distributions, mdp
from nao_trainer.errors import DataError

ALPHA = 0.05
SUCCESS_EFFECTS: tuple[str, ...] = ("feedback", "previous")
ENGAGEMENT_EFFECTS: tuple[str, ...] = ("outcome", "feedback", "previous")


class TooFewTurns(DataError):
    """A cluster has too few turns to fit a model: a user error (more data or fewer clusters), not a crash."""


def _columns(states: np.ndarray, outcome: np.ndarray | None, effects: tuple[str, ...]) -> np.ndarray:
    """Design matrix: level one-hot (4) then the effects' columns (no separate intercept)."""
    s = np.asarray(states, dtype=int)
    cols = [np.eye(4)[mdp.LEVEL[s] - 1]]
    prev = mdp.PREVIOUS[s]
    for eff in effects:
        if eff == "feedback":
            cols.append(np.column_stack([mdp.FEEDBACK[s] == 1, mdp.FEEDBACK[s] == 2]).astype(float))
        elif eff == "previous":
            cols.append(np.column_stack([prev < 0, prev > 0, np.abs(prev) / 4.0]).astype(float))
        elif eff == "outcome":
            cols.append(np.asarray(outcome, dtype=float)[:, None])
        else:
            raise ValueError(f"unknown effect {eff!r}")
    return np.hstack(cols)


def _logistic(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """Maximum-likelihood logistic fit by Newton's method with a tiny ridge (separation-safe).

    Returns (coefficients, log-likelihood).
    """
    w = np.zeros(x.shape[1])
    ridge = 1e-4
    for _ in range(100):
        z = np.clip(x @ w, -30, 30)
        p = 1.0 / (1.0 + np.exp(-z))
        grad = x.T @ (y - p) - ridge * w
        hess = (x * (p * (1 - p))[:, None]).T @ x + ridge * np.eye(x.shape[1])
        step = np.linalg.solve(hess, grad)
        w += step
        if np.max(np.abs(step)) < 1e-10:
            break
    z = np.clip(x @ w, -30, 30)
    p = np.clip(1.0 / (1.0 + np.exp(-z)), 1e-12, 1 - 1e-12)
    return w, float(np.sum(y * np.log(p) + (1 - y) * np.log(1 - p)))


def _drop_empty(x: np.ndarray) -> np.ndarray:
    """Columns that are constant zero carry no information (a level never played): keep them out of df."""
    return x[:, np.any(x != 0, axis=0)]


def _pav_non_increasing(y: np.ndarray) -> np.ndarray:
    """Least-squares non-increasing fit of a short vector (scikit-learn's pool adjacent violators)."""
    from sklearn.isotonic import isotonic_regression

    return isotonic_regression(np.asarray(y, dtype=float), increasing=False)


@dataclass
class TestedPerformanceModel:
    """P(success | state) with only the effects the likelihood-ratio tests keep (module docstring)."""

    alpha: float = ALPHA
    tests: dict[str, dict[str, float | bool]] = field(default_factory=dict)

    def fit(self, states: np.ndarray, success: np.ndarray) -> "TestedPerformanceModel":
        s = np.asarray(states, dtype=int)
        y = np.asarray(success, dtype=float)
        x0 = _columns(s, None, ())
        played = np.any(x0 != 0, axis=0)
        _, ll0 = _logistic(x0[:, played], y)
        kept = []
        for eff in SUCCESS_EFFECTS:
            x1 = _columns(s, None, (eff,))
            x1 = x1[:, np.concatenate([played, np.any(x1[:, 4:] != 0, axis=0)])]
            _, ll1 = _logistic(x1, y)
            df = x1.shape[1] - int(played.sum())
            stat = max(0.0, 2 * (ll1 - ll0))
            p = float(distributions.chi2_sf(stat, df)) if df > 0 else 1.0
            keep = p < self.alpha / len(SUCCESS_EFFECTS)
            self.tests[eff] = {"statistic": round(stat, 6), "df": df, "p": round(p, 6), "kept": bool(keep)}
            if keep:
                kept.append(eff)
        self.effects_ = tuple(kept)
        x = _columns(s, None, self.effects_)
        use = np.any(x != 0, axis=0)
        w, _ = _logistic(x[:, use], y)
        coef = np.zeros(x.shape[1])
        coef[use] = w
        # A level never played gets the mean logit of the played ones (no information either way).
        if not played.all():
            coef[:4][~played] = coef[:4][played].mean()
        z = _columns(np.arange(mdp.N_TURN_STATES), None, self.effects_) @ coef
        table = 1.0 / (1.0 + np.exp(-np.clip(z, -30, 30)))
        rates = np.array([y[mdp.LEVEL[s] == lv].mean() for lv in (1, 2, 3, 4) if np.any(mdp.LEVEL[s] == lv)])
        if np.all(np.diff(rates) <= 1e-12):
            grid = table.reshape(4, 27)
            table = np.column_stack([_pav_non_increasing(grid[:, j]) for j in range(27)]).reshape(-1)
        self.table_ = np.clip(table, 0.0, 1.0)
        return self


@dataclass
class TestedEngagementModel:
    """Phi(state, outcome) with only the effects the F-tests keep (module docstring)."""

    alpha: float = ALPHA
    tests: dict[str, dict[str, float | bool]] = field(default_factory=dict)

    def fit(self, states: np.ndarray, success: np.ndarray, engagement: np.ndarray) -> "TestedEngagementModel":
        ok = np.isfinite(np.asarray(engagement, dtype=float))
        s = np.asarray(states, dtype=int)[ok]
        o = np.asarray(success, dtype=float)[ok]
        e = np.asarray(engagement, dtype=float)[ok]
        if len(e) < 8:
            raise TooFewTurns(f"only {len(e)} turns with engagement in a cluster: the tested-effects fit needs at least "
                              "8 (fit more sessions, a smaller --k, or --compat authors2018)")

        def rss(x: np.ndarray) -> tuple[float, int, np.ndarray]:
            x = _drop_empty(x)
            coef, *_ = np.linalg.lstsq(x, e, rcond=None)
            r = e - x @ coef
            return float(r @ r), x.shape[1], coef

        rss0, k0, _ = rss(_columns(s, o, ()))
        kept = []
        for eff in ENGAGEMENT_EFFECTS:
            rss1, k1, _ = rss(_columns(s, o, (eff,)))
            df1, df2 = k1 - k0, len(e) - k1
            if df1 > 0 and df2 > 0 and rss1 > 0:
                stat = max(0.0, (rss0 - rss1) / df1 / (rss1 / df2))
                p = float(distributions.f_sf(stat, df1, df2))
            else:
                stat, p = 0.0, 1.0
            keep = p < self.alpha / len(ENGAGEMENT_EFFECTS)
            self.tests[eff] = {"statistic": round(stat, 6), "df": df1, "p": round(p, 6), "kept": bool(keep)}
            if keep:
                kept.append(eff)
        self.effects_ = tuple(kept)
        x = _columns(s, o, self.effects_)
        use = np.any(x != 0, axis=0)
        coef = np.zeros(x.shape[1])
        coef[use], *_ = np.linalg.lstsq(x[:, use], e, rcond=None)
        played = use[:4]
        if not played.all():
            coef[:4][~played] = coef[:4][played].mean()
        all_s = np.repeat(np.arange(mdp.N_TURN_STATES), 2)
        all_o = np.tile([0.0, 1.0], mdp.N_TURN_STATES)
        self.table_ = np.clip(_columns(all_s, all_o, self.effects_) @ coef, 0.0, 1.0).reshape(-1, 2)
        return self


def effect_report(perf: TestedPerformanceModel, eng: TestedEngagementModel) -> dict[str, Any]:
    """The JSON record of which effects were tested, their p-values and which were kept."""
    return {"criterion": f"likelihood-ratio (success) / F (engagement) test vs level only, alpha {perf.alpha} "
                         "Bonferroni-split over the candidate effects",
            "success": perf.tests, "engagement": eng.tests}
