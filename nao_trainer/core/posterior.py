"""Which known user model is this participant? A posterior over user models, updated per turn.

Pure: no I/O. The prior of model k is its cluster's share of the sessions it was fitted on. After
each turn played in turn state ``s`` with outcome ``o``, the weight of model k is multiplied by its
predictive probability of that outcome::

    w_k  <-  w_k * q_k(s)^o * (1 - q_k(s))^(1-o)          (then renormalised)

With ``kappa = inf`` (the plain user-model posterior) ``q_k(s) = p_k(s)``, the model's table.
With a finite ``kappa`` each model is the prior of a per-level Beta posterior of the participant's
own success rate: model k's Beta at level l has mean ``m_kl`` (the model's mean success over the
reachable states of level l) and strength ``kappa`` pseudo-turns, and after ``n_l`` turns with
``wins_l`` successes at level l its posterior mean moves by

    delta_kl = (wins_l - n_l * m_kl) / (kappa + n_l)

and ``q_k(s) = p_k(s) + delta_k,level(s)`` (clipped). For level-only models this is exactly a
mixture of Beta-binomials: the mixture weights are the posterior over models, the Betas the
participant's per-level posteriors, so the estimate keeps learning after the match is made.

Probabilities in the likelihood are clipped to [``FLOOR``, 1 - ``FLOOR``]: one surprising turn
(a failure where a model says 1.0) weakens a model but cannot rule it out for good.

Engagement, when ``engagement_sigma`` is given, multiplies in a Gaussian likelihood
N(e; Phi_k(s, o), sigma_k^2) of the turn's engagement ``e``. Whether that adds information on the
published data is measured by ``nao-trainer evaluate --personalise`` (``engagement_information``)
and reported in docs/explanation/results.md; the live policy leaves it off unless asked.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from nao_trainer.core import mdp

FLOOR = 1e-3

_CLUSTER = re.compile(r"cluster-(\d+)(?:-(.+))?")


def model_label(name: str) -> str:
    """A user model's name in the words the output uses for it: ``cluster-3`` is "user model 3", the words of the
    policy trained for it (``usp:3``: "personalised (user model 3)"), so the posterior, the match and the policy
    name a model alike; ``cluster-2-level-only`` is "user model 2 (level-only)"; any other name follows
    "user model". The files keep the names (``cluster-3``)."""
    m = _CLUSTER.fullmatch(name)
    if m is None:
        return f"user model {name}"
    return f"user model {m.group(1)}" + (f" ({m.group(2)})" if m.group(2) else "")


def level_means(p_success: np.ndarray) -> np.ndarray:
    """(K, 4): each model's mean P(success) over the reachable turn states of each level."""
    p = np.atleast_2d(np.asarray(p_success, dtype=float))
    out = np.zeros((p.shape[0], 4))
    for lv in range(4):
        cells = (mdp.LEVEL == lv + 1) & mdp.REACHABLE
        out[:, lv] = p[:, cells].mean(axis=1)
    return out


@dataclass(frozen=True, eq=False)
class ModelSet:
    """The known user models: names, tables and prior weights (cluster sizes, normalised)."""

    names: tuple[str, ...]
    p_success: np.ndarray  # (K, 108)
    engagement: np.ndarray  # (K, 108, 2)
    prior: np.ndarray  # (K,) sums to 1
    engagement_sigma: np.ndarray | None = None  # (K,) residual SD of engagement, None: not used

    def __post_init__(self) -> None:
        p = np.asarray(self.p_success, dtype=float)
        e = np.asarray(self.engagement, dtype=float)
        prior = np.asarray(self.prior, dtype=float)
        k = len(self.names)
        if k < 1 or p.shape != (k, mdp.N_TURN_STATES) or e.shape != (k, mdp.N_TURN_STATES, 2):
            raise ValueError(f"a model set of {k} models needs p_success ({k}, 108) and engagement ({k}, 108, 2)")
        if prior.shape != (k,) or np.any(prior <= 0) or not np.all(np.isfinite(prior)):
            raise ValueError("model priors must be positive, one per model")
        object.__setattr__(self, "p_success", p)
        object.__setattr__(self, "engagement", e)
        object.__setattr__(self, "prior", prior / prior.sum())
        if self.engagement_sigma is not None:
            s = np.asarray(self.engagement_sigma, dtype=float)
            if s.shape != (k,) or np.any(s <= 0):
                raise ValueError("engagement_sigma needs one positive value per model")
            object.__setattr__(self, "engagement_sigma", s)

    @property
    def k(self) -> int:
        return len(self.names)

    @property
    def level_means(self) -> np.ndarray:
        return level_means(self.p_success)


