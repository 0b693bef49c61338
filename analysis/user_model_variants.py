"""Variants of the pooled psychometric user model (issue 21): which predicts held-out turns best, and how each plans.

    PYTHONPATH=. python analysis/user_model_variants.py --data DATASET_ROOT [--out FILE.json]

Every variant is a hierarchical model of success against sequence length x (3, 5, 7, 9 letters at
levels 1-4), with the participant's parameters integrated over a grid, so its prior is a finite
mixture of per-level user models, exactly what ``core.bayes`` plans over:

``probit-grid``   the shipped model (``core.psychometric``): (1 - lapse) Phi((theta - x) / sigma),
                  theta ~ N(mu, tau^2); (mu, tau, sigma, lapse) by maximum marginal likelihood over
                  ``psychometric.fit``'s coarse grid;
``probit``        the same model with the four hyperparameters fitted continuously (Nelder-Mead);
``logit``         a logistic link, (1 - lapse) / (1 + exp(-(theta - x) / s)) (the other common sigmoid
                  of psychophysics: Wichmann & Hill 2001, "The psychometric function: I", Percept.
                  Psychophys. 63:1293);
``probit-slope``  a per-participant slope: theta ~ N(mu, tau^2) and log sigma_i ~ N(m, s^2)
                  independently (a 2-D grid of components, 141 spans x 25 slopes; as s -> 0
                  it becomes ``probit`` with sigma on the slope grid);
``log-length``    the probit on log length, (1 - lapse) Phi((log theta - log x) / sigma),
                  log theta ~ N(mu, tau^2): psychometric functions of a stimulus magnitude are
                  usually fitted on its logarithm (Kingdom & Prins 2016, "Psychophysics: a practical
                  introduction", ch. 4; Weber's law), so the fall of success per added letter
                  shrinks as sequences grow;
``weibull``       (1 - lapse) exp(-(x / alpha)^beta), log alpha ~ N(mu, tau^2): the Weibull
                  function (Quick 1974; Wichmann & Hill 2001), here as the chance of recalling a
                  sequence of x items falling as a stretched exponential of its length;
``log-length-grid`` ``log-length`` fitted like the shipped model, over ``psychometric.fit``'s grid carried to
                  log length (``LOG_GRID``): the continuous ``probit`` predicts worse than the grid
                  ``probit-grid``, so the links are also compared at the shipped fitting method.

Held-out prediction (the criterion for choosing a model, as ``evaluate --user-models``): leave the
session's PERSON out (user_1 and user_4 played two sessions each: both are left out), fit the
hyperparameters on the other people's sessions, predict the held-out session's turns one at a time
from its earlier turns (posterior mixture), clip to [0.001, 0.999], mean log-likelihood per turn;
means and 95 % t-intervals over the 48 people (a person's sessions averaged), and the paired
difference to the shipped model (and between links at the same fitting method). Also the maximised log marginal likelihood on
all 50 sessions with AIC. The rule: a variant replaces the shipped model only if it predicts held-out
turns better, its paired difference to it having a 95 % interval above 0 (the target value is
reported, never used to choose: that would be fitting to the evaluated users).

Target values (reported for every variant, never used to choose one): the prior fitted on all 50
sessions (as the live ``bayes`` policy ships it), pruned to at most 300 components (largest prior
weight, each at least 1e-6 of the largest), solved for 25 turns under each target objective
(``OBJECTIVES``: ``target-p:0.75``, each turn's success probability near 75 %, and ``target-rate:0.75``,
the session's success rate near 75 %) and valued exactly on the 50 own-rate users and the 50
data-prior users of that objective's outputs (docs/results/ceiling-{own-rates,data-prior}-target-*-0.75),
summarised by ``experiments.ceiling.achievable`` beside their stored rows: the mean over people with
its 95 % interval and the paired differences to always level 2 and to the ceiling (intervals over
people; the ceiling's are conditional on these users). No share of a gap is printed (the stored
outputs give them, with Fieller intervals, where the gap excludes 0).
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, ndtr

from nao_trainer.core import bayes, evaluation, objective, people, psychometric
from nao_trainer.experiments import ceiling

LENGTHS = psychometric.LENGTHS
THETA = psychometric.THETA
LOG_THETA = np.linspace(np.log(1.5), np.log(25.0), 141)
LOG_SIGMA = np.linspace(np.log(0.2), np.log(8.0), 25)
CLIP = 1e-3
MAX_COMPONENTS = 300
HERE = Path(__file__).resolve().parent
RESULTS = HERE.parent / "docs" / "results"
OBJECTIVES = ("target-p:0.75", "target-rate:0.75")
USERS = {"own rates": "own-rates", "data prior": "data-prior"}


def folder(users: str, obj: str) -> Path:
    """The stored ceiling output of a user set under an objective (analysis/make_ceiling_results.sh)."""
    return RESULTS / f"ceiling-{USERS[users]}-{obj.replace(':', '-')}"


def _normal_weights(grid: np.ndarray, mu: float, tau: float) -> np.ndarray:
    lw = -0.5 * ((grid - mu) / tau) ** 2
    return lw - psychometric._logsumexp(lw, 0)


@dataclass(frozen=True)
class Variant:
    """A hierarchical model: ``mixture(x)`` gives the components' success per level (C, 4) and log
    prior weights (C,) from the hyperparameters ``x`` (unconstrained); ``start`` from the grid fit."""

    name: str
    mixture: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    start: Callable[[psychometric.PooledModel], np.ndarray]
    params: Callable[[np.ndarray], dict[str, float]]


def _lapse(z: float) -> float:
    return float(expit(z))


def _probit(x):
    mu, lt, ls, zl = x
    p = (1 - _lapse(zl)) * ndtr((THETA[:, None] - LENGTHS[None, :]) / np.exp(ls))
    return p, _normal_weights(THETA, mu, np.exp(lt))


def _logit(x):
    mu, lt, ls, zl = x
    p = (1 - _lapse(zl)) * expit((THETA[:, None] - LENGTHS[None, :]) / np.exp(ls))
    return p, _normal_weights(THETA, mu, np.exp(lt))


def _slope(x):
    mu, lt, m, ls, zl = x
    sig = np.exp(LOG_SIGMA)
    p = (1 - _lapse(zl)) * ndtr((THETA[:, None, None] - LENGTHS[None, None, :]) / sig[None, :, None])
    lw = _normal_weights(THETA, mu, np.exp(lt))[:, None] + _normal_weights(LOG_SIGMA, m, np.exp(ls))[None, :]
    return p.reshape(-1, 4), lw.reshape(-1)


def _log_length(x):
    mu, lt, ls, zl = x
    p = (1 - _lapse(zl)) * ndtr((LOG_THETA[:, None] - np.log(LENGTHS)[None, :]) / np.exp(ls))
    return p, _normal_weights(LOG_THETA, mu, np.exp(lt))


def _weibull(x):
    mu, lt, lb, zl = x
    p = (1 - _lapse(zl)) * np.exp(-(LENGTHS[None, :] / np.exp(LOG_THETA)[:, None]) ** np.exp(lb))
    return p, _normal_weights(LOG_THETA, mu, np.exp(lt))


def _z(lapse: float) -> float:
    q = min(max(lapse, 1e-3), 0.5)
    return float(np.log(q / (1 - q)))


def _common(x):
    return {"mu": float(x[0]), "tau": float(np.exp(x[1])), "scale": float(np.exp(x[2])), "lapse": _lapse(x[3])}


VARIANTS = (
    Variant("probit", _probit, lambda g: np.array([g.mu, np.log(g.tau), np.log(g.sigma), _z(g.lapse)]), _common),
    Variant("logit", _logit, lambda g: np.array([g.mu, np.log(g.tau), np.log(g.sigma / 1.7), _z(g.lapse)]), _common),
    Variant("probit-slope", _slope,
            lambda g: np.array([g.mu, np.log(g.tau), np.log(g.sigma), np.log(0.3), _z(g.lapse)]),
            lambda x: {"mu": float(x[0]), "tau": float(np.exp(x[1])), "log_sigma_mean": float(x[2]),
                       "log_sigma_sd": float(np.exp(x[3])), "lapse": _lapse(x[4])}),
    Variant("log-length", _log_length,
            lambda g: np.array([np.log(g.mu), np.log(g.tau / g.mu), np.log(g.sigma / g.mu), _z(g.lapse)]), _common),
    Variant("weibull", _weibull, lambda g: np.array([np.log(g.mu + g.sigma), np.log(g.tau / g.mu), np.log(3.0),
                                                      _z(g.lapse)]), _common),
)


LOG_LENGTH = next(v for v in VARIANTS if v.name == "log-length")


def _grid_mixture(g: psychometric.PooledModel) -> tuple[np.ndarray, np.ndarray]:
    return _probit(np.array([g.mu, np.log(g.tau), np.log(g.sigma), -np.inf if g.lapse == 0 else _z(g.lapse)]))


def _session_ll(counts: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(S, C) log-likelihood of each session's counts under each component."""
    q = np.clip(p, 1e-9, 1 - 1e-9)
    return counts[:, 0::2] @ np.log(q).T + counts[:, 1::2] @ np.log1p(-q).T


