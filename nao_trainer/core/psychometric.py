"""A user model that pools across levels: success against sequence length, per participant.

Pure: no I/O. Participant i succeeds on a sequence of length x with probability

    psi(x | theta_i) = (1 - lapse) * Phi((theta_i - x) / sigma)

``theta_i`` is the participant's *span* (the length recalled half the time, before lapses),
``sigma`` how fast success falls with length and ``lapse`` the rate of failures at any length.
The prior is hierarchical: ``theta_i ~ Normal(mu, tau^2)`` across participants, with ``mu``,
``tau``, ``sigma`` and ``lapse`` fitted on the training sessions by maximum marginal likelihood
over a grid (``fit``); each participant's theta is then integrated over a grid of values, so a
participant's turns at length 5 inform the prediction at length 9, and any length (not only 3, 5,
7, 9) can be predicted. Outcomes depend on the length only, so the per-length counts are a
sufficient statistic, as for the per-level models of ``core.bayes``.

``span(counts, rate)`` is the length at which the participant succeeds with probability
``rate``: ``x_R = theta - sigma * Phi^-1(rate / (1 - lapse))``, with a posterior interval;
``session_span`` gives its posterior median and interval for one session (the study outcome).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from math import erf, sqrt

import numpy as np

from nao_trainer.core import objective

LENGTHS = np.array([3.0, 5.0, 7.0, 9.0])
#: The success rate a session's span is given at, unless the study keeps participants near its own
#: target (``policy.objective: target:R``: then R, see ``span_rate``).
SPAN_RATE = 0.75
THETA = np.linspace(0.0, 14.0, 141)
_MU = np.arange(3.0, 11.01, 0.25)
_TAU = np.array([0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0])
_SIGMA = np.geomspace(0.3, 4.0, 14)
_LAPSE = np.array([0.0, 0.02, 0.05, 0.1, 0.15])

#: The range each parameter of a pooled model may take: a span and its spread inside the grid of spans
#: integrated over (THETA, letters), a slope that is neither a step finer than the grid nor flat over it.
#: Outside them the prior has no mass on the grid (NaN, infinity, ``mu: 1e300``) or is a spike between
#: its points (``tau: 1e-300``): nothing a fit writes (its grids lie well inside).
RANGES: dict[str, tuple[float, float]] = {"mu": (float(THETA[0]), float(THETA[-1])), "tau": (0.1, 20.0),
                                           "sigma": (0.05, 20.0), "lapse": (0.0, 0.5)}


def parameter_problem(name: str, value: object) -> str | None:
    """Why ``value`` cannot be the parameter ``name`` of a pooled model (None when it can)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return "must be a number"
    try:
        x = float(value)
    except OverflowError:
        return "is too large to be a number"
    lo, hi = RANGES[name]
    if not math.isfinite(x):
        return f"must be a finite number, got {x}"
    if not lo <= x <= hi:
        return f"must lie in [{lo:g}, {hi:g}], got {x:.6g}"
    return None


_phi = np.vectorize(lambda z: 0.5 * (1.0 + erf(z / sqrt(2.0))))


def curve(x: np.ndarray, theta: np.ndarray, sigma: float, lapse: float) -> np.ndarray:
    return (1.0 - lapse) * _phi((np.asarray(theta, float) - np.asarray(x, float)) / sigma)


def _log_lik(counts: np.ndarray, sigma: float, lapse: float) -> np.ndarray:
    """(S, G): log-likelihood of each session's counts (S, 8) at every theta of the grid."""
    psi = np.clip(curve(LENGTHS[None, :], THETA[:, None], sigma, lapse), 1e-9, 1 - 1e-9)  # (G, 4)
    c = np.atleast_2d(np.asarray(counts, dtype=float))
    return c[:, 0::2] @ np.log(psi).T + c[:, 1::2] @ np.log1p(-psi).T


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    m = a.max(axis=axis, keepdims=True)
    return (m + np.log(np.exp(a - m).sum(axis=axis, keepdims=True))).squeeze(axis)