def shifts(models: ModelSet, wins: np.ndarray, turns: np.ndarray, kappa: float) -> np.ndarray:
    """(n, K, 4): per-level shift of each model's success rate after ``wins``/``turns`` (n, 4) per level."""
    wins = np.atleast_2d(np.asarray(wins, dtype=float))
    turns = np.atleast_2d(np.asarray(turns, dtype=float))
    if not np.isfinite(kappa):
        return np.zeros((wins.shape[0], models.k, 4))
    m = models.level_means[None]  # (1, K, 4)
    return (wins[:, None, :] - turns[:, None, :] * m) / (kappa + turns[:, None, :])


def predictive(models: ModelSet, state: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(n, K): each model's probability of success in turn state ``state`` (n,) given shifts (n, K, 4)."""
    s = np.atleast_1d(np.asarray(state, dtype=np.int64))
    base = models.p_success[:, s].T  # (n, K)
    lv = mdp.LEVEL[s] - 1
    shift = np.take_along_axis(delta, np.broadcast_to(lv[:, None, None], (len(s), models.k, 1)), axis=2)[..., 0]
    return np.clip(base + shift, 0.0, 1.0)


def log_likelihood(models: ModelSet, state: np.ndarray, success: np.ndarray, delta: np.ndarray,
                   engagement: np.ndarray | None = None) -> np.ndarray:
    """(n, K): log-likelihood of one turn's outcome (and engagement, when the models use it)."""
    q = np.clip(predictive(models, state, delta), FLOOR, 1.0 - FLOOR)
    o = np.atleast_1d(np.asarray(success, dtype=bool))
    ll = np.where(o[:, None], np.log(q), np.log1p(-q))
    if engagement is not None and models.engagement_sigma is not None:
        e = np.atleast_1d(np.asarray(engagement, dtype=float))
        s = np.atleast_1d(np.asarray(state, dtype=np.int64))
        mu = models.engagement[:, s, o.astype(np.int64)].T  # (n, K)
        sig = models.engagement_sigma[None]
        ok = np.isfinite(e)[:, None]
        gauss = -0.5 * ((e[:, None] - mu) / sig) ** 2 - np.log(sig)
        ll = ll + np.where(ok, gauss, 0.0)
    return ll


def normalise(log_w: np.ndarray) -> np.ndarray:
    """Posterior probabilities from unnormalised log weights (rows)."""
    lw = np.atleast_2d(log_w)
    z = lw - lw.max(axis=1, keepdims=True)
    w = np.exp(z)
    return w / w.sum(axis=1, keepdims=True)


def posterior(models: ModelSet, states: "list[int] | np.ndarray", successes: "list[bool] | np.ndarray",
              kappa: float = float("inf"), engagements: "list[float] | np.ndarray | None" = None) -> np.ndarray:
    """(K,): the posterior over models after one sequence of turns (a convenience for one participant)."""
    log_w = np.log(models.prior)[None]
    wins = np.zeros((1, 4))
    turns = np.zeros((1, 4))
    for i, (s, o) in enumerate(zip(states, successes)):
        delta = shifts(models, wins, turns, kappa)
        e = None if engagements is None else np.array([engagements[i]], dtype=float)
        log_w = log_w + log_likelihood(models, np.array([s]), np.array([o]), delta, e)
        lv = mdp.LEVEL[s] - 1
        turns[0, lv] += 1
        wins[0, lv] += bool(o)
    return normalise(log_w)[0]
