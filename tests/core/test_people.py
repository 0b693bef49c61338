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


# ----------------------------------------------------------------------------------------------
# evaluate --users sessions and evaluate --personalise: means, intervals and counts over people
# ----------------------------------------------------------------------------------------------

_SESSIONS = ["session:user_1/session_4", "session:user_1/session_5", "session:user_2/session_1",
             "session:user_3/session_1"]


def _eval_rows():
    """Rows of `evaluate`: two baselines (one row per session) and a learner (2 seeds per session)."""
    rows = []
    for i, u in enumerate(_SESSIONS):
        rows.append({"user": u, "policy": "best-fixed", "seed": None, "score": 40.0 + i, "engagement": 0.3,
                     "success": 0.9, "regret": 1.0})
        rows.append({"user": u, "policy": "fixed:2", "seed": None, "score": 40.0 + i * i, "engagement": 0.3 + i / 100,
                     "success": 0.8, "regret": 2.0 + i})
        for seed in (0, 1):
            for method, shift in (("performance", 0.0), ("qaug", 0.5 * seed + i / 10)):
                rows.append({"user": u, "policy": f"usp:{method}", "seed": seed, "score": 39.0 + i + shift,
                             "engagement": 0.3 + shift / 10, "success": 0.85, "regret": 1.5})
    return rows


def test_evaluate_on_sessions_counts_and_resamples_people_not_sessions():
    """user_1's two sessions are one person: n = 3 people, the interval is the t-interval over the
    three person means (user_1's sessions and seeds averaged first), not over 4 sessions / 8 rows."""
    from nao_trainer.experiments import comparison, reports

    rows = _eval_rows()
    by = {s["policy"]: s for s in comparison.summarise(rows, by_person=True)}
    f2 = by["fixed:2"]
    assert f2["n"] == f2["people"] == 3 and f2["users"] == 4 and f2["unit"] == "people"
    per_person = np.array([(40.0 + 41.0) / 2, 44.0, 49.0])  # user_1: sessions 0 and 1 averaged
    assert f2["score"] == pytest.approx(per_person.mean())
    assert f2["score_ci"] == pytest.approx(people.t_interval(per_person))
    d = np.array([(0.0 + 0.0) / 2, 4.0 - 2.0, 9.0 - 3.0])
    assert f2["vs_reference"]["score_diff_ci"] == pytest.approx(people.t_interval(d))
    lrn = by["usp:qaug"]  # 8 (session, seed) rows of 3 people
    assert lrn["n"] == 3
    v = np.array([np.mean([39.0 + 0.0, 39.5, 40.1, 40.6]), np.mean([41.2, 41.7]), np.mean([42.3, 42.8])])
    assert lrn["score_ci"] == pytest.approx(people.t_interval(v))
    (claim,) = [c for c in comparison.claims(rows, by_person=True) if c["a"] == "usp:qaug"]
    dq = np.array([np.mean([0.0, 0.5, 0.1, 0.6]), np.mean([0.2, 0.7]), np.mean([0.3, 0.8])])
    assert claim["n"] == 3 and claim["score_diff_ci"] == pytest.approx(people.t_interval(dq))
    # simulated users (not people): the unit stays the (user, seed) row
    rowwise = {s["policy"]: s for s in comparison.summarise(rows)}
    assert rowwise["usp:qaug"]["n"] == 8 and "people" not in rowwise["usp:qaug"]
    table = reports.format_table(list(by.values()), comparison.claims(rows, by_person=True))
    assert table.splitlines()[0].startswith("means and 95 % t-intervals over 3 people (4 sessions")
    assert "paired over people" in table


def _personalise_rows():
    rows = []
    for i, u in enumerate(_SESSIONS):
        rows.append({"user": u, "policy": "best-fixed", "assessment": None, "score": 40.0, "regret": 1.0,
                     "engagement": 0.3})
        rows.append({"user": u, "policy": "oracle", "assessment": None, "score": 41.0 + i, "regret": 0.0,
                     "engagement": 0.3})
        rows.append({"user": u, "policy": "personalised", "assessment": 0, "score": 40.0 + i * i / 2,
                     "regret": 1.0 + i, "engagement": 0.3, "matched": float(i % 2), "switches": float(i)})
    return rows


