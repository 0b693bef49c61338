"""Evaluate the personalisation pipeline on held-out sessions: ``nao-trainer evaluate --personalise``.

For each real session i (leave its person out, as ``learn.users``' per-session users):

* the sessions without i are clustered again (K clusters); every cluster gets its default fit
  (``learn.effects``) from its members' turns, and one more *generic* simulator is fitted on all
  of them pooled; the prior of each cluster is its number of sessions;
* session i is the user (``learn.users.session_user``: its success per level shrunk toward its
  nearest cluster, its engagement per level), never seen by any fit or policy below;
* a Q-learner (``method``, default ``performance``) is trained on every cluster simulator (the
  user-specific policies) and on the generic one.

Policies scored on user i over a 25-turn session, assessment turns included:

``fixed:2``          always level 2;
``best-fixed``       the best fixed level on the user's training simulator (its nearest cluster's);
``generic``          the policy trained on the pooled data, frozen;
``paper@A``          the paper's pipeline: A assessment turns, the most likely cluster, its policy;
``posterior-ev@A``   A assessment turns, then the candidate (each cluster's policy, each fixed level)
                     with the highest posterior expected value, re-decided every turn (the
                     anti-flip-flop margin), per-cluster tables as fitted (``kappa = inf``);
``personalised@A``   the same with the per-level Beta posteriors learning (``kappa``): the whole
                     pipeline (``core.assessment``);
``oracle``           the finite-horizon optimum on the user's true tables.

Tabular policies are evaluated exactly; the pipelines by Monte Carlo (``mc_episodes`` per user).
``engagement_information`` measures, on the sessions' real turns, whether the engagement
likelihood improves the match to the session's cluster.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nao_trainer.core import assessment, baselines, evaluation, mdp, people, posterior, psychometric
from nao_trainer.core.qlearning import METHODS, QConfig
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.core.assessment import Choice
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.experiments.comparison import EvalSpec, train_learners
from nao_trainer.learn.fitting import FitOptions, Turns, fit_cluster
from nao_trainer.learn.users import User, hold_out, leave_one_person_out, level_only, read_turns, session_user

PIPELINES: tuple[str, ...] = ("paper", "posterior-ev", "personalised")


@dataclass(frozen=True)
class PersonaliseSpec:
    """``session_prior``: how the held-out session's success per level is shrunk toward its
    cluster: None = ``learn.users.session_user`` (a Beta prior whose strength is estimated from the
    cluster's sessions, the default user set of ``evaluate --users sessions``), or a number of
    pseudo-turns (e.g. 2: the session's own rates, barely shrunk) to ask what personalisation wins
    on users as different from their clusters as the raw sessions are."""

    lengths: tuple[int, ...] = tuple(range(13))
    session_prior: float | None = None
    levels: tuple[int, ...] = assessment.DEFAULT_LEVELS
    kappa: float = 10.0
    margin: float = 0.5
    method: str = "performance"
    episodes: int = 10_000
    seeds: int = 1
    mc_episodes: int = 500
    turns: int = 25
    seed: int = 0
    config: QConfig = field(default_factory=QConfig)

    def __post_init__(self) -> None:
        if not self.lengths or any(a < 0 or a > self.turns for a in self.lengths):
            raise ConfigError(f"--assessment: lengths must lie in 0..{self.turns}, got {list(self.lengths)}")
        if self.method not in METHODS:
            raise ConfigError(f"--personalise-method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if not self.kappa > 0:
            raise ConfigError(f"--kappa must be > 0 (inf: no per-level learning), got {self.kappa}")
        if self.margin < 0:
            raise ConfigError(f"--margin must be >= 0, got {self.margin}")
        if self.session_prior is not None and not self.session_prior > 0:
            raise ConfigError(f"--session-prior must be 'data' or a number > 0, got {self.session_prior}")
        if self.mc_episodes < 2 or self.episodes < 1 or self.seeds < 1:
            raise ConfigError("--mc-episodes must be >= 2, --episodes and --seeds >= 1")


def parse_lengths(text: str) -> tuple[int, ...]:
    """``"0-12"``, ``"0,3,6"`` or a mix -> sorted lengths; ConfigError naming the bad part."""
    out: set[int] = set()
    for part in str(text).split(","):
        part = part.strip()
        try:
            if "-" in part:
                lo, hi = (int(x) for x in part.split("-", 1))
                if hi < lo:
                    raise ValueError
                out.update(range(lo, hi + 1))
            elif part:
                out.add(int(part))
        except ValueError:
            raise ConfigError(f"--assessment: {part!r} is not a length or a range like 0-12") from None
    if not out:
        raise ConfigError("--assessment: give at least one length")
    return tuple(sorted(out))


# ----------------------------------------------------------------------------------------------
# Held-out sessions
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class HeldOut:
    """One held-out session with everything fitted without it."""

    user: User
    sims: tuple[UserSimulator, ...]  # cluster 1..K, fitted without the session
    sizes: np.ndarray  # sessions per cluster
    sigma: np.ndarray  # residual SD of engagement per cluster (its members' turns)
    generic: UserSimulator  # fitted on all the other sessions pooled
    cluster_index: int  # the session's nearest cluster (0-based)
    states: np.ndarray  # the session's real turns, in order
    successes: np.ndarray
    engagements: np.ndarray


def _engagement_sigma(sim: UserSimulator, turns: Any) -> float:
    e = turns.engagement
    ok = np.isfinite(e)
    if not ok.any():
        return 0.15
    resid = e[ok] - sim.engagement[turns.state[ok], turns.success[ok].astype(int)]
    return float(max(np.sqrt(np.mean(resid ** 2)), 1e-3))


def own_rates_user(name: str, own: Any, prior: UserSimulator, kappa: float, cluster: str) -> User:
    """A level-only user from the session's own success per level, shrunk toward ``prior``'s level
    rates by ``kappa`` pseudo-turns, with ``learn.users.session_user``'s engagement."""
    p_level = np.zeros(4)
    for lv in (1, 2, 3, 4):
        mine = own.level == lv
        m = float(prior.p_success[(mdp.LEVEL == lv) & mdp.REACHABLE].mean())
        p_level[lv - 1] = (float(own.success[mine].sum()) + kappa * m) / (float(mine.sum()) + kappa)
    e_level = np.array([float(prior.engagement[mdp.LEVEL == lv].mean()) for lv in (1, 2, 3, 4)])
    for lv in (1, 2, 3, 4):
        e_own = own.engagement[(own.level == lv) & np.isfinite(own.engagement)]
        if e_own.size:
            e_level[lv - 1] = float(e_own.mean())
    return User(name, level_only(prior, p_level, e_level, name=name), prior, cluster)


def held_out(turns: Any, session: str, k: int, n_init: int, seed: int, session_prior: float | None = None) -> HeldOut:
    """Fit everything without ``session`` (see the module docstring)."""
    split = hold_out(turns, session, k, n_init, seed)
    rest, own, labels, cid = split.rest, split.own, split.labels, split.cluster
    options = FitOptions(k=k, seed=seed, cv_folds=1)
    sims, sizes, sigma, member_sets = [], [], [], []
    for c in range(1, k + 1):
        members = rest.subset(labels == c)
        fit = fit_cluster(members, c, options, np.random.default_rng(seed), np.zeros(4), np.zeros(4),
                          {"compat": None, "left_out": session})
        sims.append(fit.simulator)
        sizes.append(len(np.unique(members.session)))
        sigma.append(_engagement_sigma(fit.simulator, members))
        member_sets.append(members)
    generic = fit_cluster(rest, 0, options, np.random.default_rng(seed), np.zeros(4), np.zeros(4),
                          {"compat": None, "left_out": session}).simulator
    if session_prior is None:
        user = session_user(f"session:{session}", own, member_sets[cid - 1], sims[cid - 1], str(cid), sims[cid - 1])
    else:
        user = own_rates_user(f"session:{session}", own, sims[cid - 1], session_prior, str(cid))
    return HeldOut(user, tuple(sims), np.array(sizes, dtype=float), np.array(sigma), generic, cid - 1,
                   own.state.copy(), own.success.copy(), own.engagement.copy())


def model_set(h: HeldOut, with_engagement: bool = False) -> posterior.ModelSet:
    return posterior.ModelSet(tuple(s.name for s in h.sims), np.stack([s.p_success for s in h.sims]),
                              np.stack([s.engagement for s in h.sims]), h.sizes,
                              h.sigma if with_engagement else None)


# ----------------------------------------------------------------------------------------------
# Scoring one held-out session
# ----------------------------------------------------------------------------------------------


def _rng(spec: PersonaliseSpec, user: str, *key: int) -> np.random.Generator:
    ukey = int.from_bytes(hashlib.sha256(user.encode()).digest()[:4], "little")
    return np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(ukey, *key)))


