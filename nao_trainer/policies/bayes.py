"""The live Bayes-adaptive policy (``policy.kind: bayes``): the exact planner of ``core.bayes``.

The prior (``policy.prior``) is a finite mixture of per-level user models:

``clusters``      the shipped cluster models (``sim/models``), each reduced to its success per level,
                  weighted by its number of sessions;
``psychometric``  the pooled psychometric model (``core.psychometric``) fitted on the 50 published
                  sessions (``sim/psychometric/pooled.json``), as the grid of spans theta it
                  integrates over (``PooledModel.mixture``): exactly the prior of the evaluation's
                  ``bayes-psychometric``, there fitted on the other sessions;
a file ``*.json``  another psychometric prior (``nao-trainer fit ... --psychometric FILE``);
a folder          user simulator files (e.g. the training users), equal weights.

Unset, it follows the objective: ``psychometric`` for ``target:R`` (it pools a participant's turns
across lengths and wins most under a target rate), ``clusters`` for ``score`` (the smooth curve
sends some participants to levels 3-4 too often and loses score; docs/explanation/results.md).

What the policy knows about the participant is the per-level counts of successes and failures;
they are a sufficient statistic, so the plan solved once for the session covers every turn (also
after a supervisor's override or an invalid turn that is not observed): a decision is a table lookup.

Across sessions the counts of the earlier sessions are carried: the next session's prior is the
posterior they give, and its table is solved for it (``learn.bayes_cache``: the same prior and
objective load in milliseconds). They live in ``<output>/participants/<pseudonym>/bayes.json``
(checksummed, written atomically after every turn, naming its participant). The file is refused in
one line when it was made with another prior or objective (fingerprint), belongs to another
participant (copied between folders), or is torn or edited; ``--fresh-policy`` keeps it as
``bayes.json.replaced-<time>`` and starts from the prior.
"""
from __future__ import annotations

import hashlib
import logging
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nao_trainer.core import bayes, mdp, objective
from nao_trainer.core.posterior import level_means, model_label
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import JsonFormat
from nao_trainer.learn import artifacts
from nao_trainer.learn.artifacts import load_simulator_file
from nao_trainer.learn.bayes_cache import solve_cached
from nao_trainer.learn.psychometric_prior import load_prior
from nao_trainer.learn.users import policy_users
from nao_trainer.policies.participant_state import FRESH, ParticipantState, open_saved
from nao_trainer.policies.plugin import LiveContext, OfflineContext
from nao_trainer.ports import Transition

STATE_FILE = JsonFormat("nao-trainer/participant-bayes", 1, "participant Bayes state", "participant state", FRESH)
#: The participant's file (policies.participant_state: one save, read, owner and fingerprint check).
PARTICIPANT = ParticipantState(lambda p: STATE_FILE.read(p, DataError), STATE_FILE.write,
                               lambda saved: saved.get("prior_fingerprint"), "another prior or objective")
FILENAME = "bayes.json"
#: ``policy.prior`` names (anything else is a psychometric prior file or a folder of user simulators).
PRIORS = ("clusters", "psychometric")
SHOWN = 6  # the status lists the posterior of this many most likely models (the shipped psychometric prior has 78)
log = logging.getLogger(__name__)


def prior_fingerprint(names: Sequence[str], p: np.ndarray, w: np.ndarray, obj: objective.Objective) -> str:
    h = hashlib.sha256()
    # target-p is the old target: its old name keeps the participants' saved states valid
    name = f"target:{obj.rate:g}" if obj.kind == "target-p" else str(obj)
    h.update(("|".join(names) + f"|{name}").encode())
    h.update(np.round(np.asarray(p, float), 12).astype("<f8").tobytes())
    h.update(np.round(np.asarray(w, float) / np.sum(w), 12).astype("<f8").tobytes())
    return h.hexdigest()