def test_evaluate_personalise_intervals_and_the_gap_bootstrap_are_over_people():
    from nao_trainer.experiments import personalisation, reports

    rows = _personalise_rows()
    by = {(s["policy"], s["assessment"]): s for s in personalisation.summarise(rows)}
    mine = by[("personalised", 0)]
    assert mine["users"] == 4 and mine["people"] == 3
    gain = np.array([(0.0 + 0.5) / 2, 2.0, 4.5])  # user_1: its two sessions averaged
    gap = np.array([(1.0 + 2.0) / 2, 3.0, 4.0])
    assert mine["d_reference"] == pytest.approx(gain.mean())
    assert mine["d_reference_ci"] == pytest.approx(people.t_interval(gain))
    assert mine["matched"] == pytest.approx(np.mean([0.5, 0.0, 1.0]))
    # the bootstrap resamples the 3 people (a person's sessions together), from the Generator given
    g = personalisation.gap_closed(rows, "personalised", 0, np.random.default_rng(7), boot=400)
    idx = np.random.default_rng(7).integers(3, size=(400, 3))
    shares = gain[idx].mean(axis=1) / gap[idx].mean(axis=1)
    assert g["people"] == 3 and g["share"] == pytest.approx(gain.mean() / gap.mean())
    assert g["share_ci"] == pytest.approx([np.percentile(shares, 2.5), np.percentile(shares, 97.5)])
    again = personalisation.gap_closed(rows, "personalised", 0, np.random.default_rng(7), boot=400)
    assert again == g  # seeded: bit-reproducible
    assert personalisation.summarise(rows) == personalisation.summarise(rows)
    text = reports.format_personalise(list(by.values()), [])
    assert text.splitlines()[0].startswith("means and 95 % t-intervals over 3 people (4 held-out sessions")


def _engagement_measurements():
    """Per-session engagement measurements (``personalisation.engagement_information``) at 6 and 25 turns."""
    p_out = [0.2, 0.4, 0.5, 0.9]
    p_eng = [0.8, 0.9, 0.4, 0.9]  # user_1's two sessions gain 0.6 and 0.5, user_2 loses 0.1, user_3 gains 0
    meas = []
    for turns in (6, 25):
        for u, a, b in zip(_SESSIONS, p_out, p_eng):
            meas.append({"user": u, "turns": turns, "outcomes": {"correct": a > 0.45, "p_true": a},
                         "outcomes+engagement": {"correct": b > 0.45, "p_true": b}})
    return meas


def test_does_engagement_help_the_match_is_summarised_over_people(tmp_path):
    """Accuracy, P(true cluster) and their difference average a person's sessions first (user_1's two count
    once) with the t-interval over the 3 people, not the 4 sessions; the row file gives them back exactly."""
    from nao_trainer.experiments import personalisation, reports

    meas = _engagement_measurements()
    got = personalisation.summarise_engagement(meas)
    assert [e["turns"] for e in got] == [6, 25]
    e = got[0]
    assert e["people"] == 3 and e["sessions"] == 4
    assert e["outcomes"]["p_true"] == pytest.approx(np.mean([0.3, 0.5, 0.9]))  # over sessions: 0.5
    assert e["outcomes"]["accuracy"] == pytest.approx(np.mean([0.0, 1.0, 1.0]))  # over sessions: 0.5
    assert e["outcomes+engagement"]["accuracy"] == pytest.approx(np.mean([1.0, 0.0, 1.0]))  # over sessions: 0.75
    d = np.array([0.55, -0.1, 0.0])
    assert e["p_true_diff"] == pytest.approx(d.mean())  # over sessions: 0.25
    assert e["p_true_diff_ci"] == pytest.approx(people.t_interval(d))
    assert "over 3 people (4 held-out sessions" in reports.format_engagement(got)
    reports.write_engagement_rows(meas, tmp_path / reports.ENGAGEMENT_ROWS_FILE)
    assert reports.read_engagement_rows(tmp_path / reports.ENGAGEMENT_ROWS_FILE) == meas
