"""The personalised policy of a live session (``--policy personalised``) and the participant's state.

The policy runs ``core.assessment``'s pipeline for one participant: the assessment turns, the
posterior over the shipped user models (``sim/models``, prior = cluster sizes) after every turn,
the choice among the candidates (each cluster's trained policy from ``sim/policies``, each fixed
level) by posterior expected value with the anti-flip-flop margin, and the participant's per-level
Beta posteriors. Every candidate Q-learner keeps learning from every turn (off-policy Q-learning:
the update needs no one to have followed it), and its value tables are recomputed from its new
softmax policy, so the choice sees what it learned.

Across sessions, everything lives in ``<output>/participants/<pseudonym>/personalised.json``
(``PARTICIPANT_FILE``: checksummed, written atomically after every turn): the posterior, the
per-level counts, the learners' tables and one line per session. A returning participant starts
from it and skips the assessment (the carried-over posterior already holds it). The file is
refused in one line when it was made for another MDP, with other user models or policies
(fingerprint), or is torn; ``--fresh-policy`` keeps the old file as ``personalised.json.replaced-<time>``
(``policies.participant_state.set_aside``) and starts from the prior. Nothing is reset silently. The file
names its participant; a file of another pseudonym (copied between folders) is refused.
"""
from __future__ import annotations

import hashlib
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nao_trainer.core import assessment, baselines, evaluation, mdp
from nao_trainer.core.assessment import Choice
from nao_trainer.core.posterior import ModelSet, model_label
from nao_trainer.core.qlearning import QLearner
from nao_trainer.errors import DataError
from nao_trainer.files import JsonFormat
from nao_trainer.learn import artifacts, policy_files
from nao_trainer.learn.users import policy_users
from nao_trainer.policies.base import Guidance, log
from nao_trainer.policies.participant_state import FRESH, ParticipantState, open_saved, session_state_file, state_file
from nao_trainer.policies.plugin import LiveContext, OfflineContext
from nao_trainer.ports import Transition

PARTICIPANT_FILE = JsonFormat("nao-trainer/participant-personalisation", 1, "participant personalisation state",
                              "participant state", FRESH)
#: The participant's file (policies.participant_state: one save, read, owner and fingerprint check).
PARTICIPANT = ParticipantState(lambda p: PARTICIPANT_FILE.read(p, DataError), PARTICIPANT_FILE.write,
                               lambda saved: saved.get("models_fingerprint"), "other user models or policies")


def participant_file(output: Path, pseudonym: str) -> Path:
    """The participant's state file by default (``policies.participant_state.state_file``)."""
    path = state_file("personalised", None, pseudonym, output)
    assert path is not None
    return path


def models_fingerprint(models: ModelSet, fingerprints: Sequence[str], policy_digests: Sequence[str]) -> str:
    """One digest of the user models (tables and priors) and the trained policies the state was built on."""
    h = hashlib.sha256()
    for part in (*fingerprints, *policy_digests, ",".join(f"{p:.12g}" for p in models.prior)):
        h.update(part.encode())
    return h.hexdigest()


def plain_name(candidate: str, why: str = "") -> str:
    """A candidate's name in words: ``usp:3`` is the policy trained for user model 3 (``cluster-3``, which
    ``core.posterior.model_label`` prints as "user model 3" too), ``fixed:4``
    level 4 always; ``why`` (e.g. "by expected value") joins the parenthesis."""
    kind, _, arg = candidate.partition(":")
    if kind == "usp":
        return f"personalised (user model {arg}{', ' + why if why else ''})"
    name = f"fixed level {arg}" if kind == "fixed" else candidate
    return f"{name} ({why})" if why else name


