"""What personalisation can win: the Bayes ceiling beside every evaluation, for either objective.

For users whose success depends on the level only (the per-session users, the level-only
clusters), ``core.bayes`` gives exact values:

``ceiling``      the Bayes-adaptive policy whose prior is uniform over the evaluated users
                 themselves: the highest mean any policy can reach on these users without being
                 told which user it faces (its per-user values average to that mean);
``bayes-loo``    the same planner with the prior made of the *other* users only (point masses,
                 leave one out): what a planner that knows the population, but not this user, earns;
``oracle``       the per-user optimum under the objective (for level-only users: always the user's
                 best level), the upper end of the oracle gap.

Every policy of an evaluation is also scored under the chosen objective from its expected turns
per level (exact for level-only users: a turn's utility depends on its level only), and its
*share of the achievable gap* is ``mean(policy - best fixed) / mean(ceiling - best fixed)`` over
people, given with Fieller's 95 % interval only when the gap's own interval excludes 0
(``core.people.fieller``). ``multi_session`` values S sessions of the same participant
with the counts carried over (module ``core.bayes``: ``commit``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nao_trainer.core import bayes, evaluation, mdp, people
from nao_trainer.core.objective import Objective
from nao_trainer.errors import DataError
from nao_trainer.core.psychometric import PooledModel
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.experiments import adaptive
from nao_trainer.experiments.personalisation import own_rates_user
from nao_trainer.learn.bayes_cache import solve_cached
from nao_trainer.learn.fitting import FitOptions, Turns, fit_cluster
from nao_trainer.learn.users import beta_concentration, hold_out, leave_one_person_out, read_turns, session_user


def level_rates(sim: Any) -> np.ndarray:
    """Mean success per level over the reachable turn states (4,)."""
    return np.array([float(sim.p_success[(mdp.LEVEL == lv) & mdp.REACHABLE].mean()) for lv in (1, 2, 3, 4)])


def is_level_only(sim: Any, tol: float = 1e-9) -> bool:
    p = np.asarray(sim.p_success)
    return all(np.ptp(p[(mdp.LEVEL == lv) & mdp.REACHABLE]) <= tol for lv in (1, 2, 3, 4))


def user_rates(users: Sequence[Any]) -> dict[str, np.ndarray]:
    """name -> success per level of each user's truth; DataError when a user is not level-only."""
    out = {}
    for u in users:
        if not is_level_only(u.truth):
            raise DataError(f"user {u.name}: its success depends on more than the level, so the per-level Bayes "
                            "ceiling does not bound it; use level-only or per-session users")
        out[u.name] = level_rates(u.truth)
    return out


def _solve(p: np.ndarray, w: np.ndarray, obj: Objective, turns: int, commit: int, cache: Path | None) -> bayes.Plan:
    return solve_cached(p, w, obj.coefficients(p.shape[1]), turns, commit, cache, terminal=obj.terminal(turns))


def plan_row(name: str, cluster: str, policy: str, p: np.ndarray, e: np.ndarray | None, value: bayes.PlanValue,
             i: int, turns: int, obj: Objective, oracle_score: float) -> dict[str, Any]:
    visits = value.visits[i]
    score = float(visits @ (p * np.arange(2, 6) - 1.0))
    row = {"user": name, "cluster": cluster, "policy": policy, "seed": None, "assessment": None,
           "score": round(score, 9), "success": round(float(value.successes[i]) / turns, 9),
           "regret": round(oracle_score - score, 9), "visits": np.round(visits, 4).tolist(), "samples": 0,
           "utility": round(float(value.session[i]), 9), "objective": str(obj)}
    if value.successes_var is not None:
        row["success_var"] = round(float(value.successes_var[i]) / turns ** 2, 12)
    if e is not None:
        row["engagement"] = round(float(visits @ e / turns), 9)
    return row


