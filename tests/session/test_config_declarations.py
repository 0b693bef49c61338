"""config/default.yaml and the docs against the settings declarations: every declared key of every section and
of every built-in policy is in default.yaml with its declared default, default.yaml has no undeclared key, and
every ``policy.<key>`` the docs name is declared."""
from __future__ import annotations

import re
from dataclasses import MISSING

from nao_trainer import registry
from nao_trainer.core.settings import declared
from nao_trainer.files import PROJECT_ROOT, read_yaml
from nao_trainer.session.config import DEFAULT_CONFIG, SECTIONS

#: Nested sections default.yaml leaves to their own declaration and page ({} = every default).
NESTED_DEFAULTS = ("eeg.processing",)


def _default_file() -> dict:
    return read_yaml(DEFAULT_CONFIG, fix="")[0]


def _lookup(data: dict, dotted: str) -> tuple[bool, object]:
    node: object = data
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return False, None
        node = node[part]
    return True, node


def _plain(value: object) -> object:
    return list(value) if isinstance(value, tuple) else value


def test_every_declared_key_is_in_default_yaml_with_its_declared_default():
    data = _default_file()
    for section, cls in SECTIONS.items():
        for key, default, _rule in declared(cls, f"{section}."):
            if key.startswith(NESTED_DEFAULTS):
                continue
            present, value = _lookup(data, key)
            assert present, f"{key} is declared but not in config/default.yaml"
            if default is not MISSING:
                assert _plain(value) == _plain(default), f"{key}: default.yaml has {value!r}, declared {default!r}"


def test_every_builtin_policy_key_is_in_the_policy_section_of_default_yaml():
    policy = _default_file()["policy"]
    for item in registry.installed("policy"):
        if item.spec.origin != "nao_trainer" or item.settings is None:
            continue
        for key, default, _rule in declared(item.settings):
            assert key in policy, f"policy {item.spec.name}'s key policy.{key} is not in config/default.yaml"
            assert _plain(policy[key]) == _plain(default)


def test_default_yaml_declares_no_key_the_sections_do_not():
    data = _default_file()
    keys = {key for section, cls in SECTIONS.items() for key, _, _ in declared(cls, f"{section}.")}
    nested = {key.rsplit(".", 1)[0] for key in keys if key.startswith(NESTED_DEFAULTS)}

    def walk(node: dict, prefix: str) -> None:
        for key, value in node.items():
            dotted = f"{prefix}{key}"
            if isinstance(value, dict) and value and dotted not in keys:
                walk(value, dotted + ".")
            else:
                assert dotted in keys or dotted in nested, f"config/default.yaml has {dotted}, which nothing declares"

    walk(data, "")


def test_the_docs_name_only_declared_policy_keys():
    keys = {key for key, _, _ in declared(SECTIONS["policy"], "policy.")}
    named = {(page.relative_to(PROJECT_ROOT), m.group(1)) for page in (PROJECT_ROOT / "docs").rglob("*.md")
             for m in re.finditer(r"`(policy\.[a-z_]+)", page.read_text(encoding="utf-8"))}
    assert named, "the docs name no policy key at all"
    stale = sorted(f"{page}: {key}" for page, key in named if key not in keys)
    assert not stale, f"the docs name undeclared policy keys: {stale}"