class BayesPolicy:
    """``ports.Policy`` of the module docstring."""

    name = "bayes"

    def __init__(self, names: Sequence[str], p: np.ndarray, weights: np.ndarray, obj: objective.Objective,
                 turns: int, path: Path | None, saved: dict[str, Any] | None = None,
                 cache: Path | None = None, pseudonym: str | None = None, prior: str = "models") -> None:
        self.pseudonym = pseudonym  # whose state this is (stored in the file; another participant's is refused)
        self.prior = prior  # what the prior is, in words (the file and the status say it)
        self.names = tuple(names)
        self.p = np.asarray(p, dtype=float)
        self.weights = np.asarray(weights, dtype=float) / np.sum(weights)
        self.objective = obj
        self.turns = int(turns)
        self.path = Path(path) if path is not None else None
        self.fingerprint = prior_fingerprint(self.names, self.p, self.weights, obj)
        saved = saved or {}
        self.history: list[dict[str, Any]] = list(saved.get("sessions", []))
        self.carried = np.array(saved.get("counts", [0] * 8), dtype=np.int64)  # earlier sessions
        self.counts = np.zeros(8, dtype=np.int64)  # this session
        self.cache = cache
        self.plan = self._solve()
        self.session_dir: Path | None = None
        self.started = datetime.now(timezone.utc).isoformat(timespec="seconds")
        self.last_level = 0

    def _solve(self) -> bayes.Plan:
        """The table for this session: prior = the posterior after the earlier sessions' counts."""
        # no earlier turns: the prior's own weights, so the plan is the evaluation's for the same prior
        start = bayes.posterior_weights(self.p, self.weights, self.carried) if self.carried.any() else self.weights
        return solve_plan(self.p, start, self.objective, self.turns, self.cache)

    # -- ports.Policy ------------------------------------------------------------------------------

    def decide(self) -> int:
        """The level (1-based) for the next turn: the plan's, or past its horizon the posterior-best."""
        if int(self.counts.sum()) < self.plan.horizon:
            return self.plan.decide(self.counts)
        w = self.posterior()
        return int(np.argmax(np.round(w @ self.objective.utility(self.p), 12))) + 1

    def act(self, state: int, rng: np.random.Generator) -> int:
        self.last_level = self.decide()
        return self.last_level - 1  # actions 0..3 are levels 1..4

    def observe(self, transition: Transition) -> None:
        level = int(mdp.LEVEL[transition.next_state])
        self.counts[2 * (level - 1) + (0 if transition.score > 0 else 1)] += 1
        self.save()

    def bind_state_dir(self, folder: Path) -> None:
        self.session_dir = Path(folder)
        if self.path is None:
            self.path = self.session_dir / FILENAME

    def probabilities(self, state: int) -> np.ndarray | None:
        out = np.zeros(mdp.N_ACTIONS)
        out[self.decide() - 1] = 1.0
        return out

    def guide(self, state: int, action: int) -> None:
        pass  # an override is observed like any turn: the counts, not the plan, change

    def snapshot(self) -> dict | None:
        return {"counts": self.counts.tolist(), "carried": self.carried.tolist(), "history": self.history,
                "started": self.started}

    def restore(self, data: dict | None) -> None:
        """Back to a checkpoint of this session (``--resume``): the participant file already holds the
        interrupted session's turns, so the counts before it come from the checkpoint."""
        if data:
            carried = np.array(data["carried"], dtype=np.int64)
            self.counts = np.array(data["counts"], dtype=np.int64)
            self.history = list(data["history"])
            self.started = str(data["started"])
            if not np.array_equal(carried, self.carried):
                self.carried = carried
                self.plan = self._solve()

    def close(self) -> None:
        self.save()

    def posterior(self) -> np.ndarray:
        return bayes.posterior_weights(self.p, self.weights, self.carried + self.counts)

    def status(self) -> dict[str, Any]:
        w = self.posterior()
        est = w @ self.p
        ranked = sorted(zip(self.names, w), key=lambda x: -x[1])
        post = " | ".join(f"{model_label(n)} {x:.2f}" for n, x in ranked[:4])
        best = int(np.argmax(w))
        return {
            "phase": "bayes", "prior": self.prior,
            "posterior": {n: round(float(x), 4) for n, x in ranked[:SHOWN]},
            "matched": self.names[best], "match_probability": round(float(w[best]), 4),
            "following": f"bayes ({self.objective})", "level_success": [round(float(x), 4) for x in est],
            "posterior_text": post,
            "progress": f"           posterior: {post} -> next level {self.decide()}",
            "summary": (f"Bayes planner ({self.objective}, prior {self.prior}): most likely {model_label(self.names[best])} "
                        f"(posterior {w[best]:.2f}; {post}); estimated success by level "
                        + " ".join(f"L{i + 1} {x:.2f}" for i, x in enumerate(est)) + self.why_one_level(w)),
        }

    def why_one_level(self, w: np.ndarray) -> str:
        """Why a session stayed at one level (the demo's strong participant at level 2 under ``--policy bayes``):
        each level's expected value per turn now, and where the two likeliest user models differ. Empty when
        several levels were played."""
        played = self.counts.reshape(-1, 2).sum(axis=1)
        if int(played.sum()) < 2 or int(np.count_nonzero(played)) != 1:
            return ""
        at = int(np.flatnonzero(played)[0])
        value = w @ self.objective.utility(self.p)
        text = (f". It played level {at + 1} in all {int(played.sum())} turns, the highest expected value per turn "
                "under the posterior (now " + " ".join(f"L{i + 1} {v:.2f}" for i, v in enumerate(value)) + ")")
        if len(self.names) >= 2:
            a, b = np.argsort(-w, kind="stable")[:2]
            gap = np.abs(self.p[a] - self.p[b])
            apart = int(np.argmax(gap))
            if apart != at:
                text += (f"; the two likeliest user models succeed at level {at + 1} alike ({model_label(self.names[a])} "
                         f"{self.p[a, at]:.2f}, {model_label(self.names[b])} {self.p[b, at]:.2f}) and differ most at level "
                         f"{apart + 1} ({self.p[a, apart]:.2f}, {self.p[b, apart]:.2f}): only turns there would tell "
                         "them apart, and the planner expected them to cost more than they could gain over the turns "
                         "left")
        return text + " (the prior decides: policy.prior; docs/explanation/personalisation.md#why-it-can-stay-at-one-level)"

    # -- the participant's file ----------------------------------------------------------------------

    def payload(self) -> dict[str, Any]:
        entry = {"started": self.started, "session": str(self.session_dir) if self.session_dir else None,
                 "turns": int(self.counts.sum()), "counts": self.counts.tolist()}
        return {"pseudonym": self.pseudonym, "mdp_definition": mdp.DEFINITION, "prior_fingerprint": self.fingerprint,
                "prior": self.prior, "objective": str(self.objective), "models": list(self.names),
                "counts": (self.carried + self.counts).tolist(), "sessions": self.history + [entry],
                "updated": datetime.now(timezone.utc).isoformat(timespec="seconds")}

    def save(self) -> None:
        if self.path is not None:
            PARTICIPANT.save(self.path, self.payload())


