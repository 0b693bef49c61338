"""Psychophysics' adaptive rules as baselines beside the ceiling: staircases and QUEST+.

Both see each outcome straight away, like the Bayes planner (``core.bayes``), and play levels
only; on a level-only user both are evaluated exactly (no Monte Carlo):

``staircase-NdIu@L``  N successes in a row: one level up; one failure: one level down; start at L.
               Its state is (level, streak), a Markov chain of 4 x N states run forward for the
               session. 2-down/1-up converges where p^2 = 1/2 (70.7 %), 3-down/1-up where
               p^3 = 1/2 (79.4 %) (Levitt 1971), so they are the rules that match target:0.707 and
               target:0.794.
``questplus``  the QUEST+ posterior (Watson 2017, J. Vision 17(3):10; the ``questplus`` package)
               over a psychometric function of sequence length: success =
               lapse-scaled normal CDF of (threshold - length) / spread, on a grid of thresholds
               2-12, spreads 0.5-4 and lapse rates 0-10 %, uniform prior. The next level is the one
               whose posterior mean success has the highest utility (target:R: the level expected
               nearest R, QUEST's placement at the R-threshold; score: the highest expected score).
               Ranking levels by the posterior expected utility instead, which counts the posterior
               variance against a level, keeps it at level 1 for good under target:R (level 1 is the
               level it is surest about), so it is not used. QUEST+'s own placement (minimum
               expected entropy) serves estimation, not training, and is not used either. The posterior depends on
               the per-level counts only, so ``core.bayes.evaluate_rule`` runs it exactly.
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

        qp = QuestPlus(stim_domain={"intensity": -np.array(LENGTHS, dtype=float)},
                       param_domain={"mean": -THRESHOLDS, "sd": SPREADS, "lower_asymptote": np.array([0.0]),
                                     "lapse_rate": LAPSES},
                       outcome_domain={"response": ["Correct", "Incorrect"]}, func="norm_cdf", stim_scale="linear")
        lik = qp.likelihoods.sel(response="Correct").transpose("intensity", "mean", "sd", "lower_asymptote",
                                                               "lapse_rate").values
        psi = np.clip(lik.reshape(len(LENGTHS), -1).T, 1e-9, 1 - 1e-9)
        prior = qp.prior.transpose("mean", "sd", "lower_asymptote", "lapse_rate").values.reshape(-1)
        return cls(psi, np.log(prior / prior.sum()))

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
        (target:R: the level expected nearest R; score: the highest expected score)."""
        _, mean = self.predictive(counts)
        return np.argmax(np.round(obj.utility(mean), 12), axis=1)


def questplus_values(p_users: np.ndarray, obj: Objective, turns: int = 25) -> bayes.PlanValue:
    """Exact expected results of the ``questplus`` rule on each user (rows of ``p_users``)."""
    grid = QuestPlusGrid.build()
    return bayes.evaluate_rule(lambda states, n: grid.choose(states, obj), p_users, obj.coefficients(4), turns,
                               obj.terminal(turns))