def bayes_rows(names: Sequence[str], clusters: Sequence[str], p: np.ndarray, e: np.ndarray | None,
               obj: Objective, turns: int = 25, loo: bool = False, cache: Path | None = None
               ) -> list[dict[str, Any]]:
    """``ceiling`` rows (one solve), and with ``loo`` also ``bayes-loo`` rows (one solve per user)."""
    p = np.asarray(p, dtype=float)
    oracle = [evaluation.optimal(_table(pi), turns).value for pi in p]
    plan = _solve(p, np.ones(len(p)), obj, turns, 0, cache)
    value = bayes.evaluate_plan(plan, p)
    rows = [plan_row(n, c, "ceiling", p[i], None if e is None else e[i], value, i, turns, obj, oracle[i])
            for i, (n, c) in enumerate(zip(names, clusters))]
    if loo:
        for i, (n, c) in enumerate(zip(names, clusters)):
            others = people.others(names, i)  # leave the PERSON out (user_1 and user_4 have two sessions)
            plan_i = _solve(p[others], np.ones(len(others)), obj, turns, 0, cache)
            v = bayes.evaluate_plan(plan_i, p[i:i + 1])
            rows.append(plan_row(n, c, "bayes-loo", p[i], None if e is None else e[i], v, 0, turns, obj, oracle[i]))
    return rows


def prior_rows(priors: dict[str, tuple[np.ndarray, np.ndarray]], rates: dict[str, np.ndarray],
               clusters: dict[str, str], obj: Objective, turns: int = 25, cache: Path | None = None,
               policy: str = "bayes") -> list[dict[str, Any]]:
    """The planner with each user's own prior (``priors[name] = (p (K, 4), weights)``, e.g. the
    clusters fitted without the user, as the live ``bayes`` policy uses them), run on the user."""
    out = []
    for name, (pk, wk) in priors.items():
        p = rates[name]
        plan = _solve(np.asarray(pk, dtype=float), np.asarray(wk, dtype=float), obj, turns, 0, cache)
        v = bayes.evaluate_plan(plan, p[None])
        out.append(plan_row(name, clusters.get(name, ""), policy, p, None, v, 0, turns, obj,
                           evaluation.optimal(_table(p), turns).value))
        out[-1]["predicted"] = round(plan.value, 9)  # what the prior expects the plan to earn
    return out


def report(rows: list[dict[str, Any]], rates: dict[str, np.ndarray], train_rates: dict[str, np.ndarray],
           clusters: dict[str, str], obj: Objective, turns: int = 25, loo: bool = False,
           priors: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] | None = None, cache: Path | None = None,
           fitted_questplus: bool = False) -> dict[str, Any]:
    """Every policy of an evaluation (``rows``, not changed) beside the ceiling, under ``obj``: the
    ``achievable`` summary and the rows added here (ceiling, bayes, fixed levels, oracle).
    ``priors[policy][user] = (p (K, 4), weights)``: the planner with that prior, one row per user."""
    mine = [dict(r) for r in rows if r["user"] in rates]
    add_utility(mine, rates, obj)
    names = list(rates)
    p = np.array([rates[n] for n in names])
    extra = objective_rows(rates, train_rates, clusters, obj, turns, {r["policy"] for r in mine})
    extra += bayes_rows(names, [clusters.get(n, "") for n in names], p, None, obj, turns, loo, cache)
    for policy, per_user in (priors or {}).items():  # e.g. "bayes": the fitted clusters, per user
        extra += prior_rows(per_user, rates, clusters, obj, turns, cache, policy)
    extra += adaptive_rows(rates, clusters, obj, turns, fitted=fitted_questplus)
    return {"objective": str(obj), "turns": turns, "summary": achievable(mine + extra), "rows": extra,
            "prior_checks": prior_checks(extra, priors or {}, p)}


