"""A trained user-specific policy driving a live session (``policy.kind: usp:CLUSTER[:METHOD]``).

``load_policy("usp:CLUSTER[:METHOD]", learning, state_path)`` returns a ``LivePolicy``
(``ports.Policy``) that keeps learning from the session's real outcomes and engagement with the
method it was trained with, and writes its whole state atomically to ``state_path`` after every
turn (a policy file, ``learn.policy_files``). If ``state_path`` already holds the state of the
same policy (a previous or interrupted session of this participant), learning resumes from it.
"""
from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.core.qlearning import METHODS, QLearner, policy_probabilities
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.learn.artifacts import load_simulator
from nao_trainer.learn.policy_files import (FRESH, RETRAIN, check_simulator, default_policies_dir, learner_from_payload,
                                            policy_filename, read_manifest, read_policy_file, save_policy_file)
from nao_trainer.policies.base import Guidance, TableSessions, log
from nao_trainer.policies.participant_state import ParticipantState, digest, session_state_file
from nao_trainer.policies.plugin import LiveContext, OfflineContext
from nao_trainer.ports import Transition
from nao_trainer.tasks.base import published


#: What a participant's learning state was made from: it must be the trained policy being loaded.
TRAINED = ("cluster", "method", "simulator", "hyperparameters")


def _made_with(saved: dict[str, Any]) -> str:
    return f"cluster {saved.get('cluster')!r}, method {saved.get('method')!r}"


#: The participant's file (policies.participant_state: one save, read, owner and fingerprint check); a valid
#: policy file, its owner in ``live.pseudonym``.
PARTICIPANT = ParticipantState(lambda p: read_policy_file(p, fix=FRESH), save_policy_file,
                               lambda saved: digest(saved, TRAINED), "another policy",
                               owner=lambda saved: (saved.get("live") or {}).get("pseudonym"), fix=FRESH,
                               saved_what="the policy's state", save_fix="choose a writable policy.state_path")


