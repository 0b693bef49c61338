"""The psychometric prior on disk: round trip, the shipped file loads, damaged files are refused by name."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nao_trainer.core.psychometric import PooledModel, session_span
from nao_trainer.errors import DataError
from nao_trainer.learn import psychometric_prior as pp


def test_round_trip_and_the_shipped_prior_loads(tmp_path):
    model = PooledModel(mu=6.5, tau=1.0, sigma=1.25, lapse=0.05)
    path = pp.save_prior(tmp_path / "sub" / "p.json", model, {"dataset_fingerprint": "x", "sessions": 3})
    assert pp.load_prior(path) == model
    assert json.loads(path.read_text())["sessions"] == 3
    shipped = pp.load_prior()
    assert shipped == pp.load_prior(pp.DEFAULT_PRIOR)
    span = session_span(shipped, np.zeros(8))
    assert 3.0 < span.lo < span.median < span.hi < 11.0


def test_fit_prior_counts_every_session():
    sessions = np.array(["a"] * 4 + ["b"] * 4)
    levels = np.array([1, 2, 3, 4] * 2)
    model, n = pp.fit_prior(sessions, levels, np.array([1, 1, 0, 0, 1, 1, 1, 0], bool))
    assert n == 2 and isinstance(model, PooledModel)


PRIOR = '{"format": "nao-trainer/psychometric-prior", "format_version": 1, "mu": 6, "tau": 1, "sigma": 1, "lapse": 0}'


@pytest.mark.parametrize("text, words", [
    ("{", "not valid JSON"),
    ('{"format": "nao-trainer/user-models", "format_version": 1}', "not a nao-trainer psychometric prior"),
    ('{"format": "nao-trainer/psychometric-prior", "format_version": 9}', "format version 9"),
    ('{"format": "nao-trainer/psychometric-prior", "format_version": 1, "mu": 6, "tau": 1, "sigma": "x", '
     '"lapse": 0}', "'sigma' must be a number"),
    ('{"format": "nao-trainer/psychometric-prior", "format_version": 1, "mu": 6, "tau": 1, "sigma": 1, '
     '"lapse": 1}', "'lapse' must lie in [0, 0.5]"),
    # issue 30: every parameter finite and in range (these raised inside numpy, or planned over nothing)
    *[(PRIOR.replace(f'"{k}": {v0}', f'"{k}": {v}'), f"key '{k}' {words}") for k, v0, v, words in [
        ("mu", 6, "NaN", "must be a finite number"), ("tau", 1, "NaN", "must be a finite number"),
        ("mu", 6, "Infinity", "must be a finite number"), ("tau", 1, "1e-300", "must lie in [0.1, 20]"),
        ("mu", 6, "1e300", "must lie in [0, 14]"), ("mu", 6, "1" * 400, "is too large to be a number"),
        ("sigma", 1, "-Infinity", "must be a finite number"), ("mu", 6, "true", "must be a number")]],
])
def test_damaged_priors_are_refused_with_the_file_named(tmp_path, text, words):
    path = tmp_path / "p.json"
    path.write_text(text)
    with pytest.raises(DataError) as err:
        pp.load_prior(path)
    assert str(path) in str(err.value) and words in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(DataError, match="file not found"):
        pp.load_prior(tmp_path / "missing.json")
