"""The policy a study's ``policy`` section names, for one participant."""
from __future__ import annotations

from pathlib import Path

from nao_trainer.errors import ConfigError
from nao_trainer.policies.participant_state import PolicySettings, state_file
from nao_trainer.policies.fixed import FixedSchedule, UniformRandom
from nao_trainer.ports import Policy

KINDS = "'schedule', 'random', 'personalised', 'bayes' or 'usp:CLUSTER[:METHOD]'"


def make_policy(section: PolicySettings, participant: str, output: Path, *, turns: int,
                fresh: bool = False) -> Policy:
    """The policy ``section.kind`` ("schedule", "random", "usp:CLUSTER[:METHOD]", "personalised" or "bayes") for
    the participant ``participant`` (pseudonym) of a study writing to ``output``, for sessions of
    ``turns`` turns; ``fresh``: set the participant's saved learning state aside (``--fresh-policy``)."""
    kind = section.kind
    if kind == "schedule":
        return FixedSchedule(list(section.schedule))
    if kind == "random":
        return UniformRandom()
    if kind not in ("personalised", "bayes") and not kind.startswith("usp:"):
        raise ConfigError(f"policy {kind!r}: use {KINDS}")
    path = state_file(kind, section.state_path, participant, output)
    try:  # the learning policies need the learning stack (scipy, ...), which a minimal install may lack
        if kind == "personalised":
            from nao_trainer.policies.personalised import load_personalised
        elif kind == "bayes":  # the exact Bayes-adaptive planner
            from nao_trainer.policies.bayes import load_bayes
        else:
            from nao_trainer.policies.learned import load_policy
    except ImportError as exc:
        raise ConfigError(f"policy {kind!r}: learned policies are not available in this install ({exc}); "
                          "use --policy schedule or random") from None
    if kind == "personalised":
        return load_personalised(path, participant, turns, section.assessment, float(section.kappa),
                                 float(section.margin), section.learning, fresh, guidance=section.guidance)
    if kind == "bayes":
        return load_bayes(path, participant, turns, section.objective, fresh, section.prior)
    return load_policy(kind, section.learning, path, guidance=section.guidance, fresh=fresh, pseudonym=participant)
