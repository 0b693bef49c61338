"""What a policy plug-in declares, and the ``policy`` section of a study composed from the declarations.

A policy kind is registered once in ``nao_trainer.registry`` (kind ``"policy"``); its entry point names a
``PolicyKind``: its name, its own settings dataclass (declared with ``core.settings``, like
``eeg/settings.py``), whether it keeps a state per participant across sessions (and in which file),
the argument it takes after a colon (``usp:CLUSTER[:METHOD]``), and two lazy entry points
(``"module:function"``, loaded through the registry only when used):

``live``     ``(LiveContext) -> ports.Policy``: the policy of one session;
``offline``  ``(OfflineContext) -> SessionPolicies``: the same policy on a batch of simulated participants,
             session after session (``study power``; ``start(n, session)`` returns a
             ``core.evaluation.EpisodePolicy``).

The study's ``policy`` section stays flat (backward compatible): ``kind`` and the keys every learning
policy shares (``COMMON``: ``learning``, ``state_path``, ``guidance``), then each installed policy's
own keys, each declared once by its owner (``compose_section``). A key declared by two policies is
refused. ``policy_kind("usp:2:shaping")`` is the one parse of a policy string: name before the first
colon, the argument after it, checked by its owner. Light on purpose (standard library and
``core.settings``): ``session.config`` imports it, and ``nao-trainer --help`` stays fast.
"""
from __future__ import annotations

import dataclasses
import string
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from nao_trainer import registry
from nao_trainer.core.settings import schema_of, setting, settings
from nao_trainer.errors import ConfigError

NUMBER = (int, float)
#: ``policy.state_path`` that keeps the state in the session folder (nothing carried over).
SESSION_FOLDER = "{session}"
STATE_PATH_FIELDS = ("pseudonym", "output")
DEFAULT_STATE_FILENAME = "policy_state.json"


@dataclass(frozen=True)
class PolicyKind:
    """A policy plug-in's declaration (module docstring)."""

    name: str
    summary: str  # one line: what it does (``nao-trainer plugins``, ``--help``)
    live: str  # "module:function" (LiveContext) -> ports.Policy
    offline: str | None = None  # "module:function" (OfflineContext) -> SessionPolicies; None: not simulable
    settings: type | None = None  # its own settings dataclass (keys of the ``policy`` section)
    persists: bool = False  # keeps a state per participant across sessions (participant folder, lock, resume)
    state_filename: str = DEFAULT_STATE_FILENAME  # its file in the participant's folder
    argument: str | None = None  # what follows ``name:`` in words ("CLUSTER[:METHOD]"); None: no argument
    check_argument: Callable[[str], str | None] | None = None  # the argument's rule: a problem or None

    def problem(self, argument: str | None) -> str | None:
        """What is wrong with ``argument`` (the part after ``name:``), or None."""
        if self.argument is None:
            return None if argument is None else f"policy {self.name!r} takes no argument (got {self.name}:{argument})"
        if not argument:
            return f"policy {self.name!r} needs {self.name}:{self.argument}"
        return self.check_argument(argument) if self.check_argument else None

    def own(self, section: Any) -> Any:
        """This policy's settings object, from the (flat) ``policy`` section; None when it declares none."""
        if self.settings is None:
            return None
        return self.settings(**{f.name: getattr(section, f.name) for f in dataclasses.fields(self.settings)})

    def keys(self) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(self.settings)) if self.settings else ()


@dataclass(frozen=True)
class LiveContext:
    """What a policy's ``live`` entry point is given for one session."""

    kind: str  # the whole policy string ("usp:2:shaping")
    argument: str | None  # the part after the first colon
    settings: Any  # the policy's own settings object (``PolicyKind.own``), or None
    common: Any  # the ``policy`` section (learning, state_path, guidance)
    participant: str  # pseudonym
    output: Path  # the study's output folder
    state_file: Path | None  # where its participant state lives (None: the session folder), for persisting kinds
    turns: int
    fresh: bool  # --fresh-policy: set the saved state aside
    task: Any = None  # the session's task (``tasks.base.Task``); None: the sequence task


@dataclass(frozen=True)
class OfflineContext:
    """What a policy's ``offline`` entry point is given (``study power``): a study arm's configuration."""

    kind: str
    argument: str | None
    settings: Any
    common: Any
    turns: int
    task: Any = None  # the arm's task (``tasks.base.Task``); None: the sequence task


def split(text: str) -> tuple[str, str | None]:
    """``"usp:2:shaping"`` -> ("usp", "2:shaping"); ``"bayes"`` -> ("bayes", None)."""
    name, colon, argument = str(text).partition(":")
    return name, (argument if colon else None)


def declaration(text: str) -> PolicyKind:
    """The declaration of the policy ``text`` names (its argument, if any, unchecked)."""
    name = split(text)[0]
    declared = registry.load("policy", name)
    if not isinstance(declared, PolicyKind):
        raise ConfigError(f"policy {name!r} (from {registry.spec('policy', name).origin}): its entry point must name "
                          f"a nao_trainer.policies.plugin.PolicyKind, got {type(declared).__name__}")
    return declared


def policy_kind(text: str) -> tuple[PolicyKind, str | None]:
    """The declaration of the policy ``text`` names and its argument; ConfigError in one line otherwise."""
    declared, argument = declaration(text), split(text)[1]
    problem = declared.problem(argument)
    if problem:
        raise ConfigError(problem)
    return declared, argument


