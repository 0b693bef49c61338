"""Trained user-specific policies on disk: the policy file format and a policy folder's manifest.

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

The live policy that plays such a file in a session (``usp:CLUSTER[:METHOD]``) is
``policies.learned``; its participant state file is a policy file too.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer import __version__
from nao_trainer.core import mdp, processes
from nao_trainer.core.qlearning import METHOD_TEXT, QConfig, QLearner
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import DataError
from nao_trainer.files import PROJECT_ROOT, JsonFormat, read_json, write_json_atomic

FORMAT = "nao-trainer/user-specific-policy"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
MANIFEST_FORMAT = "nao-trainer/user-specific-policies"
#: Where the policies trained on the default user models ship.
DEFAULT_POLICIES_DIR = PROJECT_ROOT / "sim" / "policies"
POLICIES_ENV = "NAO_TRAINER_POLICIES"
RETRAIN = "retrain with `nao-trainer train --out DIR` (or restore the file)"
#: The fix for a participant's state file (a policy file too): never retrain, start afresh and keep it.
FRESH = "start from the trained policy with --fresh-policy (the old file is kept beside it)"


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
        **learner.state_dict(),  # q, h, h_counts, visits
        "simulator": {"name": simulator.name, "fingerprint": simulator.fingerprint()},
        "training": {**training, "nao_trainer_version": __version__},  # no timestamp: reruns are bit-identical
        "live": {"turns_learned": 0, "turns_without_engagement": 0, "updated": None},
    }


def save_policy_file(path: Path, payload: dict[str, Any]) -> None:
    """Write a policy file (payload + checksum) atomically."""
    POLICY_FILE.write(path, payload)


def read_policy_file(path: Path, process: str = "paper", fix: str = RETRAIN) -> dict[str, Any]:
    """The verified payload of a policy file; DataError naming the file and ``fix`` otherwise
    (``FRESH`` for a participant's state file).

    Checks, in order: readable JSON, format and version, checksum, state/action definition (the
    policy must be made for the decision process ``process``, ``core.processes``).
    """
    path = Path(path)
    payload = dataclasses.replace(POLICY_FILE, fix=fix).read(path, DataError)
    check_definition(payload, path, process, fix)
    return payload


def policy_process(payload: dict[str, Any]) -> str | None:
    """The decision process (``core.processes`` name) a payload was made for, None if unknown."""
    proc = processes.by_definition(str(payload.get("mdp_definition")))
    return None if proc is None else proc.name


def check_definition(payload: dict[str, Any], path: Path, process: str = "paper", fix: str = RETRAIN) -> None:
    """Refuse a policy made for another state/action definition, naming what differs."""
    proc = processes.get(process)
    made_for = policy_process(payload)
    if made_for is not None and made_for != proc.name:
        raise DataError(f"{path}: policy was made for the {made_for} MDP, not the {proc.name} MDP; "
                        f"use --mdp {made_for} or retrain with `nao-trainer train --mdp {proc.name}`")
    if payload.get("mdp_definition") != proc.definition:
        raise DataError(f"{path}: policy was trained for another state/action definition "
                        f"({payload.get('mdp_definition')!r}, this build: {mdp.DEFINITION!r}); {fix}")
    states = proc.labels()
    if payload.get("states") != states:
        raise DataError(f"{path}: policy's state list differs from this build's {len(states)} states; {fix}")
    if payload.get("actions") != list(mdp.ACTION_NAMES):
        raise DataError(f"{path}: policy's actions {payload.get('actions')} differ from "
                        f"{list(mdp.ACTION_NAMES)}; {fix}")


def learner_from_payload(payload: dict[str, Any], path: Path, fix: str = RETRAIN) -> QLearner:
    """Rebuild the Q-learner of a verified payload; DataError naming the bad field."""
    try:
        config = QConfig.from_dict(payload["hyperparameters"])
        return QLearner(payload["method"], config, np.array(payload["q"], dtype=float),
                        np.array(payload["h"], dtype=float), np.array(payload["h_counts"], dtype=np.int64),
                        np.array(payload["visits"], dtype=np.int64), policy_process(payload) or "paper")
    except KeyError as exc:
        raise DataError(f"{path}: policy file lacks field {exc.args[0]!r}; {fix}") from None
    except (TypeError, ValueError) as exc:
        raise DataError(f"{path}: invalid policy tables ({exc}); {fix}") from None


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
