"""One registry per kind that varies: task, policy, EEG device, robot model.

A plug-in is registered once by name with a lazy entry point, ``"module:attribute"`` (Gymnasium's
``register(id, entry_point=...)`` is the model): nothing is imported until the kind is asked for, so
``--help`` stays fast and a plug-in whose extra dependencies are missing fails only when used, in one
line. A separate package adds its own through Python entry points, one group per kind
(``nao_trainer.tasks``, ``nao_trainer.policies``, ``nao_trainer.eeg_devices``,
``nao_trainer.robot_models``), read once, when a kind's names are first needed.

The project's own plug-ins are the table ``BUILTIN`` at the end of this module: the one place a
built-in kind string is written beside its home (and ``DEFAULTS``: the one a config gets when it names
none). No kind string is compared outside its registry:
callers ask ``spec(kind, name)`` / ``load(kind, name)`` and use what the plug-in declares.
"""
from __future__ import annotations

import dataclasses
import difflib
import importlib
from dataclasses import dataclass
from typing import Any

from nao_trainer.errors import ConfigError

#: The kinds that vary, each with its entry-point group.
GROUPS: dict[str, str] = {
    "task": "nao_trainer.tasks",
    "policy": "nao_trainer.policies",
    "eeg_device": "nao_trainer.eeg_devices",
    "robot_model": "nao_trainer.robot_models",
}
#: How a kind is named in messages.
WORDS: dict[str, str] = {"task": "task", "policy": "policy", "eeg_device": "EEG device", "robot_model": "robot model"}


@dataclass(frozen=True)
class Spec:
    """One registered plug-in: its kind, name, entry point (``module:attribute``) and where it came from."""

    kind: str
    name: str
    entry_point: str
    origin: str = "nao_trainer"  # the distribution that registered it

    def load(self) -> Any:
        """Import the entry point's module and return its attribute; a failure is one ``ConfigError`` line."""
        return resolve(self.entry_point, f"{WORDS[self.kind]} {self.name!r} (from {self.origin})")


def resolve(entry_point: str, what: str) -> Any:
    """The object ``"module:attribute"`` names, imported now (a plug-in's own lazy entry points, such as a
    policy's ``live`` and ``offline`` forms); a failure is one ``ConfigError`` line naming ``what``."""
    module, _, attribute = entry_point.partition(":")
    try:
        target: Any = importlib.import_module(module)
        for part in attribute.split(".") if attribute else ():
            target = getattr(target, part)
    except ImportError as exc:
        raise ConfigError(f"{what} cannot be loaded: {exc}; install what it needs or choose another") from None
    except AttributeError as exc:
        raise ConfigError(f"{what}: entry point {entry_point!r} is broken ({exc})") from None
    return target


_REGISTRY: dict[str, dict[str, Spec]] = {kind: {} for kind in GROUPS}
_ENTRY_POINTS_READ: set[str] = set()


def _check_kind(kind: str) -> None:
    if kind not in GROUPS:
        raise ValueError(f"registry kind must be one of {', '.join(GROUPS)}, got {kind!r}")


def register(kind: str, name: str, entry_point: str, *, origin: str = "nao_trainer", override: bool = False) -> Spec:
    """Register ``name`` of ``kind`` at ``entry_point`` (``"package.module:Attribute"``).

    A name is registered once: a second registration of a taken name raises unless ``override``
    (a test or a lab replacing a built-in on purpose)."""
    _check_kind(kind)
    if not name or not name.replace("_", "").replace("-", "").isalnum() or not name[0].isalpha():
        raise ValueError(f"{WORDS[kind]} name must be a letter then letters, digits, '-' or '_', got {name!r}")
    module, colon, _ = entry_point.partition(":")
    if not module or not colon:
        raise ValueError(f"entry point must read 'module:attribute', got {entry_point!r}")
    taken = _REGISTRY[kind].get(name)
    if taken is not None and not override and taken.entry_point != entry_point:
        raise ValueError(f"{WORDS[kind]} {name!r} is registered already (by {taken.origin}: {taken.entry_point})")
    spec_ = Spec(kind, name, entry_point, origin)
    _REGISTRY[kind][name] = spec_
    return spec_


def unregister(kind: str, name: str) -> None:
    """Forget ``name`` of ``kind`` (tests that register a plug-in of their own)."""
    _check_kind(kind)
    _REGISTRY[kind].pop(name, None)


def _read_entry_points(kind: str) -> None:
    """Register what installed distributions declare in the entry-point groups, once per process: every group
    not read yet in one pass (each pass reads every installed distribution's metadata: about 100 files here,
    10-30 ms a pass, paid by every command)."""
    if kind in _ENTRY_POINTS_READ:
        return
    from importlib import metadata  # its import (email, zipfile, ...) only where a group is read

    todo = {GROUPS[k]: k for k in GROUPS if k not in _ENTRY_POINTS_READ}
    _ENTRY_POINTS_READ.update(todo.values())
    seen: set[str] = set()
    for dist in metadata.distributions():  # as entry_points() reads them: the first of a name on the path
        key = getattr(dist, "_normalized_name", None) or dist.metadata["Name"]  # the folder's name: no METADATA parse
        if key in seen:
            continue
        seen.add(key)
        for point in dist.entry_points:
            kind_of = todo.get(point.group)
            if kind_of is not None:
                _register_installed(kind_of, point, getattr(dist, "name", None) or "an installed package")


