"""Declared settings: a frozen dataclass whose fields carry their rule is its own schema.

A field is declared once, with its rule beside it::

    turns: int = setting(kind=int, min=1, max=500, doc="turns in a session")

``rule_of(field)`` reads the rule back, ``schema_of(cls)`` maps each key to its ``Rule`` (or, for a
nested settings dataclass, to that class's schema), ``check_value`` is the one check of one value and
``check_fields`` the one check of a built object (called from ``__post_init__``). Every problem reads
``key '<dotted key>' <what is wrong>, got <value>``; the config loader puts ``file:line:`` in front.
Pure: no I/O, and no command-line words (a caller that knows the flag adds it).
"""
from __future__ import annotations

import dataclasses
import difflib
import json
import math
from dataclasses import MISSING, dataclass
from typing import Any, Callable

from nao_trainer.errors import ConfigError

#: No setting needs an integer this large; beyond it a number is a typo (and may not fit a float).
MAX_INT = 10**12


@dataclass(frozen=True)
class Rule:
    """What one key accepts: its type, range or choices, an extra check, and what it is for."""

    kind: type | tuple[type, ...]
    nullable: bool = False
    min: float | None = None
    max: float | None = None
    above: float | None = None  # exclusive minimum (``> above``)
    choices: tuple[Any, ...] | None = None
    item: type | tuple[type, ...] | None = None  # element type of a list
    length: int | None = None  # exact list length
    check: Callable[[Any], str | None] | None = None  # extra rule: returns a problem or None
    free: bool = False  # a free-form mapping (keys not checked)
    doc: str = ""


def rule_text(rule: Rule) -> str:
    """A rule in words: ``a number, >= 0.05, <= 1`` (``nao-trainer plugins``, the docs' key reference)."""
    plural = {int: "integers", float: "numbers", str: "texts", bool: "true/false values"}
    items = rule.item if isinstance(rule.item, tuple) else (rule.item,)
    of = " or ".join(plural.get(k, k.__name__) for k in items if k is not None and not (k is int and float in items))
    parts = [type_name(rule.kind) + (f" of {of}" if rule.item is not None else "")]
    if rule.length is not None:
        parts.append(f"exactly {rule.length} items")
    if rule.choices:
        parts.append("one of " + ", ".join(str(c) for c in rule.choices))
    if rule.min is not None:
        parts.append(f">= {rule.min:g}")
    if rule.above is not None:
        parts.append(f"> {rule.above:g}")
    if rule.max is not None:
        parts.append(f"<= {rule.max:g}")
    if rule.nullable:
        parts.append("or null")
    if rule.check is not None:
        parts.append(f"checked by {rule.check.__name__}")
    return ", ".join(parts)


def declared(cls: type, prefix: str = "") -> list[tuple[str, Any, Rule]]:
    """(dotted key, default, rule) of every key a settings class declares, nested ones flattened; the
    default is ``MISSING`` for a required key."""
    out: list[tuple[str, Any, Rule]] = []
    for f in dataclasses.fields(cls):
        dotted = f"{prefix}{f.name}"
        rule, nested = rule_of(f), nested_class(f)
        if rule is None and is_settings(nested):
            out += declared(nested, dotted + ".")
        elif rule is not None:
            default = f.default if f.default is not MISSING else (
                f.default_factory() if f.default_factory is not MISSING else MISSING)
            out.append((dotted, default, rule))
    return out


class SettingError(ConfigError, ValueError):
    """A value broke its rule: ``key`` (relative to the object checked) and ``problem`` (the words after the key).

    A ``ValueError`` too: library callers that build settings from numbers (sweeps, training specs) catch that."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"key '{key}' {problem}")
        self.key = key
        self.problem = problem


class UnknownKey(SettingError):
    """A key the settings do not declare: the message suggests the nearest known key."""

    def __init__(self, prefix: str, key: str, known: list[str]) -> None:
        dotted = f"{prefix}.{key}" if prefix else key
        hint = difflib.get_close_matches(key, known, n=1)
        fix = f"did you mean '{(prefix + '.') if prefix else ''}{hint[0]}'?" if hint else f"valid keys here: {', '.join(known)}"
        super().__init__(dotted, "is unknown")
        shown = json.dumps(dotted, ensure_ascii=False)[1:-1]  # a newline or control character echoed escaped
        self.args = (f"unknown key '{shown}'; {fix}",)
        self.prefix, self.name, self.known = prefix, key, known


def setting(default: Any = MISSING, *, factory: Callable[[], Any] | None = None, **rule: Any) -> Any:
    """A dataclass field declared with its ``Rule`` (keyword arguments of ``Rule``)."""
    metadata = {"rule": Rule(**rule)}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def settings(cls: type) -> type:
    """``@settings``: a frozen dataclass whose fields are checked against their rules whenever one is built;
    the class's own ``__post_init__`` (relations between fields) runs after."""
    own = cls.__dict__.get("__post_init__")

    def __post_init__(self: Any) -> None:
        check_fields(self)
        if own is not None:
            own(self)

    cls.__post_init__ = __post_init__  # type: ignore[attr-defined]
    return dataclass(frozen=True)(cls)


def optional_keys(sections: dict[str, type], prefix: str = "") -> list[str]:
    """Dotted keys whose field has a default (a study may leave them out)."""
    out: list[str] = []
    for name, cls in sections.items():
        for f in dataclasses.fields(cls):
            dotted = f"{prefix}{name}.{f.name}"
            if rule_of(f) is None and is_settings(nested_class(f)):
                out += optional_keys({f.name: nested_class(f)}, f"{prefix}{name}.")
            elif has_default(f):
                out.append(dotted)
    return out


def rule_of(field: dataclasses.Field) -> Rule | None:
    return field.metadata.get("rule")