def prior_checks(rows: list[dict[str, Any]], priors: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]],
                 p: np.ndarray) -> list[dict[str, Any]]:
    """For each prior: what it predicts (per-level success mean and SD, averaged over the users' own
    priors; for a planner also the value it expects, ``predicted``) beside what the users show and
    what the planner achieves on them. A prior whose predicted value is far above the achieved one
    believes in more to win than the users have."""
    out = []
    for policy, per_user in priors.items():
        checks = [prior_check(np.asarray(pk), np.asarray(wk), p) for pk, wk in per_user.values()]
        mine = [r for r in rows if r["policy"] == policy and "predicted" in r]
        entry = {"prior": policy, "prior_mean": np.mean([c["prior_mean"] for c in checks], axis=0).round(4).tolist(),
                 "prior_sd": np.mean([c["prior_sd"] for c in checks], axis=0).round(4).tolist(),
                 "users_mean": checks[0]["users_mean"], "users_sd": checks[0]["users_sd"]}
        if mine:
            entry["predicted_value"] = float(np.mean([r["predicted"] for r in mine]))
            entry["achieved_value"] = float(np.mean([r["utility"] for r in mine]))
        out.append(entry)
    grid = adaptive.QuestPlusGrid.build()
    for name, g in (("questplus (uniform grid)", grid), ("questplus-fitted (all users)", grid.fitted(p))):
        out.append({"prior": name, **prior_check(g.psi, np.exp(g.log_prior), p)})
    out.append({"prior": "ceiling (uniform over the users)", **prior_check(p, np.ones(len(p)), p)})
    return out


def adaptive_rows(rates: dict[str, np.ndarray], clusters: dict[str, str], obj: Objective, turns: int = 25,
                  start: int = 2, fitted: bool = True) -> list[dict[str, Any]]:
    """The adaptive baselines of ``experiments.adaptive``, exact, each seeing every outcome at once:
    staircases 2-down/1-up and 3-down/1-up from level ``start``, the staircase tuned on the other
    people (rule and start), QUEST+ by expected entropy with a uniform prior and (``fitted``) with
    the prior fitted on the other people, and QUEST+ by its posterior mean."""
    names = list(rates)
    p = np.array([rates[n] for n in names])
    out = []

    def stair(n: str, need: int, st: int, policy: str) -> dict[str, Any]:
        r = adaptive.staircase_exact(need, st, rates[n], turns, obj)
        return {"user": n, "cluster": clusters.get(n, ""), "policy": policy, "seed": None, "assessment": None,
                "score": round(r["score"], 9), "success": round(r["success"], 9),
                "visits": np.round(r["visits"], 4).tolist(), "samples": 0, "utility": round(r["utility"], 9),
                "objective": str(obj), "success_var": round(r["success_var"], 12)}

    for need in (2, 3):
        out += [stair(n, need, start, f"staircase-{need}d1u@{start}") for n in names]
    for i, n in enumerate(names):
        others = people.others(names, i)
        need, st = adaptive.tuned_staircase(p[others], obj, turns) if len(others) else (2, start)
        out.append(stair(n, need, st, "staircase-tuned") | {"rule": f"{need}d1u@{st}"})
    grid = adaptive.QuestPlusGrid.build()
    oracle = [evaluation.optimal(_table(pi), turns).value for pi in p]
    for policy, method in (("questplus", "entropy"), ("questplus-mean", "mean")):
        qv = adaptive.questplus_values(p, obj, turns, method, grid)
        out += [plan_row(n, clusters.get(n, ""), policy, p[i], None, qv, i, turns, obj, oracle[i])
                for i, n in enumerate(names)]
    if fitted:
        for i, n in enumerate(names):
            others = people.others(names, i)
            if not len(others):
                continue
            qv = adaptive.questplus_values(p[i:i + 1], obj, turns, "entropy", grid.fitted(p[others]))
            out.append(plan_row(n, clusters.get(n, ""), "questplus-fitted", p[i], None, qv, 0, turns, obj, oracle[i]))
    return out