def usage() -> str:
    """The installed policy strings, in words: ``schedule | random | usp:CLUSTER[:METHOD] | ...``."""
    out = []
    for name in registry.names("policy"):
        try:
            declared = registry.load("policy", name)
        except ConfigError:
            continue
        out.append(f"{name}:{declared.argument}" if getattr(declared, "argument", None) else name)
    return " | ".join(out)


def check_kind(value: str) -> str | None:
    """``policy.kind``'s rule: an installed policy, with the argument it takes."""
    name, _ = split(value)
    if name not in registry.names("policy"):
        return f"must be one of {usage()} (nao-trainer plugins lists them)"
    try:
        policy_kind(value)
    except ConfigError as exc:
        return str(exc)
    return None


def check_state_path(value: str) -> str | None:
    if value == SESSION_FOLDER:
        return None
    try:
        names = {n for _, n, _, _ in string.Formatter().parse(value) if n is not None}
    except ValueError as exc:
        return f"has a broken placeholder ({exc})"
    unknown = names - set(STATE_PATH_FIELDS)
    if unknown:
        return (f"unknown placeholder {{{sorted(unknown)[0]}}}; use {{pseudonym}} and {{output}}, "
                "or exactly {session} for the session folder")
    return None


@settings
class PolicyCommon:
    """The keys of the ``policy`` section that are not one policy's own: which policy, and what every
    learning policy shares (a policy that does not learn ignores them)."""

    kind: str = setting(kind=str, check=check_kind, doc="the policy: schedule | random | usp:CLUSTER[:METHOD] | "
                                                         "personalised | bayes, or an installed plug-in's")
    learning: bool = setting(kind=bool, doc="learning policies keep learning during the session")
    state_path: str | None = setting(kind=str, nullable=True, check=check_state_path,
                                     doc="where a persisting policy keeps the participant's state; null = their folder")
    guidance: float = setting(kind=NUMBER, min=0, max=10, doc="preference for the supervisor's overrides")


class PolicySectionBase:
    """Methods of the composed ``policy`` section (``compose_section``)."""

    kind: str

    @property
    def plugin(self) -> PolicyKind:
        """The declaration of the policy this section names."""
        return policy_kind(self.kind)[0]

    @property
    def argument(self) -> str | None:
        return split(self.kind)[1]

    @property
    def persists(self) -> bool:
        """True when the policy keeps a state per participant across sessions."""
        return self.plugin.persists

    def own(self) -> Any:
        """The selected policy's own settings object."""
        return self.plugin.own(self)


def installed() -> list[PolicyKind]:
    """Every installed policy's declaration, by name; one that cannot be loaded is left out (``plugins`` says why)."""
    out = []
    for name in registry.names("policy"):
        try:
            declared = registry.load("policy", name)
        except ConfigError:
            continue
        if isinstance(declared, PolicyKind):
            out.append(declared)
    return out


def _copy(f: dataclasses.Field) -> Any:
    return field(default=f.default, default_factory=f.default_factory, metadata=f.metadata)  # type: ignore[arg-type]


def compose_section(kinds: list[PolicyKind] | None = None) -> type:
    """The flat ``policy`` section: ``PolicyCommon``'s keys then every policy's own keys, each declared once.

    A plug-in's key must have a default (a study that does not use it leaves it out) and must not be
    taken by another policy or by the common keys."""
    kinds = installed() if kinds is None else kinds
    owner: dict[str, str] = {f.name: "the common policy keys" for f in dataclasses.fields(PolicyCommon)}
    annotations: dict[str, Any] = {f.name: f.type for f in dataclasses.fields(PolicyCommon)}
    namespace: dict[str, Any] = {f.name: _copy(f) for f in dataclasses.fields(PolicyCommon)}
    for declared in kinds:
        if declared.settings is None:
            continue
        for f in dataclasses.fields(declared.settings):
            if f.name in owner:
                raise ConfigError(f"policy {declared.name!r} declares key 'policy.{f.name}', which "
                                  f"{owner[f.name]} declares already; rename it")
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"policy {declared.name!r}: key 'policy.{f.name}' needs a default")
            owner[f.name] = f"policy {declared.name!r}"
            annotations[f.name] = f.type
            namespace[f.name] = _copy(f)
    namespace["__annotations__"] = annotations
    namespace["__doc__"] = "The ``policy`` section: the common keys and every installed policy's own keys."
    namespace["__module__"] = __name__
    return settings(type("PolicySection", (PolicySectionBase,), namespace))


def settings_classes() -> dict[str, type]:
    """``policy.<name>`` -> that policy's settings class, plus ``policy`` -> ``PolicyCommon`` (the docs'
    config-key reference enumerates them; see also ``registry.settings_of``)."""
    out: dict[str, type] = {"policy": PolicyCommon}
    for declared in installed():
        if declared.settings is not None:
            out[f"policy.{declared.name}"] = declared.settings
    return out


def described(declared: PolicyKind) -> dict[str, Any]:
    """The declaration in words: for ``nao-trainer plugins``."""
    return {"summary": declared.summary, "persists": declared.persists,
            "argument": declared.argument, "settings": schema_of(declared.settings) if declared.settings else {}}