class PersonalisedPolicy:
    """``ports.Policy`` for the pipeline of ``core.assessment`` (see the module docstring)."""

    name = "personalised"

    def __init__(self, models: ModelSet, learners: list[tuple[str, QLearner]], fingerprint: str, path: Path | None,
                 turns: int, schedule: tuple[int, ...], kappa: float, margin: float, learning: bool,
                 saved: dict[str, Any] | None = None, use_engagement: bool = False, guidance: float = 0.0,
                 pseudonym: str | None = None) -> None:
        self.models = models
        self.pseudonym = pseudonym  # whose state this is (stored in the file; another participant's is refused)
        self.learners = learners
        self.fingerprint = fingerprint
        self.path = Path(path) if path is not None else None  # None: the session folder, once it exists
        self.learning = learning
        self.use_engagement = use_engagement
        self.saved = saved or {}
        self.guidance = Guidance(guidance, self.saved.get("guided"))
        history = list(self.saved.get("sessions", []))
        if history:  # a returning participant: the posterior carried over already holds an assessment
            schedule = ()
        cands = [assessment.Candidate(f"usp:{c}", baselines.learner_table(lr)) for c, lr in learners]
        cands += [assessment.Candidate(f"fixed:{lv}", evaluation.fixed_level_policy(lv)) for lv in (1, 2, 3, 4)]
        self.pers = assessment.Personaliser(
            models, cands, schedule, kappa, margin, turns, mode=Choice.EXPECTED_VALUE,
            own_policy=tuple(range(len(learners))), process="paper",
            start_log_w=self.saved.get("log_w"), start_wins=self.saved.get("wins"),
            start_turns=self.saved.get("played"), start_map_log_w=self.saved.get("map_log_w"))
        self.history = history
        self.turn = 0
        self.session_dir: Path | None = None
        self.started = datetime.now(timezone.utc).isoformat(timespec="seconds")
        self.last_action_phase = "assessment" if schedule else "personalised"
        self._closed = False

    # -- ports.Policy ------------------------------------------------------------------------------

    def act(self, state: int, rng: np.random.Generator) -> int:
        self.last_action_phase = "assessment" if self.pers.in_assessment(self.turn) else "personalised"
        return int(self.pers.act(np.array([state]), self.turn, rng, bonus=self.guidance_bonus(state))[0])

    def guidance_bonus(self, state: int) -> np.ndarray | None:
        """(1, C): the supervisor's overrides in ``state`` as extra value for the candidates that play them
        (the rule of ``policies.base``, per candidate over the candidates' expected values): with
        guidance 1 a candidate that always plays the action the supervisor always chose here is
        preferred; 0 turns it off."""
        if not self.guidance.active(state):
            return None
        bonus = self.guidance.bonus(state, self.pers.expected_values(self.turn)[0],
                                    [c.table[state] for c in self.pers.candidates])
        return None if bonus is None else bonus[None]

    def observe(self, transition: Transition) -> None:
        if self._closed:
            raise ValueError("policy is closed: observe() after close()")
        t = transition
        e = None if (t.engagement is None or not self.use_engagement) else np.array([t.engagement])
        self.pers.update(np.array([t.next_state]), np.array([t.score > 0]), e)
        if self.learning:
            for i, (_c, learner) in enumerate(self.learners):
                learner.update(t.state, t.action, t.score, t.engagement, t.next_state, t.done)
                self.pers.set_candidate_table(i, baselines.learner_table(learner))
        self.turn += 1
        self.save()

    def bind_state_dir(self, folder: Path) -> None:
        self.session_dir = Path(folder)  # named in the participant's session history
        if self.path is None:  # policy.state_path "{session}": nothing carried over, saved with the session
            self.path = session_state_file(self.name, self.session_dir)

    def probabilities(self, state: int) -> np.ndarray | None:
        """P(a | state) of the next choice: the assessment's level, else the followed candidate's."""
        if self.pers.in_assessment(self.turn):
            out = np.zeros(mdp.N_ACTIONS)
            out[self.pers.schedule[self.turn] - 1] = 1.0
            return out
        current = int(self.pers.current[0])
        if current < 0:
            current = int(self.pers.expected_values(self.turn)[0].argmax())
        return self.pers.candidates[current].table[state].copy()

    def guide(self, state: int, action: int) -> None:
        """A supervisor's override: counted (kept across sessions) and, with ``policy.guidance`` > 0,
        turned into extra value for the candidates that play it (``guidance_bonus``); the candidate
        learners learn the overridden turn in ``observe`` like any other (off-policy)."""
        if self.learning:
            self.guidance.record(state, action)

    def snapshot(self) -> dict | None:
        """The whole state (a session checkpoint carries it; ``restore`` goes back to it)."""
        pers = self.pers.snapshot()
        return {**self.payload(), "turn": self.turn,
                **{k: pers[k] for k in ("current", "switches", "full", "schedule")},
                "history": self.history, "started": self.started}

    def restore(self, data: dict | None) -> None:
        if not data:
            return
        # this session's own assessment and the sessions before it (the participant file already
        # holds the interrupted session itself, which is not a previous one)
        self.pers.restore(data)
        self.turn = self.pers.turn
        self.history = list(data["history"])
        self.started = str(data["started"])
        if "guided" in data:
            self.guidance.counts = np.array(data["guided"], dtype=np.int64)
        restore_learners(self.learners, data["learners"], self.path or Path("checkpoint"))
        for i, (_c, learner) in enumerate(self.learners):
            self.pers.set_candidate_table(i, baselines.learner_table(learner))

    def close(self) -> None:
        if not self._closed:
            self.save()
        self._closed = True

    def status(self) -> dict[str, Any]:
        """What the record and the operator see: phase of the next turn, posterior, the match, the choice."""
        w = self.pers.posterior()[0]
        best = int(w.argmax())
        current = int(self.pers.current[0])
        following = self.pers.candidates[current].name if current >= 0 else None
        phase = self.last_action_phase
        ranked = sorted(zip(self.models.names, w), key=lambda x: -x[1])
        post = " | ".join(f"{model_label(n)} {p:.2f}" for n, p in ranked)
        levels = self.pers.level_estimates()[0]
        return {
            "phase": phase,
            "posterior": {n: round(float(p), 4) for n, p in zip(self.models.names, w)},
            "matched": self.models.names[best], "match_probability": round(float(w[best]), 4),
            "following": following, "policy": plain_name(following) if following else None,
            "switches": int(self.pers.switches[0]),
            "level_success": [round(float(x), 4) for x in levels],
            "posterior_text": post,
            "progress": f"           posterior: {post}" + (
                f" -> policy: {plain_name(following, 'by expected value')}" if following
                else " (assessment: levels set in advance)"),
            "summary": (f"matched {model_label(self.models.names[best])} (posterior {w[best]:.2f}; {post}); "
                        + (f"policy: {plain_name(following)}, chosen by its expected score under the posterior over "
                           "all the user models (so not always the matched model's own policy)" if following
                           else "policy: the assessment (levels set in advance)")
                        + "; estimated success by level " + " ".join(f"L{i + 1} {x:.2f}" for i, x in enumerate(levels))),
        }

    # -- the participant's file -----------------------------------------------------------------------

    def payload(self) -> dict[str, Any]:
        p = self.pers
        pers = p.snapshot()
        entry = {"started": self.started, "session": str(self.session_dir) if self.session_dir else None,
                 "turns": self.turn, "assessment": len(p.schedule), **{k: v for k, v in self.status().items()
                                                                       if k in ("matched", "match_probability",
                                                                                "following", "switches")}}
        return {
            "pseudonym": self.pseudonym, "mdp_definition": mdp.DEFINITION, "models_fingerprint": self.fingerprint,
            "models": list(self.models.names), "kappa": p.kappa, "margin": p.margin,
            **{k: pers[k] for k in ("log_w", "map_log_w", "wins", "played")},
            "learners": {c: lr.state_dict() for c, lr in self.learners},
            "sessions": self.history + [entry], "guided": self.guidance.counts.tolist(),
            "updated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        }

    def save(self) -> None:
        if self.path is not None:  # None: the session folder does not exist yet, nothing has been played
            PARTICIPANT.save(self.path, self.payload())


def read_state(path: Path, fingerprint: str, pseudonym: str | None = None) -> dict[str, Any]:
    """A participant's saved state, checked; DataError in one line otherwise (module docstring).
    A state that names another participant than ``pseudonym`` is refused (a file copied between folders)."""
    saved = PARTICIPANT.read(path, fingerprint, pseudonym)
    if saved.get("mdp_definition") != mdp.DEFINITION:
        raise DataError(f"{path}: participant state made for another MDP ({str(saved.get('mdp_definition'))[:40]}...); "
                        f"{FRESH}")
    for key in ("log_w", "map_log_w", "wins", "played", "learners", "sessions"):
        if key not in saved:
            raise DataError(f"{path}: participant state lacks {key!r}; {FRESH}")
    return saved


def restore_learners(learners: list[tuple[str, QLearner]], tables: dict[str, Any], path: Path) -> None:
    """Put saved tables back into the candidate learners; DataError naming ``path`` when they do not fit."""
    for cid, learner in learners:
        saved = tables.get(cid)
        if saved is None:
            raise DataError(f"{path}: participant state lacks the learner of cluster {cid}; {FRESH}")
        try:
            learner.load_state_dict(saved)
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"{path}: invalid learner tables of cluster {cid} ({exc}); {FRESH}") from None