def prior_check(p_models: np.ndarray, weights: np.ndarray, rates: np.ndarray) -> dict[str, Any]:
    """Prior-predictive check per level: the mean and SD of success a prior (models ``p_models``
    with ``weights``) predicts for a participant, beside the users' mean and SD (their rates)."""
    pk, w = np.asarray(p_models, dtype=float), np.asarray(weights, dtype=float)
    w = w / w.sum()
    mean = w @ pk
    sd = np.sqrt(np.maximum(w @ pk ** 2 - mean ** 2, 0.0))
    r = np.asarray(rates, dtype=float)
    return {"prior_mean": mean.round(4).tolist(), "prior_sd": sd.round(4).tolist(),
            "users_mean": r.mean(axis=0).round(4).tolist(),
            "users_sd": (r.std(axis=0, ddof=1) if len(r) > 1 else np.zeros(r.shape[1])).round(4).tolist()}


def _table(p_level: np.ndarray) -> np.ndarray:
    return np.clip(np.asarray(p_level, dtype=float)[mdp.LEVEL - 1], 0.0, 1.0)


def add_utility(rows: list[dict[str, Any]], rates: dict[str, np.ndarray], obj: Objective,
                visits_key: str = "visits") -> None:
    """Set ``utility`` of every row from its expected turns per level and the mean and variance of its
    success rate (exact for level-only users). Under ``target-rate`` a row without the variance
    (``success_var``, e.g. from a results file written before it was recorded) gets no utility."""
    for r in rows:
        if "utility" in r and r.get("objective") == str(obj):
            continue
        r.pop("utility", None)
        var = r.get("success_var")
        if obj.per_session and var is None:
            continue
        turns = float(np.sum(r[visits_key]))
        r["utility"] = round(obj.from_moments(np.asarray(r[visits_key], dtype=float), rates[r["user"]],
                                              float(r.get("success", 0.0)), float(var or 0.0), int(round(turns))), 9)
        r["objective"] = str(obj)


def objective_rows(rates: dict[str, np.ndarray], train_rates: dict[str, np.ndarray], clusters: dict[str, str],
                   obj: Objective, turns: int, have: Sequence[str] = ()) -> list[dict[str, Any]]:
    """Fixed-level rows judged under the objective: ``fixed:L`` (those not in ``have``),
    ``best-fixed-objective`` (the level best under the objective on the user's training rates),
    ``pooled-fixed`` (the level best on average over the evaluated users) and ``oracle-objective``
    (each user's own best level)."""
    pooled = int(np.argmax(np.round(np.mean([obj.fixed_value(p, turns) for p in rates.values()], axis=0), 12)))
    out = []
    for name, p in rates.items():
        choices = {f"fixed:{lv + 1}": lv for lv in range(4) if f"fixed:{lv + 1}" not in have}
        choices["best-fixed-objective"] = int(np.argmax(np.round(obj.fixed_value(train_rates[name], turns), 12)))
        choices["pooled-fixed"] = pooled
        choices["oracle-objective"] = int(np.argmax(np.round(obj.fixed_value(p, turns), 12)))
        for policy, lv in choices.items():
            if policy == "oracle-objective" and obj.per_session:
                out.append(_rate_oracle_row(name, clusters.get(name, ""), p, obj, turns))
            else:
                out.append(_level_row(name, clusters.get(name, ""), policy, p, lv, obj, turns))
    return out


def rate_oracle(p: np.ndarray, obj: Objective, turns: int) -> tuple[float, np.ndarray, float, float]:
    """The optimum of a user with known rates under ``target-rate``: its state is (turn, successes
    so far), so the exact policy is a (turns x successes) backward induction; no fixed level
    reaches it (it steers the count, e.g. easier after a run of successes). Returns (value, turns
    per level, E rate, Var rate)."""
    p = np.asarray(p, dtype=float)
    v = obj.terminal(turns).astype(float)
    act = np.zeros((turns, turns + 1), dtype=np.int64)
    for t in range(turns - 1, -1, -1):
        q = p[None, :] * v[1:t + 2, None] + (1 - p[None, :]) * v[:t + 1, None]  # (S = 0..t, levels)
        act[t, :t + 1] = np.argmax(np.round(q, 12), axis=1)
        v = q.max(axis=1)
    dist = np.zeros(turns + 1)
    dist[0] = 1.0
    visits = np.zeros(len(p))
    for t in range(turns):
        a = act[t]
        np.add.at(visits, a, dist)
        pa = p[a]
        new = dist * (1 - pa)
        new[1:] += (dist * pa)[:-1]
        dist = new
    s = np.arange(turns + 1, dtype=float)
    mean = float(dist @ s)
    return float(v[0]), visits, mean / turns, max(float(dist @ s ** 2) - mean ** 2, 0.0) / turns ** 2