def _made_with(saved: dict[str, Any]) -> str:
    return ", ".join(str(x) for x in (saved.get("prior"), saved.get("objective")) if x is not None)


def read_state(path: Path, fingerprint: str, pseudonym: str | None = None) -> dict[str, Any]:
    """A participant's saved counts, checked; DataError in one line otherwise (``PARTICIPANT``: the shared
    owner and fingerprint checks; a file copied between folders is refused)."""
    saved = PARTICIPANT.read(path, fingerprint, pseudonym, _made_with)
    counts = saved.get("counts")
    if not (isinstance(counts, list) and len(counts) == 8 and all(isinstance(c, int) and c >= 0 for c in counts)):
        raise DataError(f"{path}: participant state has invalid counts; {FRESH}")
    if not isinstance(saved.get("sessions"), list):
        raise DataError(f"{path}: participant state lacks its sessions; {FRESH}")
    return saved


def default_prior(obj: objective.Objective) -> str:
    """``policy.prior`` when unset: psychometric under a target rate, clusters under the score (module docstring)."""
    return "psychometric" if obj.is_target else "clusters"


def cluster_prior(models_dir: Path | None = None) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """(names, success per level (K, 4), weights): the fitted clusters, weighted by their sessions."""
    manifest = artifacts.load_manifest(models_dir)
    rows = manifest.get("clusters", [])
    if not rows:
        raise DataError("the user model folder lists no clusters; refit with `nao-trainer fit`")
    sims = [artifacts.load_simulator(str(r["id"]), models_dir) for r in rows]
    sizes = np.array([float(r.get("size") or 1.0) for r in rows])
    return tuple(s.name for s in sims), level_means(np.stack([s.p_success for s in sims])), sizes


