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


def test_a_crafted_table_with_the_right_fingerprint_is_refused_and_solved_again(tmp_path, capsys):
    """Issue 30, finding 6: a table rewritten with every action 3 (level 4) was played silently. Refused
    with its digest unchanged (the digest), and with digest and value recomputed to match (the
    re-solved states: a one-step deviation at the start beats it)."""
    plan = solve_cached(P, np.ones(2), COEF, 8, 0, tmp_path)
    (f,) = tmp_path.glob("*.npz")
    key = plan.fingerprint
    bad = np.full_like(plan.action, 3)
    with np.load(f) as z:
        stored = str(z["digest"])
    np.savez_compressed(f, action=bad, value=np.float64(plan.value), fingerprint=np.str_(key), digest=np.str_(stored))
    again = solve_cached(P, np.ones(2), COEF, 8, 0, tmp_path)
    assert np.array_equal(again.action, plan.action)
    assert "its digest does not match its table" in capsys.readouterr().err
    forged = bayes.Plan(plan.p, plan.weights, plan.coef, 8, 0, bad, plan.value, key)
    value = bayes._bayes_value_from(forged, np.zeros(8, np.int64), 0)
    for v in (plan.value, value):  # the honest value, or the crafted table's own
        np.savez_compressed(f, action=bad, value=np.float64(v), fingerprint=np.str_(key),
                            digest=np.str_(bayes_cache.digest(key, bad, v)))
        again = solve_cached(P, np.ones(2), COEF, 8, 0, tmp_path)
        assert np.array_equal(again.action, plan.action) and again.value == plan.value
        assert "it is not the plan of its inputs" in capsys.readouterr().err
        with np.load(f) as z:  # replaced by the solved table
            assert np.array_equal(z["action"], plan.action)
    assert bayes.plan_problem(plan) is None


@pytest.mark.parametrize("commit", [0, 30])
def test_plan_problem_passes_solved_plans_and_catches_a_changed_last_turn(commit):
    p = np.array([[0.99, 0.9, 0.5, 0.2], [0.99, 0.95, 0.85, 0.6], [0.9, 0.6, 0.3, 0.1]])
    for obj in ("score", "target:0.75"):
        plan = bayes.solve(p, np.array([1.0, 2.0, 1.0]), objective.parse(obj).coefficients(4), 6, commit)
        assert bayes.plan_problem(plan) is None
    last = plan.action.copy()
    n = plan.horizon - 1
    start = int(plan.offsets[n])
    last[start:] = (last[start:] + 1) % 4  # every last-turn decision moved one level
    bad = bayes.Plan(plan.p, plan.weights, plan.coef, plan.horizon, commit, last, plan.value, plan.fingerprint)
    assert bayes.plan_problem(bad) is not None


def test_a_fifo_in_place_of_a_table_does_not_block_and_is_replaced(tmp_path, capsys):
    """Issue 30, finding 6: np.load opened a FIFO and waited for a writer forever."""
    import threading

    key = bayes.fingerprint(P, np.ones(2), COEF, 6, 0)
    fifo = tmp_path / f"{key[:32]}.npz"
    os.mkfifo(fifo)
    out: list = []
    worker = threading.Thread(target=lambda: out.append(solve_cached(P, np.ones(2), COEF, 6, 0, tmp_path)), daemon=True)
    worker.start()
    worker.join(300)  # a hang limit, not a timing bound: the solve takes well under a second
    if worker.is_alive():  # blocked in open(): give it a writer so the test run can go on
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        os.close(fd)
        worker.join(60)
        pytest.fail("solve_cached blocked on a FIFO in place of its table")
    assert np.array_equal(out[0].action, bayes.solve(P, np.ones(2), COEF, 6).action)
    assert "not a regular file" in capsys.readouterr().err
    assert fifo.is_file()  # the solved table took its place


def test_a_failed_write_leaves_no_temporary_file(tmp_path, monkeypatch, capsys):
    """Issue 30, finding 6: a write that fails (disk full) left ``.<key>.tmp-<pid>.npz`` behind."""
    import errno

    def full(file, **arrays):
        fh = open(file, "wb") if isinstance(file, (str, os.PathLike)) else file
        fh.write(b"PK\x03\x04" + b"\0" * 1000)
        fh.flush()
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", full)
    plan = solve_cached(P, np.ones(2), COEF, 6, 0, tmp_path)
    assert plan.horizon == 6 and "cannot write plan cache" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
