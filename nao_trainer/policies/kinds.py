"""The project's own policy kinds, declared (``policies.plugin.PolicyKind``): each with its settings.

``registry.BUILTIN`` points at these objects; the behaviour lives in the policy's home module
(``fixed``, ``learned``, ``personalised``, ``bayes``), named by a lazy ``"module:function"`` entry point.
Each policy declares its own keys of the ``policy`` section here, with its rules, light (standard
library and ``core.settings``: ``session.config`` composes the section at import, ``--help`` stays fast).
"""
from __future__ import annotations

import re

from nao_trainer.core.settings import setting, settings
from nao_trainer.policies.plugin import NUMBER, PolicyKind


def check_schedule(value: list) -> str | None:
    from nao_trainer.core import mdp  # numpy: lazily, `nao-trainer --help` imports this module without it

    bad = [a for a in value if a not in mdp.ACTION_NAMES]
    if bad:
        return f"unknown action {bad[0]!r}; use {', '.join(mdp.ACTION_NAMES)}"
    if not value:
        return "needs at least one action"
    if value[0] not in mdp.ACTION_NAMES[:4]:
        return f"must start with a level action (L1..L4), got {value[0]!r}: there is no outcome to give feedback on yet"
    return None


def check_assessment(value: list) -> str | None:
    return None if len(value) <= 12 and all(1 <= x <= 4 for x in value) else "must list levels 1..4, at most 12 turns"


def check_objective(value: str) -> str | None:
    """The objective's one parser (``core.objective.parse``) is its rule."""
    from nao_trainer.core import objective  # numpy: lazily, `nao-trainer --help` imports this module without it

    try:
        objective.parse(value)
    except ValueError:
        return ("must be 'score', 'target-p:R' (each turn's success probability near R; 'target:R' is its old name) "
                "or 'target-rate:R' (the session's success rate near R), 0 < R < 1, e.g. target-rate:0.75")
    return None


def check_prior(value: str) -> str | None:
    # a path is resolved and checked by session.config (against the folder of the file that sets it)
    return None if value.strip() else "must be 'clusters', 'psychometric', a psychometric prior file or a folder"


def check_usp(argument: str) -> str | None:
    if re.fullmatch(r"[^:\s]+(:[A-Za-z0-9_-]+)?", argument):
        return None
    return f"policy 'usp:{argument}': use usp:CLUSTER or usp:CLUSTER:METHOD"


@settings
class ScheduleSettings:
    schedule: tuple[str, ...] = setting(("L1", "L2", "RF1", "L2", "L3", "RF2", "L3", "L2", "RF1", "L4"), kind=list,
                                        item=str, check=check_schedule, doc="actions, cycled (policy schedule)")


@settings
class PersonalisedSettings:
    """``personalised`` (policies.personalised, docs/explanation/personalisation.md)."""

    assessment: tuple[int, ...] = setting((2, 2, 3, 3, 4, 4), kind=list, item=int, check=check_assessment,
                                          doc="levels of the first turns (a returning participant skips them)")
    kappa: float = setting(10.0, kind=NUMBER, min=0.01, doc="strength (pseudo-turns) of the per-level Beta priors")
    margin: float = setting(0.5, kind=NUMBER, min=0, doc="expected-value gain a new policy needs")


@settings
class BayesSettings:
    """``bayes`` (policies.bayes, core/objective.py)."""

    objective: str = setting("score", kind=str, check=check_objective,
                             doc="score (equation (1)) | target-p:R (each turn's success near R; target:R) | "
                                 "target-rate:R (the session's success rate near R)")
    prior: str | None = setting(None, kind=str, nullable=True, check=check_prior,
                                doc="clusters | psychometric | a psychometric prior file | a folder of user simulators; "
                                    "null = psychometric under target:R, clusters under score")


SCHEDULE = PolicyKind("schedule", "a fixed schedule of actions, cycled (policy.schedule)",
                      live="nao_trainer.policies.fixed:live_schedule", offline="nao_trainer.policies.fixed:offline_schedule",
                      settings=ScheduleSettings)
RANDOM = PolicyKind("random", "a seeded uniform choice among the allowed actions",
                    live="nao_trainer.policies.fixed:live_random", offline="nao_trainer.policies.fixed:offline_random")
USP = PolicyKind("usp", "a trained user-specific Q-learning policy (sim/policies), learning on in the session",
                 live="nao_trainer.policies.learned:live", offline="nao_trainer.policies.learned:offline",
                 persists=True, argument="CLUSTER[:METHOD]", check_argument=check_usp)
PERSONALISED = PolicyKind("personalised", "assess, match the user models, choose by posterior expected value, "
                          "keep learning (docs/explanation/personalisation.md)",
                          live="nao_trainer.policies.personalised:live",
                          offline="nao_trainer.policies.personalised:offline",
                          settings=PersonalisedSettings, persists=True, state_filename="personalised.json")
BAYES = PolicyKind("bayes", "the exact Bayes-adaptive planner over per-level counts (docs/explanation/personalisation.md)",
                   live="nao_trainer.policies.bayes:live", offline="nao_trainer.policies.bayes:offline",
                   settings=BayesSettings, persists=True, state_filename="bayes.json")
