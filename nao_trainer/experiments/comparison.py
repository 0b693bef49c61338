"""Compare policies on a set of simulated users: what ``nao-trainer evaluate`` computes.

Policies (``--policies``, comma-separated):

``fixed:L``            always level L (1..4)
``best-fixed``         the fixed level with the highest expected score on the user's *training* simulator
``random``             uniform over the allowed actions
``oracle``             the finite-horizon optimum on the user's *true* tables (regret 0 by definition)
``staircase:R[@L]``    R = 1u1d or 2d1u (``core.baselines.Staircase``), starting at level L (default 2)
``usp:METHOD``         a Q-learner trained on the user's training simulator, then frozen
``usp-learning:METHOD`` the same learner, still learning during the evaluated episodes

Trained policies: ``seeds`` independent learners per (user, method), ``episodes`` episodes each
(the paper's grid: 10,000), seeds derived from (base seed, user name, method, seed index). Tabular
policies are evaluated exactly (``core.evaluation.evaluate``); staircases and still-learning
learners by Monte Carlo over ``mc_episodes`` episodes per (user, seed).

Each row is one (user, policy, seed) with the score per episode, mean engagement and success rate
per turn, and the regret against the per-user oracle. ``summarise`` aggregates per policy with
95 % t-intervals over (user, seed) rows, or over PEOPLE for users that are sessions of people
(``by_person``: a person's seeds and sessions averaged first), and paired differences to a reference policy.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nao_trainer.core import baselines, evaluation, people, processes
from nao_trainer.core.batch import BatchLearner
from nao_trainer.core.qlearning import METHODS, QConfig, QLearner
from nao_trainer.errors import ConfigError
from nao_trainer.learn import policy_files
from nao_trainer.learn.parallel import fan_out
from nao_trainer.learn.users import User

DEFAULT_POLICIES: tuple[str, ...] = (
    "fixed:1", "fixed:2", "fixed:3", "fixed:4", "best-fixed", "random", "staircase:1u1d@2", "staircase:2d1u@2",
    "usp:performance", "usp:shaping", "usp:qaug", "usp-learning:performance", "usp-learning:shaping",
    "usp-learning:qaug", "oracle",
)
#: The comparison's learned strategies: a user-specific Q-learner trained on the user's simulator, frozen (``usp``)
#: or learning on (``usp-learning``). The comparison's strategy names (``fixed:N``, ``best-fixed``, ``random``,
#: ``oracle``, ``staircase:...`` and these) are its own vocabulary, parsed here, not the live policy plug-ins.
LEARNED: tuple[str, ...] = ("usp", "usp-learning")


def parse_policy(spec: str) -> tuple[str, Any]:
    """(kind, argument) of a policy spec; ConfigError naming the bad spec otherwise."""
    text = spec.strip()
    kind, _, arg = text.partition(":")
    if kind in ("best-fixed", "random", "oracle") and not arg:
        return kind, None
    if kind == "fixed" and arg in ("1", "2", "3", "4"):
        return kind, int(arg)
    if kind == "staircase":
        rule, _, start = arg.partition("@")
        if rule in baselines.STAIRCASE_RULES and (start in ("", "1", "2", "3", "4")):
            return kind, (rule, int(start or 2))
    if kind in LEARNED and arg in METHODS:
        return kind, arg
    raise ConfigError(f"--policies: unknown policy {text!r}; use fixed:1..4, best-fixed, random, oracle, "
                      f"staircase:1u1d[@L], staircase:2d1u[@L], usp:METHOD or usp-learning:METHOD "
                      f"(METHOD one of {', '.join(METHODS)})")


@dataclass(frozen=True)
class EvalSpec:
    policies: tuple[str, ...] = DEFAULT_POLICIES
    process: str = "paper"
    turns: int = 25
    seeds: int = 10
    episodes: int = 10_000
    mc_episodes: int = 1_000
    seed: int = 0
    config: QConfig = field(default_factory=QConfig)

    def __post_init__(self) -> None:
        for p in self.policies:
            parse_policy(p)
        processes.get(self.process)
        for name in ("turns", "seeds", "episodes"):
            if getattr(self, name) < 1:
                raise ConfigError(f"--{name} must be >= 1, got {getattr(self, name)}")
        if self.mc_episodes < 2:
            raise ConfigError(f"--mc-episodes must be >= 2, got {self.mc_episodes}")


def _user_key(name: str) -> int:
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")


def _seed(spec: EvalSpec, user: str, what: int, k: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(spec.seed, spawn_key=(_user_key(user), what, k))


def train_learners(user: User, methods: Sequence[str], spec: EvalSpec) -> dict[str, list[QLearner]]:
    """``spec.seeds`` learners per method trained on the user's training simulator."""
    if not methods:
        return {}
    sim = user.train
    agents = [(m, k) for m in methods for k in range(spec.seeds)]
    p = np.stack([sim.p_success] * len(agents))
    e = np.stack([sim.engagement] * len(agents))
    rngs = [np.random.Generator(np.random.PCG64(_seed(spec, user.name, METHODS.index(m), k))) for m, k in agents]
    res = BatchLearner(p, e, [m for m, _ in agents], spec.config, spec.process, "auto").run(
        spec.episodes, spec.turns, rngs)
    out: dict[str, list[QLearner]] = {m: [] for m in methods}
    for i, (m, _k) in enumerate(agents):
        out[m].append(QLearner(m, spec.config, res.q[i], res.h[i], res.h_counts[i], res.visits[i], spec.process))
    return out