def _rate_oracle_row(name: str, cluster: str, p: np.ndarray, obj: Objective, turns: int) -> dict[str, Any]:
    value, visits, rate, var = rate_oracle(p, obj, turns)
    return {"user": name, "cluster": cluster, "policy": "oracle-objective", "seed": None, "assessment": None,
            "score": round(float(visits @ (p * np.arange(2, 6) - 1.0)), 9), "success": round(rate, 9),
            "visits": np.round(visits, 4).tolist(), "samples": 0, "utility": round(value, 9),
            "objective": str(obj), "success_var": round(var, 12)}


def _level_row(name: str, cluster: str, policy: str, p: np.ndarray, lv: int, obj: Objective, turns: int
               ) -> dict[str, Any]:
    visits = np.zeros(4)
    visits[lv] = turns
    score = float(visits @ (p * np.arange(2, 6) - 1.0))
    return {"user": name, "cluster": cluster, "policy": policy, "seed": None, "assessment": None,
            "score": round(score, 9), "success": round(float(p[lv]), 9), "visits": visits.tolist(), "samples": 0,
            "utility": round(float(obj.fixed_value(p, turns)[lv]), 9), "objective": str(obj), "level": lv + 1,
            "success_var": round(float(p[lv] * (1 - p[lv])) / turns, 12)}


def _by_user(rows: list[dict[str, Any]], policy: str, key: str, length: Any = None) -> dict[str, float]:
    """Mean over seeds of ``key`` per user for one policy (and assessment length)."""
    acc: dict[str, list[float]] = {}
    for r in rows:
        if r["policy"] == policy and r.get("assessment") == length:
            acc.setdefault(r["user"], []).append(float(r[key]))
    return {u: float(np.mean(v)) for u, v in acc.items()}


def share_of_gap(rows: list[dict[str, Any]], policy: str, key: str, top: str, reference: str,
                 length: Any = None) -> dict[str, Any]:
    """mean(policy - reference) / mean(top - reference) over PEOPLE (a person's sessions averaged),
    with Fieller's 95 % interval, reported only when the gap's own interval excludes 0
    (``core.people.fieller``); otherwise ``share`` is None and ``why`` says so. The gap and its
    interval are always given."""
    ref, hi, mine = _by_user(rows, reference, key), _by_user(rows, top, key), _by_user(rows, policy, key, length)
    users = sorted(set(ref) & set(hi) & set(mine))
    if not users:
        return {"share": None, "share_ci": None, "gap": None, "gap_ci": None, "why": "no common users"}
    gain = people.by_person({u: mine[u] - ref[u] for u in users})
    gap = people.by_person({u: hi[u] - ref[u] for u in users})
    g = np.array([gap[p] for p in gap])
    r = people.fieller(np.array([gain[p] for p in gap]), g)
    gap_ci = people.t_interval(g)
    if r is None:
        return {"share": None, "share_ci": None, "gap": float(g.mean()), "gap_ci": gap_ci,
                "why": "the gap's 95 % interval contains 0: no share"}
    return {"share": r.share, "share_ci": r.ci, "gap": r.denominator, "gap_ci": r.denominator_ci,
            "why": None if r.ci is not None else "Fieller's set is unbounded"}


#: the paired references of every comparison: (label, policy rows compared with)
REFERENCES: tuple[tuple[str, str], ...] = (("d_level2", "fixed:2"), ("d_reference", "best-fixed-objective"),
                                           ("d_pooled", "pooled-fixed"), ("d_ceiling", "ceiling"),
                                           ("d_bayes_loo", "bayes-loo"))