def log_marginal(p: np.ndarray, lw: np.ndarray, counts: np.ndarray) -> float:
    return float(psychometric._logsumexp(_session_ll(counts, p) + lw[None, :], 1).sum())


def fit(variant: Variant, counts: np.ndarray) -> tuple[np.ndarray, float]:
    """Maximum marginal likelihood of the hyperparameters (Nelder-Mead from the grid fit)."""
    x0 = variant.start(psychometric.fit(counts))

    def nll(x: np.ndarray) -> float:
        return -log_marginal(*variant.mixture(x), counts) if np.all(np.abs(x[1:]) < 12) else np.inf

    r = minimize(nll, x0, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 4000})
    return r.x, -float(r.fun)


def grid_fit(variant: Variant, counts: np.ndarray, grids: tuple[np.ndarray, ...]) -> tuple[np.ndarray, float]:
    """Maximum marginal likelihood over a product grid of the (unconstrained) hyperparameters."""
    best, arg = -np.inf, None
    for x in np.array(np.meshgrid(*grids, indexing="ij")).reshape(len(grids), -1).T:
        lm = log_marginal(*variant.mixture(x), counts)
        if lm > best:
            best, arg = lm, x
    return arg, best


#: ``psychometric.fit``'s grid carried to log length at the middle span of its mu grid (7 letters):
#: d log x = dx / 7, so tau and sigma are the shipped values divided by 7, mu their logarithms.
LOG_GRID = (np.log(psychometric._MU), np.log(psychometric._TAU / 7.0), np.log(psychometric._SIGMA / 7.0),
            np.array([-np.inf, *[_z(q) for q in psychometric._LAPSE[1:]]]))


