"""What a study optimises: the paper's score, or keeping a participant near a target success rate.

Pure: no I/O. Two questions hide behind "keep the participant at 75 %", and they rank policies
differently, so they are two objectives:

``score``          equation (1) of the paper: +level on success, -1 on failure, so a turn at level l
                   with success probability p is worth ``p (l + 1) - 1`` in expectation.
``target-p:R``     *each turn* near R: a turn at a level where the participant's true success
                   probability is p is worth ``-(p - R)^2``, summed over the session. This is what a
                   planner can optimise turn by turn (the optimal-difficulty view of adaptive
                   training: every item should be at the participant's R-threshold, as QUEST places
                   each trial at its threshold, Watson & Pelli 1983; Watson 2017). It is convex in p: a
                   policy that alternates between two levels is penalised even when its success rate
                   is exactly R. The probability p is never observed: on a simulator it is known and
                   the utility exact; live, the utility of a level is its posterior expectation
                   ``-E[(p - R)^2]``. ``target:R`` is the old name of this objective (an alias).
``target-rate:R``  *the session's success rate* near R: with S the successes of an H-turn session,
                   the session is worth ``-H (S/H - R)^2`` (= -(S - H R)^2 / H), whatever the levels.
                   This is what a transformed staircase and a training protocol aim at: an n-down/1-up
                   staircase converges to the rate where ``p^n = 1/2`` (Levitt 1971, J. Acoust. Soc.
                   Am. 49, 467: 70.7 % for 2-down/1-up, 79.4 % for 3-down/1-up), and training studies
                   report and control the participant's observed rate (the "85 % rule", Wilson et al.
                   2019, Nat. Commun. 10, 4646, is a statement about the error rate trained at). Its
                   expectation is ``-H [(E rate - R)^2 + Var rate]``: the bias of the rate and its
                   spread, so a policy that reacts to outcomes (and so lowers the variance of S) is
                   rewarded for it. It is not a sum of per-turn terms: the exact Bayes planner
                   (``core.bayes``) plans it with a terminal reward on the counts its state already
                   holds; live, its expectation is over the posterior predictive of the outcomes.

``score`` and ``target-p`` are sums of per-turn utilities linear in a user model's mixture weights
(``coefficients``); ``target-rate`` has zero per-turn utility and a terminal value ``terminal(H)``
over the session's successes. The name of an objective (``str(obj)``) is what config files and
result tables record.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KINDS: tuple[str, ...] = ("score", "target-p", "target-rate")
ALIASES: dict[str, str] = {"target": "target-p"}
SYNTAX = "'score', 'target-p:R' or 'target-rate:R' (e.g. target-rate:0.75)"


@dataclass(frozen=True)
class Objective:
    kind: str = "score"
    rate: float | None = None

    def __post_init__(self) -> None:
        if self.kind in ALIASES:
            object.__setattr__(self, "kind", ALIASES[self.kind])
        if self.kind not in KINDS:
            raise ValueError(f"objective must be {SYNTAX}, got {self.kind!r}")
        if self.kind != "score" and (self.rate is None or not 0.0 < self.rate < 1.0):
            raise ValueError(f"target success rate R must lie strictly between 0 and 1, got {self.rate!r}")
        if self.kind == "score" and self.rate is not None:
            raise ValueError("the score objective takes no rate")

    def __str__(self) -> str:
        return "score" if self.kind == "score" else f"{self.kind}:{self.rate:g}"

    @property
    def is_target(self) -> bool:
        """Either target objective (a rate R to keep the participant at)."""
        return self.kind != "score"

    @property
    def per_session(self) -> bool:
        """The utility is a function of the session's successes, not a sum over turns."""
        return self.kind == "target-rate"

    def utility(self, p_level: np.ndarray) -> np.ndarray:
        """Expected utility of one turn at each level; ``p_level[..., l-1]`` = P(success at level l).

        Under ``target-rate`` there is no per-turn utility; this returns ``-(p - R)^2``, the greedy
        proxy used to rank levels one turn at a time (QUEST+'s placement, the planner past its
        horizon). Session values under every objective come from ``fixed_value``/``from_moments``."""
        p = np.asarray(p_level, dtype=float)
        if self.kind == "score":
            levels = np.arange(1, p.shape[-1] + 1, dtype=float)
            return p * (levels + 1.0) - 1.0
        return -(p - self.rate) ** 2

    def coefficients(self, levels: int = 4) -> np.ndarray:
        """(levels, 3): the per-turn utility as ``a + b p + c p^2`` per level (what ``core.bayes``
        plans with); all zero under ``target-rate`` (see ``terminal``)."""
        if self.kind == "score":
            return np.array([[-1.0, lv + 1.0, 0.0] for lv in range(1, levels + 1)])
        if self.kind == "target-rate":
            return np.zeros((levels, 3))
        r = float(self.rate)
        return np.array([[-r * r, 2.0 * r, -1.0]] * levels)

    def terminal(self, turns: int) -> np.ndarray | None:
        """G[S] for S = 0..turns successes: the session's value under ``target-rate``, else None."""
        if self.kind != "target-rate":
            return None
        s = np.arange(turns + 1, dtype=float)
        return -turns * (s / turns - float(self.rate)) ** 2

    def from_moments(self, visits: np.ndarray, p_level: np.ndarray, rate_mean: float, rate_var: float,
                     turns: int) -> float:
        """A session's expected value from its expected turns per level and the mean and variance of
        its success rate S/H (exact for level-only users under every objective)."""
        if self.kind == "target-rate":
            return float(-turns * ((rate_mean - float(self.rate)) ** 2 + rate_var))
        return float(np.asarray(visits, dtype=float) @ self.utility(p_level))

    def fixed_value(self, p_level: np.ndarray, turns: int) -> np.ndarray:
        """Session value of always playing each level (``p_level[..., l-1]``): under ``target-rate``
        ``-H (p - R)^2 - p (1 - p)`` (the binomial variance of S/H is ``p (1 - p) / H``)."""
        p = np.asarray(p_level, dtype=float)
        if self.kind == "target-rate":
            return -turns * (p - float(self.rate)) ** 2 - p * (1.0 - p)
        return turns * self.utility(p)

    def unit(self) -> str:
        if self.kind == "score":
            return "points"
        if self.kind == "target-rate":
            return "utility (-H (S/H - R)^2 per session)"
        return "utility (-(p - R)^2 per turn, summed)"


SCORE = Objective()


def parse(text: "str | Objective | None") -> Objective:
    """``"score"``, ``"target-p:R"`` or ``"target-rate:R"`` (``target:R`` = ``target-p:R``; R
    omitted means 0.75); ValueError naming the text."""
    if isinstance(text, Objective):
        return text
    if text is None:
        return SCORE
    s = str(text).strip()
    if s == "score":
        return SCORE
    kind, _, rate = s.partition(":")
    if kind in KINDS[1:] or kind in ALIASES:
        try:
            return Objective(kind, float(rate) if rate else 0.75)
        except ValueError as exc:
            if "could not convert" in str(exc):
                raise ValueError(f"objective {s!r}: R must be a number, e.g. {kind}:0.75") from None
            raise
    raise ValueError(f"objective {s!r} is not {SYNTAX}")
