"""People, not sessions: who a row is about, and paired comparisons over people.

Pure: no I/O. The published data are 50 sessions of 48 people (``user_1`` and ``user_4`` played two
sessions each), so every claim about "participants" counts, folds and resamples people:

``person_of``       the person of a session or user name (``session:user_1/session_4`` -> ``user_1``;
                    a name without a session part is its own person);
``by_person``       per-person means of per-session values (a person's sessions averaged, so two
                    sessions of one person are not two independent observations);
``paired``          mean and 95 % t-interval of policy - reference over the people both have;
``fieller``         the ratio of two paired means (a "share of a gap") with Fieller's 95 % interval,
                    and None when the denominator's own interval contains 0: a ratio whose
                    denominator cannot be told from 0 has no finite interval (Fieller 1954, J. R.
                    Stat. Soc. B 16, 175), so it is not printed.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from nao_trainer.core import distributions

_SESSION = re.compile(r"^(?:session:)?([^/]+)/[^/]+$")


def person_of(name: str) -> str:
    """``session:user_1/session_4`` and ``user_1/session_4`` -> ``user_1``; anything else: itself."""
    m = _SESSION.match(str(name))
    return m.group(1) if m else str(name)


def people(names) -> list[str]:
    """The distinct people of some session or user names, sorted."""
    return sorted({person_of(n) for n in names})


def by_person(values: Mapping[str, float]) -> dict[str, float]:
    """Per-person mean of per-session (or per-user) values."""
    acc: dict[str, list[float]] = {}
    for name, v in values.items():
        acc.setdefault(person_of(name), []).append(float(v))
    return {p: float(np.mean(v)) for p, v in sorted(acc.items())}


def _t_quantile(q: float, df: int) -> float:
    return float(distributions.t_ppf(q, df))


def t_interval(v: np.ndarray, level: float = 0.95) -> list[float] | None:
    v = np.asarray(v, dtype=float)
    if v.size < 2:
        return None
    half = _t_quantile(0.5 + level / 2, v.size - 1) * v.std(ddof=1) / np.sqrt(v.size)
    return [float(v.mean() - half), float(v.mean() + half)]


def paired(mine: Mapping[str, float], other: Mapping[str, float]) -> tuple[float | None, list[float] | None, int]:
    """(mean, 95 % t-interval, people) of mine - other, paired by person (sessions averaged first)."""
    a, b = by_person(mine), by_person(other)
    common = [p for p in a if p in b]
    if not common:
        return None, None, 0
    d = np.array([a[p] - b[p] for p in common])
    return float(d.mean()), t_interval(d), len(common)


@dataclass(frozen=True)
class Ratio:
    share: float
    ci: list[float] | None  # None: Fieller's set is not a bounded interval
    denominator: float
    denominator_ci: list[float]


def fieller(num: np.ndarray, den: np.ndarray, level: float = 0.95) -> Ratio | None:
    """mean(num) / mean(den) over paired units (people) with Fieller's interval; None when the
    denominator's t-interval contains 0 (then no share is reported)."""
    x, y = np.asarray(num, dtype=float), np.asarray(den, dtype=float)
    n = x.size
    if n < 2 or y.size != n:
        return None
    t = _t_quantile(0.5 + level / 2, n - 1)
    a, b = x.mean(), y.mean()
    vaa, vbb = x.var(ddof=1) / n, y.var(ddof=1) / n
    vab = float(np.cov(x, y, ddof=1)[0, 1]) / n
    den_ci = [float(b - t * np.sqrt(vbb)), float(b + t * np.sqrt(vbb))]
    if den_ci[0] <= 0.0 <= den_ci[1]:
        return None
    # (a - r b)^2 <= t^2 (vaa - 2 r vab + r^2 vbb): a quadratic in r, bounded since b^2 > t^2 vbb
    qa = b * b - t * t * vbb
    qb = -2.0 * (a * b - t * t * vab)
    qc = a * a - t * t * vaa
    disc = qb * qb - 4 * qa * qc
    ci = None if disc < 0 else sorted([float((-qb - np.sqrt(disc)) / (2 * qa)), float((-qb + np.sqrt(disc)) / (2 * qa))])
    return Ratio(float(a / b), ci, float(b), den_ci)


def others(names, i: int) -> np.ndarray:
    """Indices of the names whose person is not row ``i``'s (leave one PERSON out)."""
    me = person_of(list(names)[i])
    return np.array([j for j, n in enumerate(names) if person_of(n) != me], dtype=np.int64)


def per_person(names, values: np.ndarray) -> np.ndarray:
    """``values`` (one per name) averaged per person, in ``people(names)`` order."""
    return np.array(list(by_person(dict(zip(names, np.asarray(values, dtype=float)))).values()))
