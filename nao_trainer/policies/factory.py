"""The policy a study's ``policy`` section names, for one participant, and its offline form: through the registry.

Which policies exist, what settings each takes, whether it keeps a participant state and how it is
built are the policy's own declaration (``policies.plugin.PolicyKind``, registered in
``nao_trainer.registry``); nothing here knows a policy by name.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from nao_trainer import registry
from nao_trainer.errors import ConfigError
from nao_trainer.policies.participant_state import state_file
from nao_trainer.policies.plugin import LiveContext, OfflineContext, policy_kind
from nao_trainer.ports import Policy


def make_policy(section: Any, participant: str, output: Path, *, turns: int, fresh: bool = False,
                task: Any = None) -> Policy:
    """The policy ``section.kind`` names (the ``policy`` section of a study config) for the participant
    ``participant`` (pseudonym) of a study writing to ``output``, for sessions of ``turns`` turns of ``task``
    (None: the sequence task); ``fresh``: set the participant's saved learning state aside (``--fresh-policy``)."""
    declared, argument = policy_kind(section.kind)
    path = state_file(section.kind, section.state_path, participant, output) if declared.persists else None
    build = registry.resolve(declared.live, f"policy {declared.name!r}")
    return build(LiveContext(section.kind, argument, declared.own(section), section, participant, Path(output), path,
                             int(turns), bool(fresh), task))


def offline_policy(section: Any, turns: int, task: Any = None) -> Any:
    """The policy of ``section`` on a batch of simulated participants of ``task`` (None: the sequence task),
    session after session (``policies.plugin``: ``start(n, session)`` gives a ``core.evaluation.EpisodePolicy``)."""
    declared, argument = policy_kind(section.kind)
    if declared.offline is None:
        raise ConfigError(f"policy {declared.name!r} declares no offline form: it cannot be simulated "
                          "(study power, evaluate)")
    build = registry.resolve(declared.offline, f"policy {declared.name!r} (offline)")
    return build(OfflineContext(section.kind, argument, declared.own(section), section, int(turns), task))