class LivePolicy:
    """A trained user-specific policy driving a real session (``ports.Policy``).

    ``act`` samples from the softmax over the method's action values (``Q``, or ``Q + beta2 * H``
    for qaug) at the state's current temperature, like during training. With ``learning`` the
    policy applies the training update to every real transition (engagement ``None`` means plain
    reward and no ``H`` update) and saves its state atomically to ``state_path`` after each one;
    without it, nothing changes and nothing is written.
    """

    def __init__(self, learner: QLearner, payload: dict[str, Any], learning: bool, state_path: Path | None,
                 guidance: float = 0.0) -> None:
        # A learning policy needs ``state_path`` only when it saves: without one, the session binds
        # it to its folder once that exists (the policy is loaded and checked before the robot connects).
        self.learner = learner
        self.payload = payload
        self.learning = learning
        self.state_path = Path(state_path) if state_path is not None else None
        self.name = f"usp:{payload['cluster']}:{learner.method}" + ("" if learning else " (frozen)")
        #: How often the supervisor chose each action in each state (``guide``); kept with the state.
        self.guidance = Guidance.from_pairs(guidance, payload.get("live", {}).get("guided"))
        self.loaded_from: Path | None = None  # the state file learning resumed from (None: the trained policy)
        self._closed = False

    def state_report(self, target: Path | None, fresh: bool) -> dict[str, Any]:
        """Which learning state the session starts from (logged as ``policy_state``) and where it saves."""
        loaded = self.loaded_from
        return {"policy": self.name, "loaded_from": str(loaded) if loaded else "trained policy",
                "saves_to": str(target) if target else "session folder", "fresh": fresh,
                "turns_learned": self.payload["live"]["turns_learned"]}

    def choice_values(self, state: int) -> np.ndarray:
        """What ``act`` chooses on: the learner's values ``V(s, .)`` plus the guidance term
        (``policies.base``: per action, spread over the allowed actions' values). The Q tables
        themselves learn only from outcomes (off-policy, in ``observe``)."""
        values = self.learner.values(state)
        bonus = self.guidance.bonus(state, values[mdp.ACTION_MASK[state]])
        return values if bonus is None else values + bonus

    def act(self, state: int, rng: np.random.Generator) -> int:
        if not self.guidance.active(state):
            return self.learner.act(state, rng)
        u = rng.random()  # one uniform, as the learner would draw: the random stream stays aligned
        allowed = np.flatnonzero(mdp.ACTION_MASK[state])
        cum = np.cumsum(self.probabilities(state)[allowed])
        return int(allowed[min(int(np.searchsorted(cum, u * cum[-1], side="left")), len(allowed) - 1)])

    def probabilities(self, state: int) -> np.ndarray:
        if not self.guidance.active(state):
            return self.learner.probabilities(state)
        return policy_probabilities(self.choice_values(state), mdp.ACTION_MASK[state],
                                    self.learner.inverse_temperature(state))

    def guide(self, state: int, action: int) -> None:
        """The supervisor overrode the policy with ``action`` in ``state``: remember it (the Q update
        happens in ``observe``, off-policy, like any turn)."""
        if not self.learning:
            return
        self.guidance.record(state, action)
        self.payload["live"]["guided"] = self.guidance.pairs()

    def snapshot(self) -> dict | None:
        """The whole learning state (a session checkpoint carries it)."""
        return {**self.learner.state_dict(transient=True), "live": dict(self.payload["live"]),
                "guided": self.guidance.counts.tolist()}

    def restore(self, data: dict | None) -> None:
        if not data:
            return
        self.learner.load_state_dict(data)
        self.guidance.counts[:] = np.array(data["guided"], dtype=np.int64)
        self.payload["live"] = dict(data["live"])

    def observe(self, transition: Transition) -> None:
        if not self.learning:
            return
        if self._closed:
            raise ValueError("policy is closed: observe() after close()")
        t = transition
        self.learner.update(t.state, t.action, t.score, t.engagement, t.next_state, t.done)
        live = self.payload["live"]
        live["turns_learned"] += 1
        live["turns_without_engagement"] += int(t.engagement is None)
        live["updated"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
        self.save()

    def status(self) -> dict[str, Any]:
        return {}

    def bind_state_dir(self, folder: Path) -> None:
        """Without a configured state file, a learning policy saves into the session ``folder``."""
        if self.learning and self.state_path is None:
            self.state_path = session_state_file("usp", folder)

    def save(self) -> None:
        """Write the learner's whole state (a valid policy file) atomically to ``state_path``."""
        if self.state_path is None:
            raise ConfigError("policy.state_path: a learning policy needs a file to save its state to")
        self.payload.update(self.learner.state_dict())
        PARTICIPANT.save(self.state_path, self.payload)

    def close(self) -> None:
        if self.learning and not self._closed:
            self.save()
        self._closed = True


def parse_spec(spec: str) -> tuple[str, str | None]:
    """``usp:CLUSTER[:METHOD]`` -> (cluster, method or None)."""
    parts = str(spec).split(":")
    if parts[0] != "usp" or len(parts) not in (2, 3) or not parts[1]:
        raise ConfigError(f"policy {spec!r}: use usp:CLUSTER or usp:CLUSTER:METHOD (METHOD one of "
                          f"{', '.join(METHODS)})")
    method = parts[2] if len(parts) == 3 else None
    if method is not None and method not in METHODS:
        raise ConfigError(f"policy {spec!r}: unknown method {method!r}; use one of {', '.join(METHODS)}")
    return parts[1], method


def load_policy(spec: str, learning: bool, state_path: Path | None, policies_dir: Path | None = None,
                models_dir: Path | None = None, guidance: float = 0.0, fresh: bool = False,
                pseudonym: str | None = None) -> LivePolicy:
    """The trained policy ``usp:CLUSTER[:METHOD]`` for a live session (see the module docstring).

    METHOD defaults to the folder manifest's ``default_method`` for the cluster (the method whose
    policies scored best in training). The policy's simulator fingerprint must match the current
    user model of that cluster (``nao_trainer.learn.artifacts.load_simulator``). The session passes its
    generator to ``act``. ``pseudonym``: the participant; the state file belongs to them (stored
    as ``live.pseudonym``): a state file of another participant is refused.
    """
    cluster, method = parse_spec(spec)
    folder = Path(policies_dir) if policies_dir else default_policies_dir()
    if method is None:
        manifest = read_manifest(folder)
        method = manifest.get("default_method", {}).get(cluster)
        if method not in METHODS:
            known = ", ".join(sorted(manifest.get("default_method", {}))) or "none"
            raise ConfigError(f"policy {spec!r}: no policy for cluster {cluster!r} in {folder} (clusters: {known})")
    path = folder / policy_filename(cluster, method)
    payload = read_policy_file(path)
    if payload.get("cluster") != cluster or payload.get("method") != method:
        raise DataError(f"{path}: holds cluster {payload.get('cluster')!r} method {payload.get('method')!r}, "
                        f"not {cluster!r} {method!r}; {RETRAIN}")
    check_simulator(payload, load_simulator(cluster, models_dir), path)
    source = path
    # --fresh-policy: start from the trained policy; the old state is kept beside, never deleted
    saved = PARTICIPANT.open(state_path, fresh, digest(payload, TRAINED), pseudonym, spec, log, _made_with)
    if saved is not None:
        payload, source = saved, Path(state_path)
    learner = learner_from_payload(payload, source, FRESH if source != path else RETRAIN)
    if pseudonym is not None:
        payload["live"]["pseudonym"] = pseudonym  # the state saved from now on belongs to this participant
    policy = LivePolicy(learner, payload, learning, state_path, guidance)
    if source != path:
        policy.loaded_from = source
        log.warning("policy %s: resuming from %s (%s live turns learned)", policy.name, source,
                    payload["live"]["turns_learned"])
    return policy


# -- the plug-in's entry points (policies.kinds.USP) ------------------------------------------------


def refuse_other_task(ctx: LiveContext | OfflineContext) -> None:
    """A trained policy is trained on a user model fitted on the published data (the sequence task's): under
    another task, one ``ConfigError`` line naming the task and what to do."""
    if not published(ctx.task):
        raise ConfigError(f"policy {ctx.kind!r} under task {ctx.task.name!r}: it is trained on a user model fitted on "
                          "the sequence task's data; use personalised or bayes (they take the task's own simulated users), "
                          "schedule or random")


def live(ctx: LiveContext) -> LivePolicy:
    refuse_other_task(ctx)
    return load_policy(ctx.kind, ctx.common.learning, ctx.state_file, guidance=ctx.common.guidance, fresh=ctx.fresh,
                       pseudonym=ctx.participant)


def offline(ctx: OfflineContext) -> TableSessions:
    """Its trained table (no learning within the simulated sessions)."""
    refuse_other_task(ctx)
    policy = load_policy(ctx.kind, False, None)
    return TableSessions(np.array([policy.probabilities(s) for s in range(mdp.N_STATES)]), ctx.turns)