def predict_turns(p: np.ndarray, lw: np.ndarray, levels: np.ndarray, successes: np.ndarray) -> np.ndarray:
    """Log-likelihood of each turn, predicted from the session's earlier turns (posterior mixture)."""
    c, out = np.zeros(8), []
    for lv, ok in zip(levels, successes):
        post = lw + _session_ll(c[None, :], p)[0]
        w = np.exp(post - post.max())
        q = min(max(float(w @ p[:, lv - 1] / w.sum()), CLIP), 1 - CLIP)
        out.append(np.log(q if ok else 1 - q))
        c[2 * (lv - 1) + (0 if ok else 1)] += 1
    return np.array(out)


def prune(p: np.ndarray, lw: np.ndarray, cap: int = MAX_COMPONENTS, floor: float = 1e-6
          ) -> tuple[np.ndarray, np.ndarray, float]:
    """The ``cap`` components of largest prior weight (each >= ``floor`` of the largest), renormalised,
    and the prior mass they held."""
    w = np.exp(lw - psychometric._logsumexp(lw, 0))
    keep = np.argsort(-w)[:cap]
    keep = keep[w[keep] >= floor * w.max()]
    return p[keep], w[keep] / w[keep].sum(), float(w[keep].sum())


def _ci(v: np.ndarray) -> list[float]:
    ci = evaluation.t_interval(np.asarray(v, dtype=float))
    return [float(ci[0]), float(ci[1])]