def load_personalised(path: Path | None, pseudonym: str, turns: int, schedule: Sequence[int], kappa: float,
                      margin: float, learning: bool, fresh: bool, guidance: float = 0.0,
                      models_dir: Path | None = None, policies_dir: Path | None = None,
                      use_engagement: bool = False, task: Any = None) -> PersonalisedPolicy:
    """The personalised policy for ``pseudonym`` from the shipped models and policies and the
    participant's saved state at ``path`` (None: kept in the session folder, nothing carried over);
    see the module docstring. ``guidance``: how much the supervisor's overrides weigh in the choice
    (``PersonalisedPolicy.guidance_bonus``). ``task``: the session's (None: the sequence task); under a task
    the published data are not of, the user models are its own simulated users (``task_models``)."""
    own = task_models(task)
    if own is not None:
        models, fingerprint = own
        saved = open_saved(path, fresh, lambda f: read_state(f, fingerprint, pseudonym), "personalised", log)
        return PersonalisedPolicy(models, [], fingerprint, path, turns, tuple(int(x) for x in schedule), kappa,
                                  margin, learning, saved, False, guidance, pseudonym)
    manifest = artifacts.load_manifest(models_dir)
    rows = manifest.get("clusters", [])
    if not rows:
        raise DataError("the user model folder lists no clusters; refit with `nao-trainer fit`")
    sims = [artifacts.load_simulator(str(r["id"]), models_dir) for r in rows]
    sizes = np.array([float(r.get("size") or 1.0) for r in rows])
    models = ModelSet(tuple(s.name for s in sims), np.stack([s.p_success for s in sims]),
                      np.stack([s.engagement for s in sims]), sizes,
                      np.array([float(r.get("rmse_engagement") or 0.13) for r in rows]) if use_engagement else None)
    folder = Path(policies_dir) if policies_dir else policy_files.default_policies_dir()
    pman = policy_files.read_manifest(folder)
    learners, digests = [], []
    for r, sim in zip(rows, sims):
        cid = str(r["id"])
        method = pman.get("default_method", {}).get(cid)
        if method is None:
            raise DataError(f"{folder}: no trained policy for cluster {cid}; train with `nao-trainer train --out {folder}`")
        policy_path = folder / policy_files.policy_filename(cid, method)
        payload = policy_files.read_policy_file(policy_path)
        policy_files.check_simulator(payload, sim, policy_path)
        learners.append((cid, policy_files.learner_from_payload(payload, policy_path)))
        digests.append(f"{cid}:{method}:{payload['simulator']['fingerprint']}")
    fingerprint = models_fingerprint(models, [s.fingerprint() for s in sims], digests)
    saved = open_saved(path, fresh, lambda f: read_state(f, fingerprint, pseudonym), "personalised", log)
    if saved is not None:
        restore_learners(learners, saved["learners"], Path(path))
        log.warning("policy personalised: %s returns after %d session(s): starting from the saved posterior (%s); "
                    "no assessment", pseudonym, len(saved["sessions"]), path)
    return PersonalisedPolicy(models, learners, fingerprint, path, turns, tuple(int(x) for x in schedule), kappa,
                              margin, learning, saved, use_engagement, guidance, pseudonym)