def _train(sim: UserSimulator, name: str, spec: PersonaliseSpec, index: int) -> np.ndarray:
    """The frozen table of a Q-learner trained on ``sim`` (the first of ``spec.seeds``)."""
    es = EvalSpec(policies=("fixed:2",), turns=spec.turns, seeds=spec.seeds, episodes=spec.episodes,
                  seed=spec.seed + 1000 * index, config=spec.config)
    learner = train_learners(User(name, sim, sim, str(index)), [spec.method], es)[spec.method][0]
    return baselines.learner_table(learner)


def candidates(h: HeldOut, spec: PersonaliseSpec) -> tuple[list[assessment.Candidate], np.ndarray]:
    """(candidates, generic table): each cluster's trained policy, then fixed levels 1..4."""
    out = [assessment.Candidate(f"usp:{k + 1}", _train(sim, f"{h.user.name}|cluster-{k + 1}", spec, k + 1))
           for k, sim in enumerate(h.sims)]
    out += [assessment.Candidate(f"fixed:{lv}", evaluation.fixed_level_policy(lv)) for lv in (1, 2, 3, 4)]
    return out, _train(h.generic, f"{h.user.name}|generic", spec, 0)


def _var(out: evaluation.Outcome) -> float | None:
    """The variance of the session's success rate (what ``target-rate`` needs), rounded like the rows."""
    return None if out.success_var is None else round(float(out.success_var), 12)


