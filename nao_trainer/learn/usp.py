"""User-specific policies (USP): the policy file format and the live learning policy.

A policy file is JSON::

    {"format": "nao-trainer/user-specific-policy", "format_version": 1,
     "sha256": "<hex digest of the canonical payload>",
     "payload": {
        "cluster": "2", "method": "shaping", "method_text": "...",
        "hyperparameters": {"alpha": 0.08, "gamma": 0.95, "tau0": ..., ...},
        "mdp_definition": core.mdp.DEFINITION,
        "states": ["(3, 0, -4)", ..., "START"], "actions": ["L1", ..., "RF2"],
        "q": [[...6...] x 109], "h": [...], "h_counts": [...], "visits": [...109...],
        "simulator": {"name": "cluster-2", "fingerprint": "<UserSimulator.fingerprint()>"},
        "training": {provenance: seeds, episodes, turns, models, command, ...},
        "live": {"turns_learned": 0, "turns_without_engagement": 0, "updated": null}}}

The canonical payload is ``json.dumps(payload, sort_keys=True, separators=(",", ":"))``; its
SHA-256 detects a torn or edited file. A file whose ``mdp_definition``, states or actions differ
from this build, or whose simulator fingerprint differs from the user model it claims to be
trained on, is refused: it would choose actions for states that mean something else.

``load_policy("usp:CLUSTER[:METHOD]", learning, state_path)`` returns a ``LivePolicy``
(``ports.Policy``) that keeps learning from the session's real outcomes and engagement with the
method it was trained with, and writes its whole state atomically to ``state_path`` after every
turn. If ``state_path`` already holds the state of the same policy (a previous or interrupted
session of this participant), learning resumes from it.
"""
from __future__ import annotations

import os
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer import __version__
from nao_trainer.core import mdp, processes
from nao_trainer.core.qlearning import METHOD_TEXT, METHODS, QConfig, QLearner, policy_probabilities
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import PROJECT_ROOT, JsonFormat, read_json, write_json_atomic
from nao_trainer.ports import Transition

FORMAT = "nao-trainer/user-specific-policy"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
MANIFEST_FORMAT = "nao-trainer/user-specific-policies"
#: Where the policies trained on the default user models ship.
DEFAULT_POLICIES_DIR = PROJECT_ROOT / "sim" / "policies"
POLICIES_ENV = "NAO_TRAINER_POLICIES"
RETRAIN = "retrain with `nao-trainer train --out DIR` (or restore the file)"


def default_policies_dir() -> Path:
    """``$NAO_TRAINER_POLICIES`` when set, else ``<repo>/sim/policies``."""
    env = os.environ.get(POLICIES_ENV)
    return Path(env) if env else DEFAULT_POLICIES_DIR


def policy_filename(cluster: str, method: str) -> str:
    return f"usp_{cluster}_{method}.json"


# ----------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------


#: A policy file: a checksummed envelope of the payload (``make_payload``).
POLICY_FILE = JsonFormat(FORMAT, FORMAT_VERSION, "user-specific policy", "policy", RETRAIN)
#: A policy folder's manifest (flat, no checksum).
MANIFEST_FILE = JsonFormat(MANIFEST_FORMAT, 1, "policy manifest", "policy manifest", RETRAIN)


def make_payload(learner: QLearner, cluster: str, simulator: UserSimulator,
                 training: dict[str, Any]) -> dict[str, Any]:
    """The payload of a policy file for ``learner`` trained on ``simulator`` (cluster id ``cluster``)."""
    return {
        "cluster": str(cluster),
        "method": learner.method,
        "method_text": METHOD_TEXT[learner.method],
        "hyperparameters": learner.config.to_dict(),
        "mdp_definition": processes.get(learner.process).definition,
        "states": processes.get(learner.process).labels(),
        "actions": list(mdp.ACTION_NAMES),
        "q": learner.q.tolist(),
        "h": learner.h.tolist(),
        "h_counts": learner.h_counts.tolist(),
        "visits": learner.visits.tolist(),
        "simulator": {"name": simulator.name, "fingerprint": simulator.fingerprint()},
        "training": {**training, "nao_trainer_version": __version__},  # no timestamp: reruns are bit-identical
        "live": {"turns_learned": 0, "turns_without_engagement": 0, "updated": None},
    }


def save_policy_file(path: Path, payload: dict[str, Any]) -> None:
    """Write a policy file (payload + checksum) atomically."""
    POLICY_FILE.write(path, payload)


def read_policy_file(path: Path, process: str = "paper") -> dict[str, Any]:
    """The verified payload of a policy file; DataError naming the file and the fix otherwise.

    Checks, in order: readable JSON, format and version, checksum, state/action definition (the
    policy must be made for the decision process ``process``, ``core.processes``).
    """
    path = Path(path)
    payload = POLICY_FILE.read(path, DataError)
    check_definition(payload, path, process)
    return payload