def task_models(task: Any) -> tuple[ModelSet, str] | None:
    """(user models, fingerprint) of a task the shipped models are not of: its own simulated users
    (``learn.users.policy_users``), equal prior weights. Their success depends on the level only, so each one's
    best policy is a fixed level: the candidates are the four fixed levels (no trained per-model policy).
    None for the sequence task (the shipped models); one ``ConfigError`` line for a task without users."""
    users = policy_users(task, "personalised")
    if users is None:
        return None
    sims = [u.truth for u in users]
    models = ModelSet(tuple(s.name for s in sims), np.stack([s.p_success for s in sims]),
                      np.stack([s.engagement for s in sims]), np.ones(len(sims)), None)
    return models, models_fingerprint(models, [f"task:{task.name}"] + [s.fingerprint() for s in sims], [])


# -- the plug-in's entry points (policies.kinds.PERSONALISED) ----------------------------------------


def live(ctx: LiveContext) -> PersonalisedPolicy:
    own = ctx.settings
    return load_personalised(ctx.state_file, ctx.participant, ctx.turns, own.assessment, float(own.kappa),
                             float(own.margin), ctx.common.learning, ctx.fresh, guidance=ctx.common.guidance,
                             task=ctx.task)


class PersonalisedSessions:
    """The offline form: ``core.assessment.Personaliser`` with the shipped user models and policies, the
    assessment in session 1 and the posterior carried to the next session (its candidate learners do
    not keep learning: the live policy's small in-session updates are left out)."""

    def __init__(self, ctx: OfflineContext) -> None:
        own = ctx.settings
        live_policy = load_personalised(None, "offline", ctx.turns, own.assessment, float(own.kappa),
                                        float(own.margin), False, False, task=ctx.task)
        self.pers = live_policy.pers
        self.assessment = tuple(live_policy.pers.schedule)
        self.turns = ctx.turns

    def start(self, n: int, session: int) -> assessment.Personaliser:
        """Session ``session`` (1-based) for the same ``n`` participants as the session before."""
        pers = self.pers
        carried = None if session == 1 else (pers.log_w.copy(), pers.map_log_w.copy(), pers.wins.copy(),
                                             pers.played.copy())
        pers.schedule = self.assessment if session == 1 else ()  # a returning participant is not assessed again
        pers.reset(n, "paper")
        if carried is not None:
            pers.log_w, pers.map_log_w, pers.wins, pers.played = carried
        return pers


def offline(ctx: OfflineContext) -> PersonalisedSessions:
    return PersonalisedSessions(ctx)