def is_settings(cls: Any) -> bool:
    """A settings dataclass: every field has a rule or is itself a settings dataclass."""
    return isinstance(cls, type) and dataclasses.is_dataclass(cls) and any(
        rule_of(f) is not None for f in dataclasses.fields(cls))


def schema_of(cls: type) -> dict[str, Any]:
    """key -> ``Rule``, or key -> the nested schema of a settings dataclass field (in declaration order)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        rule = rule_of(f)
        if rule is not None:
            out[f.name] = rule
        elif is_settings(nested_class(f)):
            out[f.name] = schema_of(nested_class(f))
    return out


def nested_class(field: dataclasses.Field) -> Any:
    """The settings class of a nested field (declared with ``default_factory=ThatClass``), else None."""
    factory = field.default_factory
    return factory if isinstance(factory, type) else None


def has_default(field: dataclasses.Field) -> bool:
    return field.default is not MISSING or field.default_factory is not MISSING


def type_name(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    names = {int: "an integer", float: "a number", str: "a text", bool: "true/false", list: "a list", dict: "a mapping"}
    return " or ".join(names.get(k, k.__name__) for k in kinds if not (k is int and float in kinds))


def _is_kind(value: Any, kind: type | tuple[type, ...]) -> bool:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool) and bool not in kinds:
        return False
    return isinstance(value, kinds)


def _number_problem(value: Any) -> str | None:
    """NaN and infinity pass every range check (all comparisons are False), huge integers overflow floats."""
    if isinstance(value, float) and not math.isfinite(value):
        return f"must be a finite number, got {value!r}"
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_INT:
        return f"must be a number of sensible size, got one with {len(str(abs(value)))} digits"
    return None


def _text_problem(value: str) -> str | None:
    """Control characters (NUL...) and lone surrogates cannot be file names or spoken text."""
    bad = next((c for c in value if ord(c) < 0x20 or ord(c) == 0x7F or 0xD800 <= ord(c) <= 0xDFFF), None)
    if bad is not None:
        return f"must not contain control characters or invalid Unicode (found U+{ord(bad):04X})"
    return None


def short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_value(value: Any, spec: Rule) -> str | None:
    """The problem with ``value`` for ``spec`` (one line, without key or place), or None."""
    if value is None:
        return None if spec.nullable else f"needs a value ({type_name(spec.kind)}), got nothing"
    if not _is_kind(value, spec.kind):
        return f"must be {type_name(spec.kind)}, got {short(value)}"
    problem = _number_problem(value) or (_text_problem(value) if isinstance(value, str) else None)
    if problem:
        return problem
    if spec.choices is not None and value not in spec.choices:
        return f"must be one of {', '.join(map(str, spec.choices))}, got {value!r}"
    if spec.min is not None and value < spec.min:
        return f"must be >= {spec.min:g}, got {value!r}"
    if spec.above is not None and value <= spec.above:
        return f"must be > {spec.above:g}, got {value!r}"
    if spec.max is not None and value > spec.max:
        return f"must be <= {spec.max:g}, got {value!r}"
    if isinstance(value, list):
        problem = _list_problem(value, spec)
        if problem:
            return problem
    if spec.check is not None:
        problem = spec.check(value)
        if problem:
            return f"{problem} (got {short(value)})" if "got" not in problem else problem
    return None


def _list_problem(value: list, spec: Rule) -> str | None:
    if spec.length is not None and len(value) != spec.length:
        return f"must have {spec.length} values, got {len(value)}"
    for item in value:
        if spec.item is not None and not _is_kind(item, spec.item):
            return f"values must each be {type_name(spec.item)}, got {short(item)}"
        problem = _number_problem(item) or (_text_problem(item) if isinstance(item, str) else None)
        if problem:
            return f"values: {problem}"
    return None


def typed(value: Any, spec: Rule) -> Any:
    """A checked value in the type its field holds: an integer where a number goes becomes a float, a list a tuple."""
    if isinstance(value, int) and not isinstance(value, bool) and isinstance(spec.kind, tuple) and float in spec.kind:
        return float(value)
    return tuple(value) if isinstance(value, list) else value


def check_fields(obj: Any) -> None:
    """Check every declared field of a built settings object; ``SettingError`` for the first problem."""
    for f in dataclasses.fields(obj):
        rule = rule_of(f)
        if rule is None:
            continue
        value = getattr(obj, f.name)
        problem = check_value(list(value) if isinstance(value, tuple) else value, rule)
        if problem:
            raise SettingError(f.name, problem)


def build(cls: type, data: Any, prefix: str = "") -> Any:
    """A settings object from a mapping of (some of) its keys; the others keep their defaults.

    Every problem is a ``SettingError`` whose ``key`` is dotted from ``prefix`` (``eeg.processing.hop_s``).
    """
    dotted = (lambda key: f"{prefix}.{key}" if prefix else key)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SettingError(prefix or "(top level)", f"must be a mapping of keys, got {short(data)}")
    known = {f.name: f for f in dataclasses.fields(cls)}
    values: dict[str, Any] = {}
    for key, value in data.items():
        f = known.get(key)
        if f is None:
            raise UnknownKey(prefix, str(key), list(known))
        rule, nested = rule_of(f), nested_class(f)
        if rule is None and is_settings(nested):
            values[key] = build(nested, value, dotted(key))
            continue
        if rule is not None:
            problem = check_value(value, rule)
            if problem:
                raise SettingError(dotted(key), problem)
            value = typed(value, rule)
        values[key] = value
    for key, f in known.items():
        if key not in values and not has_default(f):
            raise SettingError(dotted(key), "is missing; add it")
    try:
        return cls(**values)
    except SettingError as exc:  # a relation between fields (__post_init__)
        raise SettingError(dotted(exc.key), exc.problem) from None