@dataclass(frozen=True)
class PooledModel:
    mu: float
    tau: float
    sigma: float
    lapse: float

    def __post_init__(self) -> None:
        for name in RANGES:
            problem = parameter_problem(name, getattr(self, name))
            if problem is not None:
                raise ValueError(f"{name} {problem}")

    def log_prior(self) -> np.ndarray:
        lp = -0.5 * ((THETA - self.mu) / self.tau) ** 2
        return lp - _logsumexp(lp, 0)

    def posterior(self, counts: np.ndarray) -> np.ndarray:
        """(G,) posterior over theta given one participant's counts (s1, f1, ..., s4, f4)."""
        lw = self.log_prior() + _log_lik(counts, self.sigma, self.lapse)[0]
        w = np.exp(lw - lw.max())
        return w / w.sum()

    def predictive(self, counts: np.ndarray, lengths: np.ndarray = LENGTHS) -> np.ndarray:
        """P(success) at each length for the participant's next turn."""
        w = self.posterior(counts)
        return w @ curve(np.asarray(lengths, float)[None, :], THETA[:, None], self.sigma, self.lapse)

    def mixture(self, min_weight: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """The prior as a finite mixture of per-level user models (what ``core.bayes`` plans over):
        success per level (G, 4) at each theta of the grid with prior weight >= ``min_weight`` (relative
        to the largest), and the weights renormalised over those."""
        _, p, w = self.components(min_weight)
        return p, w

    def components(self, min_weight: float = 1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``mixture`` with the span theta of each component first: (theta (G,), p (G, 4), w (G,))."""
        w = np.exp(self.log_prior())
        keep = w >= min_weight * w.max()
        theta = THETA[keep]
        return theta, curve(LENGTHS[None, :], theta[:, None], self.sigma, self.lapse), w[keep] / w[keep].sum()

    def span(self, counts: np.ndarray, rate: float = 0.75, level: float = 0.9) -> tuple[float, float, float]:
        """Posterior mean and central ``level`` interval of the length succeeded at ``rate``."""
        from statistics import NormalDist

        q = rate / (1.0 - self.lapse)
        if not 0.0 < q < 1.0:
            raise ValueError(f"a participant with lapse rate {self.lapse} never succeeds at rate {rate}")
        x = THETA - self.sigma * NormalDist().inv_cdf(q)
        w = self.posterior(counts)
        cdf = np.cumsum(w)
        lo = float(x[np.searchsorted(cdf, (1 - level) / 2)])
        hi = float(x[min(np.searchsorted(cdf, 1 - (1 - level) / 2), len(x) - 1)])
        return float(w @ x), lo, hi


@dataclass(frozen=True)
class Span:
    """A session's span: the sequence length (letters) it succeeds at ``rate``, median and interval."""

    rate: float
    median: float
    lo: float
    hi: float
    level: float = 0.9  # probability of the interval [lo, hi]


def session_span(model: PooledModel, counts: np.ndarray, rate: float = 0.75, level: float = 0.9) -> Span:
    """Posterior median and central ``level`` interval of the length at which P(success) = ``rate``.

    ``counts`` are the session's (s1, f1, ..., s4, f4): successes and failures at levels 1-4, which
    are sequences of 3, 5, 7 and 9 letters (only the length matters, so the counts are sufficient).
    Under ``model`` the session's theta has the grid posterior

        w(theta) ~ N(theta; mu, tau^2) * prod_l psi(x_l | theta)^s_l * (1 - psi(x_l | theta))^f_l

    and its span at rate R solves psi(x | theta) = R:

        x_R(theta) = theta - sigma * Phi^-1(R / (1 - lapse)),

    a shift of theta, so the quantiles of x_R are those of theta moved by a constant. The posterior
    CDF of theta is taken piecewise linear between grid points (each point's mass centred on it)
    and the median and the (1 - level)/2, (1 + level)/2 quantiles are read from it. Without turns
    (all counts 0) this is the prior's span. R must lie in (0, 1 - lapse): a participant who
    lapses on a fraction ``lapse`` of turns never succeeds more often than 1 - lapse.
    """
    from statistics import NormalDist

    if not 0.0 < level < 1.0:
        raise ValueError(f"interval probability must lie in (0, 1), got {level}")
    q = rate / (1.0 - model.lapse)
    if not 0.0 < q < 1.0:
        raise ValueError(f"a participant with lapse rate {model.lapse} never succeeds at rate {rate}")
    x = THETA - model.sigma * NormalDist().inv_cdf(q)
    w = model.posterior(np.asarray(counts, dtype=float))
    cdf = np.cumsum(w) - w / 2  # the CDF at each grid point, its own mass split in half
    lo, median, hi = np.interp([(1 - level) / 2, 0.5, (1 + level) / 2], cdf, x)
    return Span(float(rate), float(median), float(lo), float(hi), float(level))


def level_counts(levels: "list[int] | np.ndarray", successes: "list[bool] | np.ndarray") -> np.ndarray:
    """(8,) per-level (successes, failures) of one session's turns (levels 1-4)."""
    out = np.zeros(8)
    for lv, ok in zip(levels, successes):
        if int(lv) not in (1, 2, 3, 4):
            raise ValueError(f"level {lv} is not one of 1, 2, 3, 4")
        out[2 * (int(lv) - 1) + (0 if ok else 1)] += 1
    return out


def fit(counts: np.ndarray) -> PooledModel:
    """Maximum marginal likelihood of (mu, tau, sigma, lapse) over the grid, sessions' counts (S, 8)."""
    c = np.atleast_2d(np.asarray(counts, dtype=float))
    best, arg = -np.inf, None
    lp = -0.5 * ((THETA[None, None, :] - _MU[:, None, None]) / _TAU[None, :, None]) ** 2
    lp = lp - _logsumexp(lp, 2)[..., None]  # (M, T, G)
    for sigma in _SIGMA:
        for lapse in _LAPSE:
            ll = _log_lik(c, sigma, lapse)  # (S, G)
            total = _marginal(ll, lp).sum(axis=0)  # (M, T)
            i = np.unravel_index(int(np.argmax(total)), total.shape)
            if total[i] > best:
                best, arg = float(total[i]), (float(_MU[i[0]]), float(_TAU[i[1]]), float(sigma), float(lapse))
    return PooledModel(*arg)


def _marginal(ll: np.ndarray, lp: np.ndarray) -> np.ndarray:
    """(S, M, T): log of each session's likelihood (S, G) integrated over each prior (M, T, G) of theta.

    A product of matrices scaled by each session's largest term (the log-sum-exp over G of ll + lp written as
    one matrix product: 5.4 s to 0.13 s for a fit of 400 sessions against broadcasting (S, M, T, G)); an integral whose every
    term underflows there is computed term by term, exactly as before.
    """
    top = ll.max(axis=1, keepdims=True)  # (S, 1)
    prior = np.exp(lp).reshape(-1, lp.shape[-1])  # (M*T, G)
    with np.errstate(divide="ignore"):
        out = top + np.log(np.exp(ll - top) @ prior.T)  # (S, M*T)
    bad = ~np.isfinite(out)
    if bad.any():
        s_idx, k_idx = np.nonzero(bad)
        flat = lp.reshape(-1, lp.shape[-1])
        out[s_idx, k_idx] = _logsumexp(ll[s_idx] + flat[k_idx], 1)
    return out.reshape(ll.shape[0], *lp.shape[:2])


def session_counts(sessions: np.ndarray, levels: np.ndarray, successes: np.ndarray) -> np.ndarray:
    """(S, 8) per-level (successes, failures) of each session (sorted by name)."""
    names = sorted(np.unique(sessions).tolist())
    out = np.zeros((len(names), 8))
    index = {n: i for i, n in enumerate(names)}
    for s, lv, ok in zip(sessions, levels, successes):
        out[index[s], 2 * (int(lv) - 1) + (0 if ok else 1)] += 1
    return out


def span_rate(obj: "objective.Objective | str | None") -> float:
    """The rate of a session's span: R of a ``target:R`` objective, else :data:`SPAN_RATE`."""
    parsed = objective.parse(obj)
    return float(parsed.rate) if parsed.is_target else SPAN_RATE