def achievable(rows: list[dict[str, Any]], key: str = "utility", reference: str = "best-fixed-objective",
               oracle: str = "oracle-objective") -> list[dict[str, Any]]:
    """Per (policy, assessment length): mean ``key`` with a 95 % t-interval over PEOPLE (seeds and a
    person's sessions averaged), the paired difference to each of ``REFERENCES`` (level 2, the best
    fixed level chosen on the user's training data, the level best for the population, the
    ceiling, leave-one-out Bayes) with paired 95 % intervals over people, and shares of the
    achievable and oracle gaps only where the gap is distinguishable from 0 (``share_of_gap``).

    The ceiling is solved on the evaluated users themselves (its prior is uniform over them), and
    is not re-solved per resample: intervals that involve it are conditional on these users
    (``ceiling_conditional``)."""
    keys = list(dict.fromkeys((r["policy"], r.get("assessment")) for r in rows if key in r))
    refs = {label: _by_user(rows, pol, key) for label, pol in REFERENCES}
    refs["d_reference"] = _by_user(rows, reference, key)
    out = []
    for pol, length in keys:
        mine = _by_user(rows, pol, key, length)
        per_person = people.by_person(mine)
        v = np.array(list(per_person.values()))
        entry: dict[str, Any] = {"policy": pol, "assessment": length, "users": len(mine), "people": len(v),
                                 "value": float(v.mean()), "value_ci": _ci(v), "ceiling_conditional": True}
        for label, other in refs.items():
            d, ci, _ = people.paired(mine, other)
            entry[label], entry[f"{label}_ci"] = d, ci
        entry["achievable_share"] = share_of_gap(rows, pol, key, "ceiling", reference, length)
        # the same against the level best for the whole population (a fixed level a study can choose
        # without the participant's data; the project's rule uses their nearest cluster)
        entry["achievable_share_pooled"] = share_of_gap(rows, pol, key, "ceiling", "pooled-fixed", length)
        entry["oracle_share"] = share_of_gap(rows, pol, key, oracle, reference, length)
        out.append(entry)
    return out


def _ci(v: np.ndarray) -> list[float] | None:
    return people.t_interval(np.asarray(v, dtype=float))


def multi_session(p: np.ndarray, obj: Objective, turns: int = 25, sessions: Sequence[int] = (1, 2, 5, 10),
                  cache: Path | None = None, loo: bool = False, names: Sequence[str] | None = None
                  ) -> list[dict[str, Any]]:
    """Value per session (mean over S sessions, per user) of S sessions of the same participant:

    ``pooled-fixed``  the level best for the population (mean utility over the users), every session;
    ``explore-commit``  the Bayes-optimal first session given that the posterior-best level is then
                    played for the S - 1 other sessions (prior uniform over the users; with ``loo``
                    also the other users only), a policy a study can run;
    ``bound``       the Bayes-optimal first session, then the true rates revealed for free: no policy
                    that is not told the user can do better;
    ``oracle``      the user's best level every session.

    ``names``: the users' names; means, intervals and leave-one-out are then by person."""
    p = np.asarray(p, dtype=float)
    names = list(names) if names is not None else [f"u{i}" for i in range(len(p))]
    pp = lambda v: people.per_person(names, v)  # noqa: E731
    u = obj.utility(p)
    best = int(np.argmax(np.round(u.mean(axis=0), 12)))
    one = bayes.evaluate_plan(_solve(p, np.ones(len(p)), obj, turns, 0, cache), p).session
    out = []
    for s in sessions:
        vals: dict[str, np.ndarray] = {"pooled-fixed": turns * u[:, best],
                                       "oracle": turns * u.max(axis=1),
                                       "bound": (one + (s - 1) * turns * u.max(axis=1)) / s}
        plan = _solve(p, np.ones(len(p)), obj, turns, (s - 1) * turns, cache)
        vals["explore-commit"] = bayes.evaluate_plan(plan, p).total / s
        if loo:
            v = np.empty(len(p))
            for i in range(len(p)):
                others = people.others(names, i)
                plan_i = _solve(p[others], np.ones(len(others)), obj, turns, (s - 1) * turns, cache)
                v[i] = bayes.evaluate_plan(plan_i, p[i:i + 1]).total[0] / s
            vals["explore-commit-loo"] = v
        gap = pp(vals["oracle"] - vals["pooled-fixed"])
        for name, v in vals.items():
            d, v = pp(v - vals["pooled-fixed"]), pp(v)
            ratio = people.fieller(d, gap)  # None when the oracle gap's interval contains 0
            out.append({"sessions": s, "policy": name, "value_per_session": float(v.mean()), "value_ci": _ci(v),
                        "d_best_fixed": float(d.mean()), "d_best_fixed_ci": _ci(d),
                        "oracle_share": None if ratio is None else ratio.share,
                        "oracle_share_ci": None if ratio is None else ratio.ci, "people": len(v),
                        "objective": str(obj)})
    return out