def score_held_out(h: HeldOut, spec: PersonaliseSpec) -> list[dict[str, Any]]:
    """Rows of every policy and pipeline on one held-out session (module docstring)."""
    truth, T = h.user.truth, spec.turns
    p, e = truth.p_success, truth.engagement
    oracle = evaluation.optimal(p, T)
    cands, generic = candidates(h, spec)
    models = model_set(h)
    rows: list[dict[str, Any]] = []
    best_level = int(np.argmax([evaluation.evaluate(evaluation.fixed_level_policy(lv), p, e, T).score
                                for lv in (1, 2, 3, 4)])) + 1

    def add(policy: str, out: evaluation.Outcome, length: int | None = None, **extra: Any) -> None:
        rows.append({"user": h.user.name, "cluster": h.user.cluster, "user_best_level": best_level,
                     "policy": policy, "assessment": length, "score": round(out.score, 9),
                     "engagement": round(out.engagement, 9), "success": round(out.success, 9),
                     "regret": round(oracle.value - out.score, 9), "visits": np.round(out.visits, 4).tolist(),
                     "samples": out.samples, "success_var": _var(out), **extra})

    add("fixed:2", evaluation.evaluate(evaluation.fixed_level_policy(2), p, e, T))
    level = baselines.best_fixed_level(h.user.train.p_success, h.user.train.engagement, T)
    add("best-fixed", evaluation.evaluate(evaluation.fixed_level_policy(level), p, e, T), level=level)
    add("generic", evaluation.evaluate(generic, p, e, T))
    add("oracle", evaluation.evaluate(oracle.policy, p, e, T))
    own = tuple(range(len(h.sims)))
    for length in spec.lengths:
        schedule = assessment.assessment_schedule(length, spec.levels)
        for i, name in enumerate(PIPELINES):
            mode = Choice.MOST_LIKELY if name == "paper" else Choice.EXPECTED_VALUE
            kappa = spec.kappa if name == "personalised" else float("inf")
            pers = assessment.Personaliser(models, list(cands), schedule, kappa, spec.margin, T, mode=mode,
                                           own_policy=own)
            out = evaluation.monte_carlo(pers, p, e, spec.mc_episodes, _rng(spec, h.user.name, i, length), T)
            add(f"{name}", out, length, switches=round(float(pers.switches.mean()), 4),
                matched=float(np.mean(pers.posterior().argmax(axis=1) == h.cluster_index)))
    return rows


def engagement_information(h: HeldOut, lengths: Sequence[int] = (6, 12, 25)) -> list[dict[str, Any]]:
    """On the session's real turns: is its nearest cluster the most likely model, with and without
    the engagement likelihood, after its first A turns?"""
    out = []
    for length in lengths:
        n = min(length, len(h.states))
        row: dict[str, Any] = {"user": h.user.name, "turns": n}
        for label, use in (("outcomes", False), ("outcomes+engagement", True)):
            w = posterior.posterior(model_set(h, use), h.states[:n], h.successes[:n],
                                    engagements=h.engagements[:n] if use else None)
            row[label] = {"correct": bool(w.argmax() == h.cluster_index), "p_true": float(w[h.cluster_index])}
        out.append(row)
    return out


