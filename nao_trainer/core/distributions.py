"""The few distribution functions the project's intervals and tests use, straight from ``scipy.special``.

They are the functions ``scipy.stats`` calls for these distributions (its ``t``, ``chi2``, ``f`` and
``norm``: ``_sf``, ``_ppf``), so the values are the same to the bit (compared in tests/core, also for
invalid degrees of freedom: NaN in both). What differs is the import: ``scipy.special`` costs about
0.35 s of CPU, ``scipy.stats`` about 1 s, and a command such as ``study power --users clusters`` or
``evaluate`` loads nothing else of scipy. Imported lazily inside each function: every session imports
modules that use these (``core.people``), and no session asks for an interval.

Pure: no I/O.
"""
from __future__ import annotations

from typing import Any


def t_ppf(q: Any, df: Any) -> Any:
    """Quantile of Student's t with ``df`` degrees of freedom (``scipy.stats.t.ppf``)."""
    from scipy import special

    return special.stdtrit(df, q)


def t_sf(x: Any, df: Any) -> Any:
    """Upper tail P(T > x) of Student's t (``scipy.stats.t.sf``)."""
    from scipy import special

    return special.stdtr(df, -x)


def chi2_sf(x: Any, df: Any) -> Any:
    """Upper tail P(X > x) of chi-squared with ``df`` degrees of freedom (``scipy.stats.chi2.sf``)."""
    from scipy import special

    return special.chdtrc(df, x)


def f_sf(x: Any, dfn: Any, dfd: Any) -> Any:
    """Upper tail P(F > x) of Fisher's F (``scipy.stats.f.sf``)."""
    from scipy import special

    return special.fdtrc(dfn, dfd, x)


def norm_ppf(q: Any) -> Any:
    """Quantile of the standard normal (``scipy.stats.norm.ppf``)."""
    from scipy import special

    return special.ndtri(q)