# ----------------------------------------------------------------------------------------------
# The per-session users without the policy training (what the ceiling needs)
# ----------------------------------------------------------------------------------------------


def _session_one(turns: Any, session: str, k: int, n_init: int, seed: int, session_prior: float | None) -> Any:

    split = hold_out(turns, session, k, n_init, seed)
    members = split.rest.subset(split.labels == split.cluster)
    fit = fit_cluster(members, split.cluster, FitOptions(k=k, seed=seed, cv_folds=1), np.random.default_rng(seed),
                      np.zeros(4), np.zeros(4), {"compat": None, "left_out": session})
    name, cid = f"session:{session}", str(split.cluster)
    if session_prior is None:
        return session_user(name, split.own, members, fit.simulator, cid, fit.simulator)
    return own_rates_user(name, split.own, fit.simulator, session_prior, cid)


def session_users(source: Path, compat: str | None, k: int = 3, session_prior: float | None = None, seed: int = 0,
                  workers: int = 2, n_init: int = 50) -> list[Any]:
    """The held-out per-session users of ``evaluate --personalise`` (same clustering and fits), without
    training any policy: ``session_prior`` None = the data prior, a number = own rates shrunk by it."""

    turns = Turns.from_columns(read_turns(Path(source), compat).columns)
    return leave_one_person_out(turns, _session_one, (k, n_init, seed, session_prior), k, source, workers)


def evaluation_ceiling(rows: list[dict[str, Any]], rates: dict[str, np.ndarray], train: dict[str, np.ndarray],
                       clusters: dict[str, str], obj: Objective, turns: int = 25, loo: bool = False,
                       priors: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] | None = None,
                       sessions: Sequence[int] = (), fitted_questplus: bool = False) -> dict[str, Any]:
    """The ceiling section of an evaluation: ``report`` and, for ``sessions`` (e.g. 2, 5, 10), the
    value of that many sessions of the same participant (``multi_session``)."""
    out = report(rows, rates, train, clusters, obj, turns, loo, priors, fitted_questplus=fitted_questplus)
    if sessions and obj.per_session:  # commit turns score per turn; a rate objective is per session
        out["multi_session_note"] = f"not computed under {obj}: commit turns have no per-session rate"
    elif sessions:
        p = np.array([rates[n] for n in rates])
        out["multi_session"] = multi_session(p, obj, turns, (1, *sessions), loo=loo, names=list(rates))
    return out


def comparison_inputs(users: Sequence[Any]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, str]]:
    """Rates, training rates and clusters of the compared users (``evaluate``; level-only users)."""
    return (user_rates(users), {u.name: level_rates(u.train) for u in users},
            {u.name: u.cluster for u in users})