def held_out(turns, names: list[str]) -> dict[str, np.ndarray]:
    """Mean log-likelihood per turn of each held-out session, per model (its person left out), in ``names``' order."""
    per: dict[str, list[float]] = {"probit-grid": [], **{v.name: [] for v in VARIANTS}, "log-length-grid": []}
    person = np.array([people.person_of(x) for x in turns.session])
    for s in names:
        mine = turns.session == s
        rest = person != people.person_of(s)
        rest = psychometric.session_counts(turns.session[rest], turns.level[rest], turns.success[rest])
        lv, ok = turns.level[mine].astype(int), turns.success[mine].astype(bool)
        per["probit-grid"].append(predict_turns(*_grid_mixture(psychometric.fit(rest)), lv, ok).mean())
        for v in VARIANTS:
            x, _ = fit(v, rest)
            per[v.name].append(predict_turns(*v.mixture(x), lv, ok).mean())
        x, _ = grid_fit(LOG_LENGTH, rest, LOG_GRID)
        per["log-length-grid"].append(predict_turns(*LOG_LENGTH.mixture(x), lv, ok).mean())
        print(f"  held out {s}: " + ", ".join(f"{k} {val[-1]:+.4f}" for k, val in per.items()), flush=True)
    return {k: np.array(v) for k, v in per.items()}


def target_values(p: np.ndarray, w: np.ndarray, label: str, turns: int = 25) -> dict[str, dict]:
    """The plan of prior (p, w) under each objective of ``OBJECTIVES``, valued on the own-rate and
    data-prior users of that objective's stored outputs: {objective: {users: value, d_level2, d_ceiling
    (each with its interval over people), people}, "solve_seconds": {objective: s}, "components": C}."""
    out: dict[str, dict] = {"solve_seconds": {}}
    for name in OBJECTIVES:
        obj = objective.parse(name)
        t0 = time.perf_counter()
        plan = bayes.solve(p, w, obj.coefficients(p.shape[1]), turns, terminal=obj.terminal(turns))
        out["solve_seconds"][name] = time.perf_counter() - t0
        out[name] = {}
        for users in USERS:
            section = json.loads((folder(users, name) / "personalise.json").read_text())["ceiling"]
            if section["objective"] != name or int(section["turns"]) != turns:
                raise SystemExit(f"{folder(users, name)}: computed under {section['objective']}, "
                                 f"{section['turns']} turns, not {name}, {turns} turns")
            rows = section["rows"]
            rates = _user_rates(rows)
            names = list(rates)
            value = bayes.evaluate_plan(plan, np.array([rates[n] for n in names]))
            mine = [ceiling.plan_row(n, "", label, rates[n], None, value, i, turns, obj,
                                     evaluation.optimal(ceiling._table(rates[n]), turns).value)
                    for i, n in enumerate(names)]
            # always level 2 under the objective (the stored level-2 rows are in the personalise row file)
            level2 = [ceiling._level_row(n, "", "fixed:2", rates[n], 1, obj, turns) for n in names]
            s = next(e for e in ceiling.achievable(rows + level2 + mine) if e["policy"] == label)
            out[name][users] = {k: s[k] for k in ("value", "value_ci", "d_level2", "d_level2_ci", "d_ceiling",
                                                   "d_ceiling_ci", "people", "users")}
    out["components"] = int(len(w))
    return out


def _user_rates(rows: list[dict]) -> dict[str, np.ndarray]:
    import sys

    sys.path.insert(0, str(HERE))
    from live_bayes import user_rates

    return user_rates(rows)


