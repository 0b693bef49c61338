"""The on-disk cache of solved Bayes plans: reused, checked, compressed and bounded."""
from __future__ import annotations

import os

import numpy as np
import pytest

from nao_trainer.core import bayes, objective
from nao_trainer.learn import bayes_cache
from nao_trainer.learn.bayes_cache import prune, solve_cached

pytestmark = pytest.mark.skipif(not bayes.available(), reason="needs numba")

P = np.array([[0.99, 0.9, 0.5, 0.2], [0.99, 0.95, 0.85, 0.6]])
COEF = objective.parse("target:0.75").coefficients(4)


def test_a_solved_table_is_stored_compressed_and_read_back_equal(tmp_path):
    first = solve_cached(P, np.ones(2), COEF, 8, 0, tmp_path)
    (f,) = tmp_path.glob("*.npz")
    assert f.stat().st_size < first.action.nbytes / 4  # compressed (a 25-turn table: 10.5 MB -> 0.2-1.1 MB)
    again = solve_cached(P, np.ones(2), COEF, 8, 0, tmp_path)
    assert np.array_equal(again.action, first.action) and again.value == first.value
    fresh = bayes.solve(P, np.ones(2), COEF, 8)
    assert np.array_equal(fresh.action, first.action)


def test_a_file_of_another_prior_or_torn_is_ignored_and_replaced(tmp_path, capsys):
    plan = solve_cached(P, np.ones(2), COEF, 6, 0, tmp_path)
    (f,) = tmp_path.glob("*.npz")
    f.write_bytes(f.read_bytes()[:100])  # torn
    again = solve_cached(P, np.ones(2), COEF, 6, 0, tmp_path)
    assert np.array_equal(again.action, plan.action)
    assert "ignoring unreadable plan cache" in capsys.readouterr().err
    np.savez(f, action=np.zeros_like(plan.action), value=np.float64(0.0), fingerprint=np.str_("another prior"))
    assert np.array_equal(solve_cached(P, np.ones(2), COEF, 6, 0, tmp_path).action, plan.action)


def test_prune_removes_the_least_recently_used_tables_until_the_folder_fits(tmp_path):
    files = []
    for i in range(5):
        f = tmp_path / f"{i}.npz"
        f.write_bytes(b"x" * 1000)
        os.utime(f, (1000 + i, 1000 + i))  # 0 is the oldest
        files.append(f)
    os.utime(files[0], (2000, 2000))  # 0 was used last
    (tmp_path / "notes.txt").write_bytes(b"y" * 5000)  # not a table: never counted or removed
    removed = prune(tmp_path, 2500, keep=files[1])
    assert removed == [files[2], files[3], files[4]]  # oldest first; 1 kept (just written), 0 recently used
    assert sorted(p.name for p in tmp_path.iterdir()) == ["0.npz", "1.npz", "notes.txt"]
    assert prune(tmp_path, 2500) == []


def test_the_cache_stays_within_its_bound_and_a_table_in_use_survives(tmp_path, monkeypatch):
    solve_cached(P, np.ones(2), COEF, 8, 0, tmp_path)
    (used,) = tmp_path.glob("*.npz")
    size = used.stat().st_size
    monkeypatch.setattr(bayes_cache, "MAX_BYTES", int(2.5 * size))
    for h in (4, 5, 6, 7):
        os.utime(used, (1, 1))  # old, but read again below before each new table
        solve_cached(P, np.ones(2), COEF, 8, 0, tmp_path)  # a hit: touched
        solve_cached(P, np.ones(2), COEF, h, 0, tmp_path)
    assert used.exists()
    assert sum(f.stat().st_size for f in tmp_path.glob("*.npz")) <= 2.5 * size
    assert len(list(tmp_path.glob("*.npz"))) < 5