def personalise_inputs(result: dict[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray],
                                                        dict[str, str], dict[str, dict[str, Any]]]:
    """Rates, training rates, clusters and the live priors per held-out user (``evaluate --personalise``):
    ``bayes`` with the fitted clusters, ``bayes-psychometric`` with the pooled psychometric model
    fitted on the other sessions."""

    sims = [UserSimulator.from_dict(u) for u in result["users"]]
    rates = {s.name: level_rates(s) for s in sims}
    fits = result["fits"]
    train = {n: np.array(fits[n]["train_rates"]) for n in rates}
    clusters = {n: str(fits[n]["cluster"]) for n in rates}
    priors = {"bayes": {n: (np.array(fits[n]["prior"]["p"]), np.array(fits[n]["prior"]["w"])) for n in rates},
              "bayes-psychometric": {n: PooledModel(**fits[n]["psychometric"]).mixture() for n in rates}}
    return rates, train, clusters, priors



# ----------------------------------------------------------------------------------------------
# How much of the oracle gap is noise: the spread of true rates the beta-binomial fit supports
# ----------------------------------------------------------------------------------------------


def noise_corrected_oracle(counts: dict[str, np.ndarray], obj: Objective, turns: int = 25, shrink: float = 2.0,
                           draws: int = 20000, rng: np.random.Generator | None = None) -> dict[str, Any]:
    """The fixed-level oracle gap, E[max_l V_l(p)] - max_l E[V_l(p)], two ways, by person:

    ``own_rates``   over the people's own success per level (their sessions' counts pooled, shrunk by
                    ``shrink`` pseudo-turns toward the level's mean): the "own rates" users, whose
                    spread is mostly binomial noise of 5-7 turns per level;
    ``population``  over rates drawn from the per-level Beta the beta-binomial fit supports (mean
                    and between-person variance by the method of moments, ``learn.users.
                    beta_concentration``: observed variance minus binomial noise), levels drawn
                    independently: the gap that exists if people differ as much as the data say.

    ``counts[name]`` = (s1, f1, ..., s4, f4) of a session; ``V_l`` = ``obj.fixed_value``."""

    rng = rng or np.random.default_rng(0)
    per: dict[str, np.ndarray] = {}
    for name, c in counts.items():
        key = people.person_of(name)
        per[key] = per.get(key, np.zeros(8)) + np.asarray(c, dtype=float)
    c = np.array(list(per.values()))
    wins, n = c[:, 0::2], c[:, 0::2] + c[:, 1::2]
    m = wins.sum(axis=0) / np.maximum(n.sum(axis=0), 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rates = np.where(n > 0, wins / np.maximum(n, 1), m)
    kappa = np.array([beta_concentration(rates[:, lv], n[:, lv]) for lv in range(4)])
    own = (wins + shrink * m) / (n + shrink)
    mc = np.clip(m, 1e-6, 1 - 1e-6)  # a level every person passed (or failed) has no spread to draw from
    draw = rng.beta(mc * kappa, (1 - mc) * kappa, size=(draws, 4))
    out: dict[str, Any] = {"objective": str(obj), "people": len(c), "level_mean": m.tolist(),
                           "kappa": kappa.tolist(), "between_sd": np.sqrt(m * (1 - m) / (kappa + 1)).tolist()}
    for label, p in (("own_rates", own), ("population", draw)):
        v = np.array([obj.fixed_value(pi, turns) for pi in p])
        gap = v.max(axis=1) - v[:, int(np.argmax(v.mean(axis=0)))]
        out[label] = {"oracle_gap": float(gap.mean()), "oracle_gap_ci": None if label == "population" else _ci(gap),
                      "best_fixed_level": int(np.argmax(v.mean(axis=0))) + 1,
                      "oracle_levels": np.bincount(v.argmax(axis=1), minlength=4).tolist() if label == "own_rates"
                      else (np.bincount(v.argmax(axis=1), minlength=4) / len(v)).round(3).tolist()}
    g_own, g_pop = out["own_rates"]["oracle_gap"], out["population"]["oracle_gap"]
    out["noise_share"] = None if g_own <= 0 else float(1 - g_pop / g_own)
    return out