def policy_process(payload: dict[str, Any]) -> str | None:
    """The decision process (``core.processes`` name) a payload was made for, None if unknown."""
    proc = processes.by_definition(str(payload.get("mdp_definition")))
    return None if proc is None else proc.name


def check_definition(payload: dict[str, Any], path: Path, process: str = "paper") -> None:
    """Refuse a policy made for another state/action definition, naming what differs."""
    proc = processes.get(process)
    made_for = policy_process(payload)
    if made_for is not None and made_for != proc.name:
        raise DataError(f"{path}: policy was made for the {made_for} MDP, not the {proc.name} MDP; "
                        f"use --mdp {made_for} or retrain with `nao-trainer train --mdp {proc.name}`")
    if payload.get("mdp_definition") != proc.definition:
        raise DataError(f"{path}: policy was trained for another state/action definition "
                        f"({payload.get('mdp_definition')!r}, this build: {mdp.DEFINITION!r}); {RETRAIN}")
    states = proc.labels()
    if payload.get("states") != states:
        raise DataError(f"{path}: policy's state list differs from this build's {len(states)} states; {RETRAIN}")
    if payload.get("actions") != list(mdp.ACTION_NAMES):
        raise DataError(f"{path}: policy's actions {payload.get('actions')} differ from "
                        f"{list(mdp.ACTION_NAMES)}; {RETRAIN}")


def learner_from_payload(payload: dict[str, Any], path: Path) -> QLearner:
    """Rebuild the Q-learner of a verified payload; DataError naming the bad field."""
    try:
        config = QConfig.from_dict(payload["hyperparameters"])
        return QLearner(payload["method"], config, np.array(payload["q"], dtype=float),
                        np.array(payload["h"], dtype=float), np.array(payload["h_counts"], dtype=np.int64),
                        np.array(payload["visits"], dtype=np.int64), policy_process(payload) or "paper")
    except KeyError as exc:
        raise DataError(f"{path}: policy file lacks field {exc.args[0]!r}; {RETRAIN}") from None
    except (TypeError, ValueError) as exc:
        raise DataError(f"{path}: invalid policy tables ({exc}); {RETRAIN}") from None


def check_simulator(payload: dict[str, Any], simulator: UserSimulator, path: Path) -> None:
    """Refuse a policy trained on another version of its user model."""
    stored = (payload.get("simulator") or {}).get("fingerprint")
    if stored != simulator.fingerprint():
        raise DataError(f"{path}: trained on user model {payload.get('simulator', {}).get('name')!r} with "
                        f"fingerprint {str(stored)[:12]}..., but the current model {simulator.name!r} has "
                        f"{simulator.fingerprint()[:12]}... (refitted since?); {RETRAIN}")


def write_manifest(folder: Path, methods: dict[str, Any], default_method: dict[str, str],
                   files: dict[str, str]) -> Path:
    """The index of a policy folder: which files exist and the default method per cluster."""
    path = Path(folder) / MANIFEST
    write_json_atomic(path, {**MANIFEST_FILE.header(),
                             "clusters": {c: list(m) for c, m in methods.items()},
                             "default_method": default_method, "files": files})
    return path


def read_manifest(folder: Path) -> dict[str, Any]:
    path = Path(folder) / MANIFEST
    data = read_json(path, DataError, f"no trained policies here; create them with `nao-trainer train --out {folder}`")
    MANIFEST_FILE.check(data, path, DataError)
    if not isinstance(data.get("default_method", {}), dict):
        raise DataError(f"{path}: policy manifest of an unknown version or shape; {RETRAIN}")
    return data


