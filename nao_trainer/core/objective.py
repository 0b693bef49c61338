"""What a study optimises: the paper's score or keeping a participant near a target success rate.

Pure: no I/O. An objective turns a participant's success probability at a level into the expected
utility of one turn played at that level:

``score``      equation (1) of the paper: +level on success, -1 on failure, so a turn at level l
               with success probability p is worth ``p (l + 1) - 1`` in expectation.
``target:R``   keep the participant succeeding at rate R (0 < R < 1, e.g. 0.75): a turn at a level
               where the participant's success probability is p is worth ``-(p - R)^2``, whatever
               its outcome. On a simulator p is known and the utility is exact; live, p is unknown
               and the utility of a level is its posterior expectation ``-E[(p - R)^2]`` (the
               squared distance of the posterior mean plus the posterior variance), which for a
               mixture of user models is the mixture of the models' utilities.

Both utilities are linear in the user model's mixture weights, which is what lets
``core.bayes`` plan exactly over them. The name of an objective (``str(obj)``) is what config
files and result tables record.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KINDS: tuple[str, ...] = ("score", "target")


@dataclass(frozen=True)
class Objective:
    kind: str = "score"
    rate: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"objective must be 'score' or 'target:R', got {self.kind!r}")
        if self.kind == "target" and (self.rate is None or not 0.0 < self.rate < 1.0):
            raise ValueError(f"target success rate R must lie strictly between 0 and 1, got {self.rate!r}")
        if self.kind == "score" and self.rate is not None:
            raise ValueError("the score objective takes no rate")

    def __str__(self) -> str:
        return "score" if self.kind == "score" else f"target:{self.rate:g}"

    def utility(self, p_level: np.ndarray) -> np.ndarray:
        """Expected utility of one turn at each level; ``p_level[..., l-1]`` = P(success at level l)."""
        p = np.asarray(p_level, dtype=float)
        if self.kind == "score":
            levels = np.arange(1, p.shape[-1] + 1, dtype=float)
            return p * (levels + 1.0) - 1.0
        return -(p - self.rate) ** 2

    def coefficients(self, levels: int = 4) -> np.ndarray:
        """(levels, 3): the utility as ``a + b p + c p^2`` per level (what ``core.bayes`` plans with)."""
        if self.kind == "score":
            return np.array([[-1.0, lv + 1.0, 0.0] for lv in range(1, levels + 1)])
        r = float(self.rate)
        return np.array([[-r * r, 2.0 * r, -1.0]] * levels)

    def unit(self) -> str:
        return "points" if self.kind == "score" else "utility (-(p - R)^2 per turn, summed)"


SCORE = Objective()


def parse(text: "str | Objective | None") -> Objective:
    """``"score"`` or ``"target:R"`` (``"target"`` alone means R = 0.75); ValueError naming the text."""
    if isinstance(text, Objective):
        return text
    if text is None:
        return SCORE
    s = str(text).strip()
    if s == "score":
        return SCORE
    kind, _, rate = s.partition(":")
    if kind == "target":
        try:
            return Objective("target", float(rate) if rate else 0.75)
        except ValueError as exc:
            if "could not convert" in str(exc):
                raise ValueError(f"objective {s!r}: R must be a number, e.g. target:0.75") from None
            raise
    raise ValueError(f"objective {s!r} is not 'score' or 'target:R' (e.g. target:0.75)")