def main() -> None:
    from nao_trainer.data.dataset import import_dataset
    from nao_trainer.learn.fitting import Turns

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="the published dataset root (clean_data, extracted)")
    ap.add_argument("--out", type=Path, help="also write the numbers as JSON here")
    args = ap.parse_args()
    turns = Turns.from_columns(import_dataset(args.data, compat="authors2018").table.columns)
    names = sorted(np.unique(turns.session).tolist())
    counts = psychometric.session_counts(turns.session, turns.level, turns.success)
    per_session = held_out(turns, names)
    ll = {k: people.per_person(names, v) for k, v in per_session.items()}  # over people, in people(names) order
    table = []
    for name in ["probit-grid"] + [v.name for v in VARIANTS] + ["log-length-grid"]:
        if name == "log-length-grid":
            x, lm = grid_fit(LOG_LENGTH, counts, LOG_GRID)
            p, lw = LOG_LENGTH.mixture(x)
            params, k = LOG_LENGTH.params(x), len(x)
        elif name == "probit-grid":
            g = psychometric.fit(counts)
            p, lw = _grid_mixture(g)
            params, k, lm = dict(g.__dict__), 4, log_marginal(p, lw, counts)
        else:
            v = next(v for v in VARIANTS if v.name == name)
            x, lm = fit(v, counts)
            p, lw = v.mixture(x)
            params, k = v.params(x), len(x)
        d = ll[name] - ll["probit-grid"]
        row = {"variant": name, "params": params, "log_marginal": lm, "aic": 2 * k - 2 * lm,
               "ll": float(ll[name].mean()), "ll_ci": _ci(ll[name]), "d": float(d.mean()),
               "d_ci": _ci(d) if np.any(d != 0) else [0.0, 0.0]}
        pp, pw, kept = prune(p, lw)
        row.update(target_values(pp, pw, name), kept_mass=kept)
        table.append(row)
        print(json.dumps(row), flush=True)

    def diff(v: dict) -> str:
        out = f"{v['value']:+.3f} [{v['value_ci'][0]:+.3f}, {v['value_ci'][1]:+.3f}]"
        for key, what in (("d_level2", "level 2"), ("d_ceiling", "ceiling")):
            ci = v[f"{key}_ci"]
            out += f"; minus {what} {v[key]:+.3f} [{ci[0]:+.3f}, {ci[1]:+.3f}]"
        return out

    who = people.people(names)
    print(f"\n{len(names)} sessions of {len(who)} people; held-out next-turn log-likelihood per turn (each session "
          "predicted with its person left out; means and 95 % CIs over people); d = paired difference to probit-grid "
          "(shipped); log marginal likelihood and AIC on all 50 sessions; the plan of the prior fitted on all 50 "
          f"valued under {' and '.join(OBJECTIVES)} on each objective's stored users "
          "(docs/results/ceiling-{own-rates,data-prior}-OBJECTIVE): mean over people [95 % CI]; paired differences "
          "to always level 2 and to the ceiling [95 % CI over people; the ceiling's conditional on these users]")
    for r in table:
        seconds = ", ".join(f"{o} {t:.1f} s" for o, t in r["solve_seconds"].items())
        print(f"  {r['variant']:<13} {r['ll']:+.4f} [{r['ll_ci'][0]:+.4f}, {r['ll_ci'][1]:+.4f}]  d {r['d']:+.4f} "
              f"[{r['d_ci'][0]:+.4f}, {r['d_ci'][1]:+.4f}]  logML {r['log_marginal']:.2f} AIC {r['aic']:.2f}  "
              f"({r['components']} components holding {100 * r['kept_mass']:.2f} % of the prior; solve {seconds})")
        for name in OBJECTIVES:
            for users in USERS:
                print(f"      {name:<16} {users:<10} {diff(r[name][users])}")
        print(f"      {r['params']}")
    print("paired differences of held-out log-likelihood per turn at the same fitting method [95 % CI]:")
    for a, b in (("logit", "probit"), ("probit-slope", "probit"), ("log-length", "probit"), ("weibull", "probit"),
                 ("log-length-grid", "probit-grid"), ("probit", "probit-grid")):
        d = ll[a] - ll[b]
        ci = _ci(d)
        print(f"  {a} - {b}: {d.mean():+.4f} [{ci[0]:+.4f}, {ci[1]:+.4f}]")
    if args.out:
        held = {k: dict(zip(names, map(float, v))) for k, v in per_session.items()}
        args.out.write_text(json.dumps({"sessions": len(names), "people": len(who), "objectives": list(OBJECTIVES),
                                        "variants": table, "held_out_per_session": held}, indent=1) + "\n")


if __name__ == "__main__":
    main()