def psychometric_prior(file: Path | None = None) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """(names, success per level (G, 4), weights): the pooled psychometric model of ``file`` (default:
    the shipped one) as the mixture over its grid of spans, the same as the evaluation's ``bayes-psychometric``."""
    theta, p, w = load_prior(file).components()
    return tuple(f"span {t:.1f}" for t in theta), p, w


def users_prior(users_dir: Path) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """(names, success per level (K, 4), equal weights): every user simulator file of ``users_dir``."""
    files = sorted(Path(users_dir).glob("*.json"))
    if not files:
        raise ConfigError(f"policy.prior {users_dir}: no user simulator files (*.json) in that folder; "
                          "give clusters, psychometric, a psychometric prior file or a folder of user simulators")
    sims = [load_simulator_file(f) for f in files]  # DataError in one line: torn, foreign definition, ...
    return tuple(s.name for s in sims), level_means(np.stack([s.p_success for s in sims])), np.ones(len(sims))


def model_prior(prior: str, models_dir: Path | None = None) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """The mixture ``policy.prior`` names: ``clusters``, ``psychometric``, a psychometric prior file or a folder."""
    if prior == "clusters":
        return cluster_prior(models_dir)
    if prior == "psychometric":
        return psychometric_prior()
    path = Path(prior).expanduser()
    if path.is_dir():
        return users_prior(path)
    if path.is_file():
        return psychometric_prior(path)
    raise ConfigError(f"policy.prior {prior!r}: not clusters, psychometric, a psychometric prior file or a folder of "
                      "user simulators; fix policy.prior (or --prior)")


def task_prior(prior: str | None, task: Any, models_dir: Path | None = None
               ) -> tuple[str, tuple[tuple[str, ...], np.ndarray, np.ndarray]] | None:
    """(the prior in words, the mixture) for a task the shipped priors are not of: its own simulated users
    (``learn.users.policy_users``), equal weights, when ``policy.prior`` is unset; a folder or file the study
    names as it is. None for the sequence task. A shipped prior (``PRIORS``: fitted on the published data,
    the sequence task's) under another task is one ``ConfigError`` line naming the task."""
    users = policy_users(task, "bayes")
    if users is None:
        return None
    if prior in PRIORS:
        raise ConfigError(f"policy 'bayes' under task {task.name!r}: prior {prior!r} is fitted on the sequence task's "
                          "data; leave policy.prior unset (the task's own simulated users) or give a folder of user "
                          "simulators (--prior)")
    if prior is not None:
        return prior, model_prior(prior, models_dir)
    sims = [u.truth for u in users]
    return (f"task {task.name}'s simulated users",
            (tuple(s.name for s in sims), level_means(np.stack([s.p_success for s in sims])), np.ones(len(sims))))


def load_bayes(path: Path | None, pseudonym: str, turns: int, objective_text: str, fresh: bool,
               prior: str | None = None, models_dir: Path | None = None, cache: Path | None = None,
               task: Any = None) -> BayesPolicy:
    """The Bayes policy for ``pseudonym`` with the participant's saved counts at ``path`` (None: kept
    in the session folder, nothing carried over); ``prior``: ``policy.prior`` (None: by the objective);
    ``task``: the session's (None: the sequence task; another task's prior: ``task_prior``)."""
    if not bayes.available():
        raise ConfigError("policy 'bayes' needs numba: pip install 'nao-trainer[all]'")
    try:
        obj = objective.parse(objective_text)
    except ValueError as exc:
        raise ConfigError(f"policy.objective: {exc}") from None
    own = task_prior(prior, task, models_dir)
    if own is not None:
        prior, (names, p, w) = own
    else:
        prior = prior or default_prior(obj)
        names, p, w = model_prior(prior, models_dir)
    fp = prior_fingerprint(names, p, w, obj)
    saved = open_saved(path, fresh, lambda f: read_state(f, fp, pseudonym), "bayes", log)  # + the counts' checks
    if saved is not None:
        log.warning("policy bayes: %s returns after %d session(s) with counts %s (%s)", pseudonym,
                    len(saved["sessions"]), saved["counts"], path)
    return BayesPolicy(names, p, w, obj, turns, Path(path) if path is not None else None, saved, cache, pseudonym,
                       prior)


# -- the plug-in's entry points (policies.kinds.BAYES) -----------------------------------------------