def evaluate_user(user: User, spec: EvalSpec, given: dict[str, list[QLearner]] | None = None) -> list[dict[str, Any]]:
    """Rows of every policy of ``spec`` on one user (see the module docstring).

    ``given``: trained learners per method (e.g. read from policy files) instead of training here.
    """
    proc = processes.get(spec.process)
    truth = user.truth
    p, e, T = truth.p_success, truth.engagement, spec.turns
    oracle = evaluation.optimal(p, T, proc)
    parsed = [(s, *parse_policy(s)) for s in spec.policies]
    methods = sorted({arg for _, kind, arg in parsed if kind in LEARNED}, key=METHODS.index)
    learners = dict(given or {})
    learners.update(train_learners(user, [m for m in methods if m not in learners], spec))
    rows = []

    def add(name: str, out: evaluation.Outcome, seed: int | None) -> None:
        # Rounded to 1e-9 (far below any difference reported): keeps the JSON files small.
        rows.append({"user": user.name, "cluster": user.cluster, "policy": name, "seed": seed,
                     "score": round(out.score, 9), "engagement": round(out.engagement, 9),
                     "success": round(out.success, 9), "regret": round(oracle.value - out.score, 9),
                     "visits": np.round(out.visits, 4).tolist(), "samples": out.samples,
                     "success_var": None if out.success_var is None else round(out.success_var, 12)})

    for name, kind, arg in parsed:
        if kind == "fixed":
            add(name, evaluation.evaluate(evaluation.fixed_level_policy(arg, proc), p, e, T, proc), None)
        elif kind == "best-fixed":
            level = baselines.best_fixed_level(user.train.p_success, user.train.engagement, T)
            add(name, evaluation.evaluate(evaluation.fixed_level_policy(level, proc), p, e, T, proc), None)
            rows[-1]["level"] = level
        elif kind == "random":
            add(name, evaluation.evaluate(evaluation.uniform_policy(proc), p, e, T, proc), None)
        elif kind == "oracle":
            add(name, evaluation.evaluate(oracle.policy, p, e, T, proc), None)
        elif kind == "staircase":
            rng = np.random.default_rng(_seed(spec, user.name, 10 + baselines.STAIRCASE_RULES.index(arg[0]), arg[1]))
            add(name, evaluation.monte_carlo(baselines.Staircase(*arg), p, e, spec.mc_episodes, rng, T, proc), None)
        elif kind == "usp":
            for k, lr in enumerate(learners[arg]):
                add(name, evaluation.evaluate(baselines.learner_table(lr, proc), p, e, T, proc), k)
        elif kind == "usp-learning":
            for k, lr in enumerate(learners[arg]):
                rng = np.random.default_rng(_seed(spec, user.name, 20 + METHODS.index(arg), k))
                add(name, evaluation.monte_carlo(baselines.KeepLearning(lr), p, e, spec.mc_episodes, rng, T, proc), k)
    return rows


def run(users: Sequence[User], spec: EvalSpec, workers: int = 2, backend: str | None = None,
        given: dict[str, dict[str, list[QLearner]]] | None = None) -> list[dict[str, Any]]:
    """All rows, users fanned out through ``learn.parallel``; ``given[user name]``: see ``evaluate_user``."""
    given = given or {}
    parts = fan_out(evaluate_user, [(u, spec, given.get(u.name)) for u in users], workers, backend)
    return [row for part in parts for row in part]


def policy_file_learners(users: Sequence[User], folder: Any, spec: EvalSpec) -> dict[str, dict[str, list[QLearner]]]:
    """Learners read from a folder of policy files (``usp_<cluster>_<method>.json``) for cluster users.

    Each file must be made for ``spec.process`` and trained on the user's training simulator
    (fingerprint); otherwise a one-line DataError.
    """
    methods = sorted({arg for s in spec.policies for kind, arg in [parse_policy(s)] if kind in LEARNED},
                     key=METHODS.index)
    out: dict[str, dict[str, list[QLearner]]] = {}
    for user in users:
        for method in methods:
            path = Path(folder) / policy_files.policy_filename(user.cluster, method)
            payload = policy_files.read_policy_file(path, spec.process)
            policy_files.check_simulator(payload, user.train, path)
            out.setdefault(user.name, {})[method] = [policy_files.learner_from_payload(payload, path)]
    return out


