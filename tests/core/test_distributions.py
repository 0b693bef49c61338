"""core.distributions gives scipy.stats' values to the bit, for valid and invalid arguments alike: the
intervals and tests of the evaluation, the fits and the study analysis do not move by the lighter import."""
from __future__ import annotations

import numpy as np

from nao_trainer.core import distributions


def _grid():
    rng = np.random.default_rng(7)
    df = np.concatenate([[0.0, -1.0, np.nan, np.inf, 0.5, 1.0, 2.0, 1e6], rng.uniform(0.1, 200, 2000),
                         np.arange(1.0, 300.0)])
    x = np.concatenate([[0.0, np.inf, np.nan, 1e-300, 50.0], rng.uniform(0, 20, df.size - 5)])
    q = np.concatenate([[0.0, 1.0, 0.5, 0.975, 0.025], rng.uniform(0, 1, df.size - 5)])
    return df, x, q, rng.uniform(0.5, 300, df.size)


def _same(a, b) -> bool:
    return np.array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float), equal_nan=True)


def test_each_function_equals_scipy_stats_to_the_bit():
    from scipy import stats  # here: every worker collects this file, and scipy.stats costs 1 s to import

    df, x, q, df2 = _grid()
    assert _same(distributions.t_ppf(q, df), stats.t.ppf(q, df))
    assert _same(distributions.t_ppf(0.975, df), stats.t.ppf(0.975, df))
    assert _same(distributions.t_sf(x, df), stats.t.sf(x, df))
    assert _same(distributions.chi2_sf(x, df), stats.chi2.sf(x, df))
    assert _same(distributions.f_sf(x, df, df2), stats.f.sf(x, df, df2))
    assert _same(distributions.norm_ppf(q), stats.norm.ppf(q))
    assert float(distributions.t_ppf(0.975, 10)) == float(stats.t.ppf(0.975, 10))  # scalars as the callers pass


def test_a_command_without_fits_does_not_load_scipy_stats():
    import subprocess
    import sys

    code = ("import sys; from nao_trainer.core import distributions, people; from nao_trainer.study import power; "
            "people.t_interval([1.0, 2.0, 4.0]); power._z(0.8); distributions.t_sf(1.0, 3.0); "
            "print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stderr[-2000:]
