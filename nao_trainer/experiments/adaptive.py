"""Psychophysics' adaptive rules as baselines beside the ceiling: staircases and QUEST+.

Both see each outcome straight away, like the Bayes planner (``core.bayes``), and play levels
only; on a level-only user both are evaluated exactly (no Monte Carlo):

``staircase-NdIu@L``  N successes in a row: one level up; one failure: one level down; start at L.
               Its state is (level, streak), a Markov chain of 4 x N states run forward for the
               session. 2-down/1-up converges where p^2 = 1/2 (70.7 %), 3-down/1-up where
               p^3 = 1/2 (79.4 %) (Levitt 1971), so they are the rules that match target:0.707 and
               target:0.794.
``questplus``  QUEST+ (Watson 2017, J. Vision 17(3):10; the ``questplus`` package) over a
               psychometric function of sequence length: success = lapse-scaled normal CDF of
               (threshold - length) / spread, on a grid of thresholds 2-12, spreads 0.5-4 and lapse
               rates 0-10 %, uniform prior; the next level is QUEST+'s own: the one whose outcome
               minimises the expected entropy of the posterior (``stim_selection_method=
               "min_entropy"``, checked against the package's ``next_stim``). It estimates the
               participant's function; it does not aim at a rate.
``questplus-fitted``  the same with the prior fitted on the other people (the planner gets a fitted
               prior, so QUEST+ gets one too): the mixture of their posteriors under the uniform
               prior, each from 6 pseudo-turns per level at the person's rates (about the data's
               turns per level).
``questplus-mean``  the QUEST+ posterior with the level whose posterior mean success has the highest
               utility (target: the level expected nearest R, QUEST's placement at the
               R-threshold; score: the highest expected score); the project's earlier "QUEST+".
``staircase-tuned``  the n-down/1-up rule and start level (n = 1..4, start 1..4) best on average over
               the other people under the objective: a staircase tuned to the 4-level ladder.

The QUEST+ posterior depends on the per-level counts only, so ``core.bayes.evaluate_rule`` runs
each rule exactly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nao_trainer.core import bayes
from nao_trainer.core.objective import Objective
from nao_trainer.core.task import LENGTHS

THRESHOLDS = np.arange(2.0, 12.01, 0.25)
SPREADS = np.geomspace(0.5, 4.0, 12)
LAPSES = np.array([0.0, 0.02, 0.05, 0.1])


def staircase_exact(need: int, start: int, p_level: np.ndarray, turns: int, obj: Objective) -> dict[str, float | list]:
    """Expected utility, score, turns per level, success rate and its variance of an n-up/1-down
    rule on a user: the chain over (level, streak, successes so far), exact. ``p_level`` may have
    any number of levels (a fine ladder for Levitt's limit; the score assumes levels 1..L)."""
    p = np.asarray(p_level, dtype=float)
    top = len(p)
    dist = np.zeros((top, need, turns + 1))
    dist[start - 1, 0, 0] = 1.0
    visits = np.zeros(top)
    for _ in range(turns):
        visits += dist.sum(axis=(1, 2))
        lose = (dist * (1 - p)[:, None, None]).sum(axis=1)  # (level, S): one level down, streak 0
        win = np.zeros_like(dist)
        win[:, :, 1:] = dist[:, :, :-1] * p[:, None, None]  # a success adds one to S
        new = np.zeros_like(dist)
        new[:-1, 0] += lose[1:]
        new[0, 0] += lose[0]
        up = win[:, need - 1]  # the streak is complete: one level up, streak 0
        new[1:, 0] += up[:-1]
        new[top - 1, 0] += up[top - 1]
        new[:, 1:] += win[:, :need - 1]
        dist = new
    ps = dist.sum(axis=(0, 1))
    s_vals = np.arange(turns + 1, dtype=float)
    mean = float(ps @ s_vals)
    var = max(float(ps @ s_vals ** 2) - mean ** 2, 0.0)
    rate, rate_var = mean / turns, var / turns ** 2
    return {"utility": obj.from_moments(visits, p, rate, rate_var, turns),
            "score": float(visits @ (p * np.arange(2, top + 2) - 1.0)),
            "visits": visits.tolist(), "success": rate, "success_var": rate_var}


@dataclass(frozen=True)
class QuestPlusGrid:
    """The QUEST+ likelihood over the parameter grid: psi[g, l] = P(success at level l | params g)."""

    psi: np.ndarray  # (G, 4)
    log_prior: np.ndarray  # (G,)

    @classmethod
    def build(cls) -> "QuestPlusGrid":
        from questplus import QuestPlus

        qp = package_questplus(QuestPlus)
        lik = qp.likelihoods.sel(response="Correct").transpose("intensity", "mean", "sd", "lower_asymptote",
                                                               "lapse_rate").values
        psi = np.clip(lik.reshape(len(LENGTHS), -1).T, 1e-9, 1 - 1e-9)
        prior = qp.prior.transpose("mean", "sd", "lower_asymptote", "lapse_rate").values.reshape(-1)
        return cls(psi, np.log(prior / prior.sum()))

    def with_prior(self, weights: np.ndarray) -> "QuestPlusGrid":
        w = np.asarray(weights, dtype=float)
        with np.errstate(divide="ignore"):
            return QuestPlusGrid(self.psi, np.log(w / w.sum()))

    def fitted(self, p_people: np.ndarray, turns_per_level: float = 6.0) -> "QuestPlusGrid":
        """The grid prior fitted on people with these success rates per level (rows): the mixture of
        their posteriors under this grid's prior, each from ``turns_per_level`` pseudo-turns."""
        p = np.atleast_2d(np.asarray(p_people, dtype=float))
        counts = np.zeros((len(p), 8))
        counts[:, 0::2] = turns_per_level * p
        counts[:, 1::2] = turns_per_level * (1 - p)
        w, _ = self.predictive(counts)
        return self.with_prior(w.mean(axis=0) + 1e-300)

    def predictive(self, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(weights (R, G), P(success) per level (R, 4)) after count rows (R, 8)."""
        c = np.atleast_2d(np.asarray(counts, dtype=float))
        logl = np.empty((8, self.psi.shape[0]))
        logl[0::2] = np.log(self.psi).T
        logl[1::2] = np.log1p(-self.psi).T
        lw = self.log_prior + c @ logl
        w = np.exp(lw - lw.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        return w, w @ self.psi

    def choose(self, counts: np.ndarray, obj: Objective) -> np.ndarray:
        """Level index (0..3) for each count row: the utility of the posterior mean success
        (target: the level expected nearest R; score: the highest expected score)."""
        _, mean = self.predictive(counts)
        return np.argmax(np.round(obj.utility(mean), 12), axis=1)

    def expected_entropy(self, counts: np.ndarray) -> np.ndarray:
        """(R, 4): the expected entropy (nats) of the posterior after one more turn at each level,
        as ``questplus.QuestPlus.next_stim`` computes it. With the joint ``w q`` and its total ``pk``,
        ``H = log pk - (sum w q log w + sum w q log q) / pk``, summed over the outcomes weighted by ``pk``.
        ``w`` is left unnormalised (its total ``Z`` cancels: each outcome's term scales by ``Z``, so
        dividing the sum by ``Z`` gives H), which spares two passes over the (R, G) posterior; three
        matrix products with the outcomes side by side, no loop over the grid per state (3x faster than
        the normalised form, equal to 1e-14 and the same choice on every state of a 25-turn run)."""
        c = np.atleast_2d(np.asarray(counts, dtype=float))
        logl = np.empty((8, self.psi.shape[0]))
        logl[0::2] = np.log(self.psi).T
        logl[1::2] = np.log1p(-self.psi).T
        logw = c @ logl
        logw += self.log_prior
        logw -= logw.max(axis=1, keepdims=True)
        w = np.exp(logw)  # (R, G), unnormalised
        logw *= w  # w log w
        if not np.isfinite(self.log_prior).all():
            np.nan_to_num(logw, copy=False, nan=0.0)  # 0 log 0 = 0 where the prior is 0
        k = self.psi.shape[1]
        q = np.concatenate([self.psi, 1.0 - self.psi], axis=1)  # (G, 2k): success, failure
        pk = w @ q  # (R, 2k)
        h = pk * np.log(pk) - (logw @ q + w @ (q * np.log(q)))
        z = pk[:, :k] + pk[:, k:]  # the total of w, once per level
        return (h[:, :k] + h[:, k:]) / z

    def choose_entropy(self, counts: np.ndarray) -> np.ndarray:
        """Level index (0..3) for each count row: QUEST+'s minimum expected entropy."""
        return np.argmin(self.expected_entropy(counts), axis=1)


def package_questplus(QuestPlus):
    """The ``questplus`` package's QUEST+ on the grid of this module (levels as -length), uniform prior."""
    return QuestPlus(stim_domain={"intensity": -np.array(LENGTHS, dtype=float)},
                     param_domain={"mean": -THRESHOLDS, "sd": SPREADS, "lower_asymptote": np.array([0.0]),
                                   "lapse_rate": LAPSES},
                     outcome_domain={"response": ["Correct", "Incorrect"]}, func="norm_cdf", stim_scale="linear",
                     stim_selection_method="min_entropy")


def questplus_values(p_users: np.ndarray, obj: Objective, turns: int = 25, method: str = "entropy",
                     grid: QuestPlusGrid | None = None) -> bayes.PlanValue:
    """Exact expected results of QUEST+ on each user (rows of ``p_users``): ``method`` "entropy"
    (QUEST+'s own placement) or "mean" (the utility of the posterior mean)."""
    grid = grid or QuestPlusGrid.build()
    if method == "entropy":
        rule = lambda states, n: grid.choose_entropy(states)  # noqa: E731
    elif method == "mean":
        rule = lambda states, n: grid.choose(states, obj)  # noqa: E731
    else:
        raise ValueError(f"QUEST+ placement must be 'entropy' or 'mean', got {method!r}")
    return bayes.evaluate_rule(rule, p_users, obj.coefficients(4), turns, obj.terminal(turns))


def tuned_staircase(p_train: np.ndarray, obj: Objective, turns: int) -> tuple[int, int]:
    """(n, start): the n-down/1-up rule (n = 1..4) and start level best on average over ``p_train``."""
    best, arg = -np.inf, (2, 2)
    for need in (1, 2, 3, 4):
        for start in (1, 2, 3, 4):
            v = float(np.mean([staircase_exact(need, start, p, turns, obj)["utility"] for p in p_train]))
            if v > best + 1e-12:
                best, arg = v, (need, start)
    return arg