def _engagement_one(turns: Any, session: str, k: int, n_init: int, seed: int) -> list[dict[str, Any]]:
    return engagement_information(held_out(turns, session, k, n_init, seed))


def engagement_run(source: Any, compat: str | None = None, k: int = 3, n_init: int = 50, seed: int = 0,
                   workers: int = 2, backend: str | None = None, limit: int | None = None) -> list[dict[str, Any]]:
    """``run(...)["engagement"]`` alone: the engagement measurements of every held-out session,
    without training or scoring any policy. They depend on the held-out fits (``k``, ``n_init``,
    ``seed``) and the session's real turns only, not on the objective, the session prior, the
    assessment lengths or any Monte Carlo setting, so one call gives what every ``evaluate
    --personalise`` run on the same data, models and ``--seed`` writes (about a second per session)."""
    turns = Turns.from_columns(read_turns(Path(source), compat).columns)
    parts = leave_one_person_out(turns, _engagement_one, (k, n_init, seed), k, source, workers, backend, limit,
                                 progress="engagement information: held-out sessions")
    return [r for part in parts for r in part]


def _one(turns: Any, session: str, k: int, n_init: int, seed: int, spec: PersonaliseSpec) -> dict[str, Any]:
    h = held_out(turns, session, k, n_init, seed, spec.session_prior)
    # the pooled psychometric model of the other PEOPLE (issue 21; a person's other session is left out too)
    person = np.array([people.person_of(s) for s in turns.session])
    rest = person != people.person_of(session)
    pooled = psychometric.fit(psychometric.session_counts(turns.session[rest], turns.level[rest], turns.success[rest]))
    mine = turns.session == session  # the session's own (successes, failures) per level: the noise-corrected oracle
    counts = psychometric.session_counts(turns.session[mine], turns.level[mine], turns.success[mine])[0]
    means = posterior.level_means(np.stack([s.p_success for s in h.sims]))
    return {"rows": score_held_out(h, spec), "engagement": engagement_information(h),
            "user": h.user.truth.to_dict(), "best_level": None, "cluster": h.user.cluster,
            "psychometric": dict(pooled.__dict__),
            "prior": {"p": means.tolist(), "w": h.sizes.tolist()}, "train_rates": means[h.cluster_index].tolist(),
            "counts": counts.tolist()}


def run(source: Any, spec: PersonaliseSpec, compat: str | None = None, k: int = 3, n_init: int = 50,
        workers: int = 2, backend: str | None = None, limit: int | None = None) -> dict[str, Any]:
    """Rows, engagement measurements and user tables of every held-out session of a dataset."""
    turns = Turns.from_columns(read_turns(Path(source), compat).columns)
    parts = leave_one_person_out(turns, _one, (k, n_init, spec.seed, spec), k, source, workers, backend, limit,
                                 progress="evaluate --personalise: held-out sessions")
    rows = [r for part in parts for r in part["rows"]]
    return {"rows": rows, "engagement": [r for part in parts for r in part["engagement"]],
            "users": [part["user"] for part in parts],
            "fits": {part["user"]["name"]: {k: part[k] for k in ("cluster", "prior", "train_rates", "psychometric", "counts")}
                     for part in parts}}


# ----------------------------------------------------------------------------------------------
# Summaries
# ----------------------------------------------------------------------------------------------


def _ci(values: np.ndarray) -> list[float] | None:
    ci = evaluation.t_interval(values)
    return None if ci is None else [ci[0], ci[1]]


def _by_user(rows: list[dict[str, Any]], policy: str, length: int | None = None) -> dict[str, float]:
    return {r["user"]: r["score"] for r in rows if r["policy"] == policy and r["assessment"] == length}


