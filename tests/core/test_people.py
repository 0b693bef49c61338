"""People, not sessions: person names, paired intervals over people, Fieller shares only when the
denominator's interval excludes 0, and leave-one-PERSON-out folds."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import people


def test_person_of_session_names():
    assert people.person_of("session:user_1/session_4") == "user_1"
    assert people.person_of("user_4/session_3") == "user_4"
    assert people.person_of("cluster-2") == "cluster-2"
    names = ["session:user_1/session_4", "session:user_1/session_5", "session:user_2/session_1"]
    assert people.people(names) == ["user_1", "user_2"]
    assert people.others(names, 0).tolist() == [2]  # user_1's other session is left out with it
    assert people.by_person(dict(zip(names, [1.0, 3.0, 5.0]))) == {"user_1": 2.0, "user_2": 5.0}


def test_paired_difference_averages_a_persons_sessions_first():
    mine = {"a/s1": 1.0, "a/s2": 3.0, "b/s1": 2.0, "c/s1": 4.0}
    ref = {"a/s1": 0.0, "a/s2": 0.0, "b/s1": 1.0, "c/s1": 1.0}
    d, ci, n = people.paired(mine, ref)
    assert n == 3 and d == pytest.approx((2.0 + 1.0 + 3.0) / 3)
    assert ci[0] < d < ci[1]


def test_a_share_is_given_only_when_its_denominator_excludes_zero():
    rng = np.random.default_rng(3)
    den = 1.0 + 0.3 * rng.standard_normal(40)
    num = 0.5 * den + 0.1 * rng.standard_normal(40)
    r = people.fieller(num, den)
    assert r is not None and r.denominator_ci[0] > 0
    assert r.ci[0] < r.share < r.ci[1] and r.share == pytest.approx(num.mean() / den.mean())
    # Fieller's interval covers the true ratio 0.5 and is wider than the delta method's at small gaps
    assert r.ci[0] < 0.5 < r.ci[1]
    noisy = 0.05 + rng.standard_normal(40)  # a gap that cannot be told from 0
    assert people.fieller(num, noisy) is None


def test_the_ceiling_report_prints_no_share_of_a_gap_around_zero():
    from nao_trainer.cli.ceiling_report import format_section
    from nao_trainer.experiments import ceiling

    rng = np.random.default_rng(0)
    rows = []
    for i in range(30):
        u = f"session:user_{i}/session_1"
        ref = rng.normal()
        rows += [{"user": u, "policy": "best-fixed-objective", "utility": ref},
                 {"user": u, "policy": "ceiling", "utility": ref + rng.normal(0.0, 1.0)},  # gap ~ 0
                 {"user": u, "policy": "oracle-objective", "utility": ref + 2.0 + 0.1 * rng.normal()},
                 {"user": u, "policy": "x", "utility": ref + 1.0 + 0.1 * rng.normal()}]
    summary = ceiling.achievable(rows)
    x = next(s for s in summary if s["policy"] == "x")
    assert x["achievable_share"]["share"] is None and "contains 0" in x["achievable_share"]["why"]
    assert x["oracle_share"]["share"] == pytest.approx(0.5, abs=0.05) and x["oracle_share"]["share_ci"]
    text = format_section({"objective": "target-rate:0.75", "turns": 25, "summary": summary})
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("x "))
    assert line.rstrip().endswith("]") and " - " in line  # the achievable share is "-", the oracle share given
    assert "30 sessions of 30 people" in text


def _turns(sessions: list[str], rng: np.random.Generator):
    from nao_trainer.core import mdp
    from nao_trainer.learn.fitting import Turns

    n = 25
    states = rng.choice(np.flatnonzero(mdp.REACHABLE), size=n * len(sessions))
    return Turns(np.repeat(np.array(sessions), n), states, rng.random(n * len(sessions)) < 0.7,
                 rng.random(n * len(sessions)), np.ones(n * len(sessions)), np.ones(n * len(sessions)))


def test_folds_leave_the_person_out():
    """hold_out never trains on another session of the held-out person, every session is still
    evaluated, and the guard counts people, not sessions."""
    from nao_trainer.errors import DataError
    from nao_trainer.learn.users import hold_out, leave_one_person_out

    sessions = ["user_1/session_4", "user_1/session_5"] + [f"user_{i}/session_1" for i in range(2, 8)]
    turns = _turns(sessions, np.random.default_rng(1))
    split = hold_out(turns, "user_1/session_4", 2, 2, 0)
    assert set(np.unique(split.own.session)) == {"user_1/session_4"}
    assert not any(s.startswith("user_1/") for s in np.unique(split.rest.session))
    assert len(np.unique(split.rest.session)) == 6
    got = leave_one_person_out(turns, _held_out_sessions, (), 2, "t", workers=1)
    assert [g[0] for g in got] == sorted(sessions)
    assert all(not any(r.startswith(g[0].split("/")[0] + "/") for r in g[1]) for g in got)
    # 5 people in 7 sessions are too few for K = 3 (needs 7 people): the message counts people
    few = _turns(["a/s1", "a/s2", "b/s1", "c/s1", "d/s1", "e/s1", "f/s1"][:6] + ["e/s2"], np.random.default_rng(2))
    with pytest.raises(DataError, match="5 people \\(7 sessions\\) are too few"):
        leave_one_person_out(few, _held_out_sessions, (), 3, "t", workers=1)


def _held_out_sessions(turns, session):
    from nao_trainer.learn.users import hold_out

    split = hold_out(turns, session, 2, 2, 0)
    return session, sorted(np.unique(split.rest.session).tolist())