def _ci(values: np.ndarray) -> list[float] | None:
    ci = evaluation.t_interval(values)
    return None if ci is None else [ci[0], ci[1]]


def _unit(r: dict[str, Any], i: int, by_person: bool) -> str | int:
    """The unit of row ``i``: its person, or the row itself."""
    return people.person_of(r["user"]) if by_person else i


def _over(values: dict[Any, list[float]]) -> np.ndarray:
    """One value per unit, in first-seen order: the mean of its rows (a person's seeds and sessions together)."""
    return np.array([v[0] if len(v) == 1 else float(np.mean(v)) for v in values.values()])


def summarise(rows: list[dict[str, Any]], reference: str = "best-fixed", by_person: bool = False) -> list[dict[str, Any]]:
    """Per policy: means and 95 % t-intervals; paired difference to ``reference``.

    ``by_person`` (users that are sessions of people, ``--users sessions``): the unit is the PERSON,
    a person's rows (seeds and sessions) averaged first, so means, intervals and ``people`` count
    people (48 in the published data, not 50 sessions). Otherwise the unit is the (user, seed) row.
    The paired difference compares each row with the reference's row of the same user (the
    reference has one row per user), averaged per unit like the values.
    """
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    ref = {r["user"]: r for r in rows if r["policy"] == reference}
    out = []
    for pol in policies:
        mine = [r for r in rows if r["policy"] == pol]
        units = {_unit(r, i, by_person) for i, r in enumerate(mine)}
        entry: dict[str, Any] = {"policy": pol, "n": len(units) if by_person else len(mine),
                                 "users": len({r["user"] for r in mine}),
                                 "unit": "people" if by_person else "rows"}
        if by_person:
            entry["people"] = len(units)
        for key in ("score", "engagement", "success", "regret"):
            acc: dict[str, list[float]] = {}
            for i, r in enumerate(mine):
                acc.setdefault(_unit(r, i, by_person), []).append(r[key])
            v = _over(acc)
            entry[key] = float(v.mean())
            entry[f"{key}_ci"] = _ci(v)
        if ref and pol != reference:
            ds: dict[str, list[float]] = {}
            de: dict[str, list[float]] = {}
            for i, r in enumerate(r for r in mine if r["user"] in ref):
                ds.setdefault(_unit(r, i, by_person), []).append(r["score"] - ref[r["user"]]["score"])
                de.setdefault(_unit(r, i, by_person), []).append(r["engagement"] - ref[r["user"]]["engagement"])
            d, e = _over(ds), _over(de)
            entry["vs_reference"] = {"reference": reference, "score_diff": float(d.mean()), "score_diff_ci": _ci(d),
                                     "engagement_diff": float(e.mean()), "engagement_diff_ci": _ci(e)}
        out.append(entry)
    return out


def paired(rows: list[dict[str, Any]], a: str, b: str, by_person: bool = False) -> dict[str, Any] | None:
    """Difference a - b in score and engagement over (user, seed) pairs present in both (None if absent);
    ``by_person``: the pairs averaged per person first, the interval and ``n`` over people."""
    rb = {(r["user"], r["seed"]): r for r in rows if r["policy"] == b}
    pairs = [(r, rb[(r["user"], r["seed"])]) for r in rows if r["policy"] == a and (r["user"], r["seed"]) in rb]
    if not pairs:
        return None
    ds: dict[str, list[float]] = {}
    de: dict[str, list[float]] = {}
    for i, (x, y) in enumerate(pairs):
        ds.setdefault(_unit(x, i, by_person), []).append(x["score"] - y["score"])
        de.setdefault(_unit(x, i, by_person), []).append(x["engagement"] - y["engagement"])
    d, e = _over(ds), _over(de)
    return {"a": a, "b": b, "n": len(d), "unit": "people" if by_person else "rows",
            "score_diff": float(d.mean()), "score_diff_ci": _ci(d),
            "engagement_diff": float(e.mean()), "engagement_diff_ci": _ci(e)}


def claims(rows: list[dict[str, Any]], by_person: bool = False) -> list[dict[str, Any]]:
    """The paper's engagement-feedback claim, retested: shaping and qaug vs the performance-only learner."""
    out = []
    for kind in LEARNED:
        for method in ("shaping", "qaug"):
            d = paired(rows, f"{kind}:{method}", f"{kind}:performance", by_person)
            if d is not None:
                out.append(d)
    return out