def live(ctx: LiveContext) -> BayesPolicy:
    return load_bayes(ctx.state_file, ctx.participant, ctx.turns, ctx.settings.objective, ctx.fresh, ctx.settings.prior,
                      task=ctx.task)


class BayesSessions:
    """The offline form (``study power``): the same prior, objective and plan as the live policy.

    Session 1 plays the solved plan exactly (``Plan.decide_many``: the table lookup of the live
    ``decide``). A later session of the live policy solves a new plan for the posterior after the
    carried counts, one per participant; solving one per simulated participant is out of reach, so
    from session 2 on each participant plays the plan's own rule past its horizon: the posterior-best
    level after all counts so far (carried and this session's), updated every turn (the exploration a
    new plan would add is left out: an approximation, said in ``study power``'s notes)."""

    def __init__(self, ctx: OfflineContext, models_dir: Path | None = None, cache: Path | None = None) -> None:
        if not bayes.available():
            raise ConfigError("policy 'bayes' needs numba: pip install 'nao-trainer[all]'")
        self.objective = objective.parse(ctx.settings.objective)
        own = task_prior(ctx.settings.prior, ctx.task, models_dir)
        if own is not None:
            self.prior, (self.names, self.p, weights) = own
        else:
            self.prior = ctx.settings.prior or default_prior(self.objective)
            self.names, self.p, weights = model_prior(self.prior, models_dir)
        self.weights = np.asarray(weights, dtype=float) / np.sum(weights)
        self.turns = int(ctx.turns)
        self.plan = solve_plan(self.p, self.weights, self.objective, self.turns, cache)
        self.utility = self.objective.utility(self.p)  # (K, L)
        self.carried: np.ndarray | None = None
        self.counts = np.zeros((0, 8), dtype=np.int64)
        self.session = 0
        #: said in ``study power``'s notes
        self.note = ("bayes: session 1 plays the solved plan; later sessions the posterior-best level after the "
                     "carried counts (a live session re-solves the plan per participant)")

    def start(self, n: int, session: int) -> "BayesSessions":
        """Session ``session`` (1-based) of the same ``n`` participants as the session before."""
        if session == 1 or self.carried is None:
            self.carried = np.zeros((n, 8), dtype=np.int64)
        else:
            self.carried = self.carried + self.counts
        self.counts = np.zeros((n, 8), dtype=np.int64)
        self.session = session
        return self

    # -- core.evaluation.EpisodePolicy -------------------------------------------------------------

    def reset(self, n: int, process: Any) -> None:
        self.start(n, 1)

    def levels(self) -> np.ndarray:
        """The level (1-based) of the next turn of every participant."""
        played = int(self.counts[0].sum()) if len(self.counts) else 0
        if self.session == 1 and played < self.plan.horizon:
            return self.plan.decide_many(self.counts)
        total = self.carried + self.counts
        loglik = np.log(np.clip(np.stack([self.p, 1.0 - self.p], axis=-1).reshape(len(self.p), -1), 1e-300, None))
        logw = np.log(self.weights)[None, :] + total @ loglik.T  # (n, K)
        w = np.exp(logw - logw.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        return np.argmax(np.round(w @ self.utility, 12), axis=1) + 1

    def act(self, obs: np.ndarray, turn: int, rng: np.random.Generator) -> np.ndarray:
        return self.levels() - 1  # actions 0..3 are levels 1..4

    def observe(self, obs: np.ndarray, action: np.ndarray, score: np.ndarray, engagement: np.ndarray,
                next_obs: np.ndarray, done: bool) -> None:
        rows = np.arange(len(action))
        self.counts[rows, 2 * np.asarray(action) + np.where(np.asarray(score) > 0, 0, 1)] += 1


def solve_plan(p: np.ndarray, weights: np.ndarray, obj: objective.Objective, turns: int,
               cache: Path | None) -> bayes.Plan:
    """The plan of a session of ``turns`` turns for the prior ``weights`` (live and offline alike)."""
    try:
        return solve_cached(p, weights, obj.coefficients(4), turns, 0, cache, terminal=obj.terminal(turns))
    except bayes.PlanTooLarge as exc:
        raise ConfigError(f"policy bayes: {exc}; play at most {exc.max_horizon} turns "
                          "(--turns or session.turns), or another policy") from None


def offline(ctx: OfflineContext) -> BayesSessions:
    return BayesSessions(ctx)