def _register_installed(kind_of: str, point: Any, origin: str) -> None:
    if point.name in _REGISTRY[kind_of] and _REGISTRY[kind_of][point.name].origin != origin:
        return  # a built-in keeps its name; `plugins` shows the clash
    try:
        register(kind_of, point.name, point.value, origin=origin)
    except ValueError:
        return  # a malformed declaration of another package: `plugins` lists only what works


def reload_entry_points() -> None:
    """Read the entry-point groups again (after installing a plug-in package in a running process)."""
    _ENTRY_POINTS_READ.clear()


def names(kind: str) -> tuple[str, ...]:
    """The registered names of ``kind``, sorted (built-ins and installed plug-ins)."""
    _check_kind(kind)
    _read_entry_points(kind)
    return tuple(sorted(_REGISTRY[kind]))


def specs(kind: str) -> tuple[Spec, ...]:
    """Every registered ``Spec`` of ``kind``, by name."""
    return tuple(_REGISTRY[kind][name] for name in names(kind))


def spec(kind: str, name: str) -> Spec:
    """The ``Spec`` of ``name``; an unknown name is one ``ConfigError`` line naming the installed ones. A name
    registered already is answered without reading the entry points (a built-in keeps its name over theirs)."""
    _check_kind(kind)
    found = _REGISTRY[kind].get(name)
    if found is None:
        known = names(kind)
        found = _REGISTRY[kind].get(name)
    if found is None:
        near = difflib.get_close_matches(str(name), known, n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise ConfigError(f"unknown {WORDS[kind]} {name!r}{hint}; installed: {', '.join(known) or 'none'} "
                          "(nao-trainer plugins lists them)")
    return found


def load(kind: str, name: str) -> Any:
    """The object ``name``'s entry point names (a class, usually), imported now."""
    return spec(kind, name).load()


def make(kind: str, name: str, *args: Any, **kwargs: Any) -> Any:
    """``load(kind, name)(*args, **kwargs)``: a plug-in built (Gymnasium's ``make``)."""
    return load(kind, name)(*args, **kwargs)


def settings_of(target: Any) -> type | None:
    """The settings dataclass a loaded plug-in declares: ``Settings`` (a class: EEG devices, tasks, robot
    models) or ``settings`` (a declaration object: ``policies.plugin.PolicyKind``), else None."""
    for attr in ("Settings", "settings"):
        cls = getattr(target, attr, None)
        if isinstance(cls, type) and dataclasses.is_dataclass(cls):
            return cls
    return None


@dataclass(frozen=True)
class Installed:
    """One registered plug-in as ``nao-trainer plugins`` and the docs' key reference see it."""

    spec: Spec
    target: Any = None  # the loaded entry point (None when it cannot be loaded)
    settings: type | None = None  # its settings dataclass, if it declares one
    error: str = ""  # why it cannot be loaded

    @property
    def summary(self) -> str:
        """Its one-line description: a declared ``summary``, else the first line of its docstring."""
        text = getattr(self.target, "summary", None) or (getattr(self.target, "__doc__", None) or "")
        return str(text).strip().splitlines()[0] if str(text).strip() else ""


def installed(kind: str) -> tuple[Installed, ...]:
    """Every registered plug-in of ``kind`` (built-in and from entry points), each loaded now, by name."""
    out = []
    for found in specs(kind):
        try:
            target = found.load()
        except ConfigError as exc:
            out.append(Installed(found, error=str(exc)))
            continue
        out.append(Installed(found, target, settings_of(target)))
    return tuple(out)


#: The project's own plug-ins: (kind, name, entry point). Each home owns its settings and behaviour.
BUILTIN: tuple[tuple[str, str, str], ...] = (
    ("task", "sequence", "nao_trainer.tasks.sequence:SequenceTask"),
    ("task", "nback", "nao_trainer.tasks.nback:NBackTask"),
    ("policy", "schedule", "nao_trainer.policies.kinds:SCHEDULE"),
    ("policy", "random", "nao_trainer.policies.kinds:RANDOM"),
    ("policy", "usp", "nao_trainer.policies.kinds:USP"),
    ("policy", "personalised", "nao_trainer.policies.kinds:PERSONALISED"),
    ("policy", "bayes", "nao_trainer.policies.kinds:BAYES"),
    ("eeg_device", "muse", "nao_trainer.eeg.devices.muse:MuseDevice"),
    ("robot_model", "nao", "nao_trainer.robot.models.nao:NaoModel"),
    ("robot_model", "pepper", "nao_trainer.robot.models.pepper:PepperModel"),
    ("eeg_device", "brainflow", "nao_trainer.eeg.devices.brainflow:BrainFlowDevice"),
)


#: The built-in a study config gets when it names none, per kind that has such a setting: the one place a
#: default kind is written (``task.name``, ``eeg.device`` and ``robot.model`` declare theirs as ``default(kind)``).
DEFAULTS: dict[str, str] = {"task": "sequence", "eeg_device": "muse", "robot_model": "nao"}


def default(kind: str) -> str:
    """The name of ``kind`` a config that names none gets (``DEFAULTS``); a kind without one is a ``ValueError``."""
    _check_kind(kind)
    if kind not in DEFAULTS:
        raise ValueError(f"{WORDS[kind]} has no default: a config names it")
    return DEFAULTS[kind]


def _register_builtins() -> None:
    for kind, name, entry_point in BUILTIN:
        register(kind, name, entry_point)


_register_builtins()
