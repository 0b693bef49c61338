"""Simulated users to evaluate policies on: clusters, level-only variants, and one user per real session.

Every ``User`` has a ``truth`` (the simulator the policy is evaluated on) and a ``train`` simulator
(what a policy for this user is trained on, and where the best fixed level is chosen), so that
evaluation never lets a policy learn from the user it is scored on when the user set says so.

``clusters``    the fitted cluster simulators (``--models``, default ``sim/models``); truth = train.
``level-only``  each cluster's success and engagement per level only (no feedback, previous-outcome
                or outcome effects), from the cluster's data rates in the models' manifest;
                policies are still trained on the cluster simulator as fitted (that is what a study
                would ship), so this asks what the fitted effects buy when they are absent.
``task``        a task's own simulated population (``Task.simulated_users``, e.g. n-back's signal-detection
                observers): level-only users, truth = train; no data behind them (the published data are
                the sequence task's), so they say what a policy does *if* people are like the task's model.
``sessions``    each real session is a user: its success per level is the posterior mean under a
                Beta prior centred on its cluster's rate (``session_user``), its engagement per level
                its own mean (its cluster's where it never played a level). Leave-one-session-out:
                for session i the sessions are clustered again without i, i is assigned to the
                nearest centre, and its training simulator is that cluster's default fit
                (``learn.effects``) on the other sessions' turns only.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.core.people import people, person_of
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.core.task import LEVELS as MDP_LEVELS
from nao_trainer.core.usermodel import cluster_users, user_models
from nao_trainer.data import dataset, turn_table
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.learn import artifacts
from nao_trainer.learn.fit_source import table_provenance
from nao_trainer.learn.fitting import FitOptions, Turns, fit_cluster
from nao_trainer.learn.parallel import fan_out
from nao_trainer.tasks.base import published

USER_SETS: tuple[str, ...] = ("clusters", "level-only", "sessions", "task")


@dataclass(frozen=True, eq=False)
class User:
    name: str
    truth: UserSimulator
    train: UserSimulator
    cluster: str


def level_only(sim: UserSimulator, success: np.ndarray, engagement: np.ndarray, name: str | None = None) -> UserSimulator:
    """A simulator with P(success) and engagement depending on the level only (4 values each)."""
    p = np.asarray(success, dtype=float)
    e = np.asarray(engagement, dtype=float)
    if p.shape != (4,) or e.shape != (4,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(e))):
        raise DataError(f"{sim.name}: level-only variant needs 4 finite success rates and engagements")
    levels = mdp.LEVEL - 1
    return UserSimulator(name=name or f"{sim.name}-level-only", p_success=np.clip(p[levels], 0, 1),
                         engagement=np.repeat(np.clip(e[levels], 0, 1)[:, None], 2, axis=1),
                         reaction_quantiles=sim.reaction_quantiles, completion_quantiles=sim.completion_quantiles,
                         metadata={"kind": "level-only", "of": sim.name})


def cluster_user_set(models_dir: Path | None = None, variant: str = "clusters") -> list[User]:
    """``clusters`` or ``level-only`` users of a model folder (see the module docstring)."""
    manifest = artifacts.load_manifest(models_dir)
    users = []
    for row in manifest.get("clusters", []):
        cid = str(row["id"])
        sim = artifacts.load_simulator(cid, models_dir)
        truth = sim
        if variant == "level-only":
            rates = row.get("data_level_success")
            eng = row.get("e")
            if rates is None or eng is None or None in rates or None in eng:
                raise DataError(f"{models_dir or artifacts.default_models_dir()}/manifest.json: cluster {cid} lacks "
                                "data_level_success or e; refit with `nao-trainer fit`")
            truth = level_only(sim, np.array(rates, dtype=float), np.array(eng, dtype=float))
        users.append(User(f"cluster-{cid}" + ("-level-only" if variant == "level-only" else ""), truth, sim, cid))
    if not users:
        raise DataError("the user model folder lists no clusters; refit with `nao-trainer fit`")
    return users


def task_user_set(task: Any, engagement_by_level: Any = (0.5, 0.5, 0.5, 0.5)) -> list[User]:
    """``task`` users: the task's ``simulated_users()``, each a level-only simulator over the task's ``levels``
    (the MDP's four), with ``engagement_by_level`` (the task models no engagement); DataError when the task
    declares none or its levels are not the MDP's."""
    own = getattr(task, "simulated_users", None)
    if own is None:
        raise DataError(f"task {task.name!r} declares no simulated users of its own (Task.simulated_users); "
                        "its users are the fitted ones: --users clusters|level-only|sessions")
    if tuple(task.levels) != MDP_LEVELS:
        raise DataError(f"task {task.name!r}: levels {tuple(task.levels)} are not the MDP's four (1..4)")
    users = []
    for name, rates in own():
        if len(rates) != len(task.levels):
            raise DataError(f"task {task.name!r}: simulated user {name!r} has {len(rates)} rates for "
                            f"{len(task.levels)} levels")
        sim = UserSimulator.from_level_rates(name, [float(r) for r in rates], list(engagement_by_level))
        truth = level_only(sim, np.array(rates, dtype=float), np.asarray(engagement_by_level, dtype=float), name=name)
        users.append(User(name, truth, truth, task.name))
    if not users:
        raise DataError(f"task {task.name!r}: simulated_users() is empty")
    return users


def policy_users(task: Any, policy: str) -> list[User] | None:
    """``task``'s own simulated users (``task_user_set``) for a policy that otherwise takes the shipped user models
    or priors, which are fitted on the published data (the sequence task's); None when those are ``task``'s
    (``tasks.base.published``). One ``ConfigError`` line naming the task and what to do when it has none."""
    if published(task):
        return None
    if getattr(task, "simulated_users", None) is None:
        raise ConfigError(f"policy {policy!r} under task {task.name!r}: the shipped user models are fitted on the "
                          f"sequence task's data and task {task.name!r} declares no simulated users of its own "
                          "(Task.simulated_users); use schedule or random")
    try:
        return task_user_set(task)
    except DataError as exc:
        raise ConfigError(f"policy {policy!r}: {exc}") from None


# ----------------------------------------------------------------------------------------------
# Per-session users, leave the person out
# ----------------------------------------------------------------------------------------------


def beta_concentration(rates: np.ndarray, turns: np.ndarray) -> float:
    """Beta prior strength (pseudo-turns) by the method of moments over sessions' rates at one level.

    The between-session variance is the observed variance of the rates minus their binomial noise;
    ``kappa = m (1 - m) / var - 1``, kept in [1, 100] (1: the data dominates; 100: nearly the mean).
    """
    r, n = np.asarray(rates, dtype=float), np.asarray(turns, dtype=float)
    ok = n > 0
    if ok.sum() < 2:
        return 1.0
    r, n = r[ok], n[ok]
    m = float(np.average(r, weights=n))
    if m <= 0 or m >= 1:
        return 100.0
    between = float(r.var(ddof=1) - np.mean(m * (1 - m) / n))
    if between <= 0:
        return 100.0
    return float(np.clip(m * (1 - m) / between - 1.0, 1.0, 100.0))


def session_user(name: str, turns: Any, prior_turns: Any, prior_sim: UserSimulator,
                 cluster: str, train: UserSimulator) -> User:
    """One session as a level-only user, success shrunk toward ``prior_turns`` (its cluster's other sessions)."""
    level = mdp.LEVEL[turns.state]
    p_level = np.zeros(4)
    e_level = np.zeros(4)
    prior_level = mdp.LEVEL[prior_turns.state]
    for lv in (1, 2, 3, 4):
        prior_mask = prior_level == lv
        if prior_mask.any():
            names, inv = np.unique(prior_turns.session[prior_mask], return_inverse=True)
            n_s = np.bincount(inv).astype(float)
            w_s = np.bincount(inv, weights=prior_turns.success[prior_mask].astype(float))
            m = float(w_s.sum() / n_s.sum())
            kappa = beta_concentration(w_s / n_s, n_s)
        else:  # nobody in the cluster played this level: the training simulator's rate
            m = float(prior_sim.p_success[mdp.LEVEL == lv].mean())
            kappa = 1.0
        mine = level == lv
        wins, n = float(turns.success[mine].sum()), float(mine.sum())
        p_level[lv - 1] = (wins + kappa * m) / (n + kappa)
        e_own = turns.engagement[mine]
        e_own = e_own[np.isfinite(e_own)]
        if e_own.size:
            e_level[lv - 1] = float(e_own.mean())
        else:
            e_prior = prior_turns.engagement[prior_mask]
            e_prior = e_prior[np.isfinite(e_prior)]
            e_level[lv - 1] = float(e_prior.mean()) if e_prior.size else float(prior_sim.engagement[mdp.LEVEL == lv].mean())
    return User(name, level_only(prior_sim, p_level, e_level, name=name), train, cluster)


@dataclass(frozen=True)
class HeldOutSplit:
    """A session set aside: the other sessions, their clusters, and the cluster the session is nearest."""

    rest: Any  # Turns of every other session
    own: Any  # Turns of the held-out session
    labels: np.ndarray  # cluster id (1..k) of each turn of ``rest``
    cluster: int  # the held-out session's nearest cluster (1..k), from its own user model


def hold_out(turns: Any, session: str, k: int, n_init: int, seed: int) -> HeldOutSplit:
    """Cluster the user models of every session but ``session``, then place ``session`` by its own user model.

    The one rule of leave-one-out: what is fitted never sees the held-out session's turns, nor
    those of the person's other sessions (user_1 and user_4 played two: leave the PERSON out).
    """
    mine = turns.session == session
    me = person_of(session)
    same_person = np.array([person_of(s) == me for s in turns.session], dtype=bool)
    rest, own = turns.subset(~same_person), turns.subset(mine)
    um = user_models(rest.session, rest.level, rest.success, rest.engagement)
    clustering = cluster_users(um.features, k, n_init, seed)
    own_um = user_models(own.session, own.level, own.success, own.engagement)
    features = np.where(own_um.missing, um.features.mean(axis=0), own_um.features)[0]
    cid = int(np.argmin(((clustering.centers - features) ** 2).sum(axis=1))) + 1
    by_session = dict(zip(um.sessions, clustering.labels))
    return HeldOutSplit(rest, own, np.array([by_session[s] for s in rest.session]), cid)


def _loso_one(turns: Any, session: str, k: int, n_init: int, seed: int) -> User:
    """The user of ``session`` with its training simulator fitted without it (module docstring)."""
    split = hold_out(turns, session, k, n_init, seed)
    cid = split.cluster
    members = split.rest.subset(split.labels == cid)
    options = FitOptions(k=k, seed=seed, cv_folds=1)
    fit = fit_cluster(members, cid, options, np.random.default_rng(seed), np.zeros(4), np.zeros(4),
                      {"compat": None, "left_out": session})
    return session_user(f"session:{session}", split.own, members, fit.simulator, str(cid), fit.simulator)


def session_user_set(source: Path, compat: str | None = None, k: int = 3, n_init: int = 50, seed: int = 0,
                     workers: int = 2, backend: str | None = None, limit: int | None = None) -> list[User]:
    """Per-session users of a dataset root or turn-table CSV, each fitted without its person (module docstring)."""
    turns = Turns.from_columns(read_turns(Path(source), compat).columns)
    return leave_one_person_out(turns, _loso_one, (k, n_init, seed), k, source, workers, backend, limit)


def leave_one_person_out(turns: Any, one: Any, extra: tuple, k: int, source: Any = "", workers: int = 2,
                         backend: str | None = None, limit: int | None = None,
                         progress: str | None = None) -> list[Any]:
    """``one(turns, session, *extra)`` for every session, in parallel, each fitted without the
    session's person (``hold_out``): the one leave-out loop of the project (user models, per-session
    users, personalisation, the ceiling's users). DataError when the people left to cluster are too
    few for K clusters."""
    sessions = sorted(np.unique(turns.session).tolist())
    who = people(sessions)
    if len(who) < 2 * k + 1:
        raise DataError(f"{source}: {len(who)} people ({len(sessions)} sessions) are too few for leave-one-out "
                        f"with K={k} clusters; give at least {2 * k + 1} people or fewer clusters")
    if limit is not None:
        sessions = sessions[:limit]
    return fan_out(one, [(turns, s, *extra) for s in sessions], workers, backend, progress=progress)


def read_turns(source: Path, compat: str | None):
    """The turn table of a dataset root (imported through the cache) or of a turn-table CSV."""
    if not source.exists():
        raise ConfigError(f"{source}: no such dataset root or turn table; give --users clusters|level-only|sessions "
                          "or a dataset root")
    if source.is_file():
        table_provenance(source, compat)
        return turn_table.read_table(source)
    return dataset.import_dataset(source, compat=compat, cache_dir=dataset.cache_dir(source, compat)).table


def load_users(which: str, models_dir: Path | None = None, data: Path | None = None, workers: int = 2,
               backend: str | None = None, seed: int = 0, limit: int | None = None) -> tuple[str, list[User]]:
    """(user-set name, users) for ``--users``: a name of ``USER_SETS`` or a dataset root (sessions)."""
    if which in ("clusters", "level-only"):
        return which, cluster_user_set(models_dir, which)
    if which == "sessions":
        if data is None:
            raise ConfigError("--users sessions needs the dataset: add --data DATASET_ROOT (or give the root as --users)")
        source = Path(data)
    else:
        source = Path(which)
        if not source.exists():
            raise ConfigError(f"--users {which!r}: use one of {', '.join(USER_SETS)} or an existing dataset root")
    compat = artifacts.load_manifest(models_dir).get("compat")  # the same engagement definition as the models
    k = int(artifacts.load_manifest(models_dir).get("k", 3))
    return "sessions", session_user_set(source, compat, k, seed=seed, workers=workers, backend=backend, limit=limit)