def gap_closed(rows: list[dict[str, Any]], policy: str, length: int | None, rng: np.random.Generator | None = None,
               reference: str = "best-fixed", boot: int = 2000) -> dict[str, Any]:
    """Share of the gap between ``reference`` and the per-user oracle that ``policy`` closes:
    mean(policy - reference) / mean(oracle - reference) over PEOPLE (a person's sessions averaged),
    with a bootstrap 95 % interval that resamples people (a person's sessions together), drawn
    from ``rng`` (default: ``default_rng(0)``). ``people``: how many."""
    rng = np.random.default_rng(0) if rng is None else rng
    ref, orc, mine = _by_user(rows, reference), _by_user(rows, "oracle"), _by_user(rows, policy, length)
    users = sorted(set(ref) & set(orc) & set(mine))
    gain_p = people.by_person({u: mine[u] - ref[u] for u in users})
    gap_p = people.by_person({u: orc[u] - ref[u] for u in users})
    gain, gap = np.array(list(gain_p.values())), np.array(list(gap_p.values()))
    if not users or gap.mean() <= 0:
        return {"share": None, "share_ci": None, "gap": float(gap.mean()) if users else None, "people": len(gap)}
    idx = rng.integers(len(gap), size=(boot, len(gap)))
    sample_gap = gap[idx].mean(axis=1)
    ok = sample_gap > 0
    shares = gain[idx].mean(axis=1)[ok] / sample_gap[ok]
    return {"share": float(gain.mean() / gap.mean()), "share_ci": [float(np.percentile(shares, 2.5)),
                                                                    float(np.percentile(shares, 97.5))],
            "gap": float(gap.mean()), "people": len(gap)}


def _per_person(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    return np.array(list(people.by_person({r["user"]: r[key] for r in rows}).values()))


def summarise(rows: list[dict[str, Any]], reference: str = "best-fixed", seed: int = 0) -> list[dict[str, Any]]:
    """Per (policy, assessment length): mean score and regret with 95 % t-intervals over PEOPLE (the
    held-out users are sessions; a person's sessions averaged, so user_1's and user_4's two sessions
    count once), the paired difference to ``reference`` over people and the share of the gap to the
    oracle closed (bootstrap over people, one ``default_rng(seed)`` for the whole summary)."""
    rng = np.random.default_rng(seed)
    keys = list(dict.fromkeys((r["policy"], r["assessment"]) for r in rows))
    ref = _by_user(rows, reference)
    out = []
    for pol, length in keys:
        mine = [r for r in rows if r["policy"] == pol and r["assessment"] == length]
        entry: dict[str, Any] = {"policy": pol, "assessment": length, "users": len(mine),
                                 "people": len(people.people(r["user"] for r in mine))}
        for key in ("score", "regret", "engagement"):
            v = _per_person(mine, key)
            entry[key], entry[f"{key}_ci"] = float(v.mean()), _ci(v)
        d = np.array(list(people.by_person({r["user"]: r["score"] - ref[r["user"]] for r in mine
                                            if r["user"] in ref}).values()))
        entry["d_reference"], entry["d_reference_ci"] = (float(d.mean()), _ci(d)) if d.size else (None, None)
        if "matched" in mine[0]:
            entry["matched"] = float(_per_person(mine, "matched").mean())
            entry["switches"] = float(_per_person(mine, "switches").mean())
        entry["gap_closed"] = gap_closed(rows, pol, length, rng, reference=reference)
        out.append(entry)
    return out


def _engagement_by_person(meas: list[dict[str, Any]], label: str, key: str) -> np.ndarray:
    """Per-person means of ``m[label][key]`` (label "diff": P(true) with minus without engagement)."""
    def value(m: dict[str, Any]) -> float:
        if label == "diff":
            return float(m["outcomes+engagement"][key]) - float(m["outcomes"][key])
        return float(m[label][key])
    return np.array(list(people.by_person({m["user"]: value(m) for m in meas}).values()))


def summarise_engagement(meas: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per number of turns: match accuracy and mean P(true cluster) with and without engagement,
    and the paired difference of P(true cluster), over PEOPLE (a person's sessions averaged first,
    so user_1's and user_4's two sessions count once), with a 95 % t-interval over people."""
    out = []
    for n in sorted({m["turns"] for m in meas}):
        mine = [m for m in meas if m["turns"] == n]
        entry: dict[str, Any] = {"turns": n, "sessions": len(mine),
                                 "people": len(people.people(m["user"] for m in mine))}
        for label in ("outcomes", "outcomes+engagement"):
            entry[label] = {"accuracy": float(_engagement_by_person(mine, label, "correct").mean()),
                            "p_true": float(_engagement_by_person(mine, label, "p_true").mean())}
        d = _engagement_by_person(mine, "diff", "p_true")
        entry["p_true_diff"], entry["p_true_diff_ci"] = float(d.mean()), _ci(d)
        out.append(entry)
    return out