# ----------------------------------------------------------------------------------------------
# Live use
# ----------------------------------------------------------------------------------------------


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
        self.guidance = float(guidance)
        #: How often the supervisor chose each action in each state (``guide``); kept with the state.
        self.guided = np.zeros((mdp.N_STATES, mdp.N_ACTIONS), dtype=np.int64)
        for key, n in (payload.get("live", {}).get("guided") or {}).items():
            s, a = (int(x) for x in key.split(","))
            self.guided[s, a] = int(n)
        self.loaded_from: Path | None = None  # the state file learning resumed from (None: the trained policy)
        self._closed = False

    def choice_values(self, state: int) -> np.ndarray:
        """What ``act`` chooses on: the learner's values ``V(s, .)`` plus the guidance term.

        ``G(s, a) = guidance * n(s, a) / n(s) * (max V(s, .) - min V(s, .) + 1)`` over the allowed
        actions, where ``n(s, a)`` counts the supervisor's overrides toward ``a`` in ``s`` and
        ``n(s)`` all of them in ``s``. Scaled by the spread of the values, so it means the same in
        every state: with ``guidance >= 1``, an action the supervisor always chose in ``s`` is
        preferred there by at least ``guidance`` value points. The Q tables themselves learn only
        from outcomes (off-policy, in ``observe``).
        """
        values = self.learner.values(state)
        n = self.guided[state]
        total = n.sum()
        if not (self.guidance and total):
            return values
        allowed = values[mdp.ACTION_MASK[state]]
        spread = float(allowed.max() - allowed.min()) + 1.0
        return values + self.guidance * (n / total) * spread

    def act(self, state: int, rng: np.random.Generator) -> int:
        if not (self.guidance and self.guided[state].any()):
            return self.learner.act(state, rng)
        u = rng.random()  # one uniform, as the learner would draw: the random stream stays aligned
        allowed = np.flatnonzero(mdp.ACTION_MASK[state])
        cum = np.cumsum(self.probabilities(state)[allowed])
        return int(allowed[min(int(np.searchsorted(cum, u * cum[-1], side="left")), len(allowed) - 1)])

    def probabilities(self, state: int) -> np.ndarray:
        if not (self.guidance and self.guided[state].any()):
            return self.learner.probabilities(state)
        return policy_probabilities(self.choice_values(state), mdp.ACTION_MASK[state],
                                    self.learner.inverse_temperature(state))

    def guide(self, state: int, action: int) -> None:
        """The supervisor overrode the policy with ``action`` in ``state``: remember it (the Q update
        happens in ``observe``, off-policy, like any turn)."""
        if not self.learning:
            return
        self.guided[state, action] += 1
        self.payload["live"]["guided"] = {f"{s},{a}": int(self.guided[s, a]) for s, a in zip(*np.nonzero(self.guided))}

    def snapshot(self) -> dict | None:
        """The whole learning state (a session checkpoint carries it)."""
        shift = self.learner._shift
        return {"q": self.learner.q.tolist(), "h": self.learner.h.tolist(), "h_counts": self.learner.h_counts.tolist(),
                "visits": self.learner.visits.tolist(), "live": dict(self.payload["live"]),
                "guided": self.guided.tolist(), "shift": list(shift) if shift is not None else None}

    def restore(self, data: dict | None) -> None:
        if not data:
            return
        lr = self.learner
        lr.q[:] = np.array(data["q"], dtype=float)
        lr.h[:] = np.array(data["h"], dtype=float)
        lr.h_counts[:] = np.array(data["h_counts"], dtype=np.int64)
        lr.visits[:] = np.array(data["visits"], dtype=np.int64)
        lr._shift = (int(data["shift"][0]), float(data["shift"][1])) if data.get("shift") else None
        self.guided[:] = np.array(data["guided"], dtype=np.int64)
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
            self.state_path = Path(folder) / "policy_state.json"

    def save(self) -> None:
        """Write the learner's whole state (a valid policy file) atomically to ``state_path``."""
        if self.state_path is None:
            raise ConfigError("policy.state_path: a learning policy needs a file to save its state to")
        payload = self.payload
        for key in ("q", "h", "h_counts", "visits"):
            payload[key] = getattr(self.learner, key).tolist()
        try:
            self.state_path.parent.mkdir(parents=True, exist_ok=True)
            save_policy_file(self.state_path, payload)
        except OSError as exc:
            raise DataError(f"{self.state_path}: cannot save the policy's state ({exc.strerror or exc}); "
                            "choose a writable policy.state_path") from None

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
                models_dir: Path | None = None, guidance: float = 0.0, fresh: bool = False) -> LivePolicy:
    """The trained policy ``usp:CLUSTER[:METHOD]`` for a live session (see the module docstring).

    METHOD defaults to the folder manifest's ``default_method`` for the cluster (the method whose
    policies scored best in training). The policy's simulator fingerprint must match the current
    user model of that cluster (``nao_trainer.learn.artifacts.load_simulator``). The session passes its
    generator to ``act``.
    """
    from nao_trainer.learn.artifacts import load_simulator

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
    if fresh and state_path is not None and Path(state_path).exists():
        # --fresh-policy: start from the trained policy; the old state is kept beside, never deleted.
        stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
        aside = Path(state_path).with_name(f"{Path(state_path).name}.replaced-{stamp}")
        os.replace(state_path, aside)
        print(f"policy {spec}: starting fresh; the previous state was moved to {aside}", file=sys.stderr)
    if state_path is not None and Path(state_path).exists():
        saved = read_policy_file(Path(state_path))
        for key in ("cluster", "method", "simulator", "hyperparameters"):
            if saved.get(key) != payload.get(key):
                raise DataError(f"{state_path}: holds the learning state of another policy ({key} differs from "
                                f"{path.name}); choose another policy.state_path or delete the file to start "
                                "from the trained policy")
        payload, source = saved, Path(state_path)
    learner = learner_from_payload(payload, source)
    policy = LivePolicy(learner, payload, learning, state_path, guidance)
    if source != path:
        policy.loaded_from = source
        print(f"policy {policy.name}: resuming from {source} ({payload['live']['turns_learned']} live turns learned)",
              file=sys.stderr)
    return policy
