"""The generated reference pages: every command and flag, every config key. Built from the code, so they cannot drift.

``commands_markdown()`` walks ``nao_trainer.cli.build_parser()`` (every subcommand, nested ones too, and
every argument with its default, choices and help); ``config_markdown()`` walks the study sections
(``session.config.SECTIONS``, each a ``core.settings`` declaration) and the settings classes the
registered plug-ins declare, with each key's default (``config/default.yaml`` or the field's own) and
rule. The MkDocs hook (``tools/mkdocs_hooks.py``) writes them into the site at build time as
``reference/commands.md`` and ``reference/config.md``; ``python tools/docs_reference.py OUT_DIR`` writes
them to files (to read them without building the site).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any, Iterator

ROOT = Path(__file__).resolve().parent.parent


# ---------------------------------------------------------------------------------------------- commands


def _subcommands(parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser, str]]:
    """(name, parser, one-line help) of each direct subcommand, in the order ``--help`` lists them."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            seen: set[int] = set()
            for name, sub in action.choices.items():
                if id(sub) in seen:  # an alias
                    continue
                seen.add(id(sub))
                yield name, sub, helps.get(name, "")


def _actions_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser | None:
    """A command that parses its own actions (``study``: ``cli.study.actions_parser()``) names that parser there."""
    func = parser.get_default("func")
    make = getattr(sys.modules.get(getattr(func, "__module__", "")), "actions_parser", None)
    return make() if callable(make) else None


def walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
         ) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser, str]]:
    """Every (command path, parser, help) below ``parser``, depth first (actions parsed by a command too)."""
    for name, sub, helps in _subcommands(parser):
        yield path + (name,), sub, helps
        yield from walk(sub, path + (name,))
        inner = _actions_parser(sub)
        if inner is not None:
            yield from walk(inner, path + (name,))


def _md(text: str) -> str:
    text = " ".join(str(text).split()).replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")
    return text.replace("[", "\\[").replace("]", "\\]")


def _argument_row(action: argparse.Action) -> str | None:
    if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) or action.help == argparse.SUPPRESS:
        return None
    if action.option_strings:
        metavar = action.metavar or (action.dest.upper() if action.nargs != 0 else "")
        if isinstance(metavar, tuple):
            metavar = " ".join(metavar)
        name = ", ".join(f"`{o}{(' ' + str(metavar)) if action.nargs != 0 and metavar else ''}`"
                         for o in action.option_strings)
    else:
        name = f"`{action.metavar or action.dest}`"
    default = action.default
    shown = "" if default in (None, argparse.SUPPRESS, False) or action.nargs == 0 and default is False else f"`{default}`"
    if isinstance(action, argparse._StoreTrueAction):
        shown = ""
    choices = f" One of: {', '.join(f'`{c}`' for c in action.choices)}." if action.choices and not isinstance(
        action.choices, dict) else ""
    helps = (action.help or "") % {"default": default, "prog": "", "choices": ""} if action.help and "%(" in action.help \
        else (action.help or "")
    required = " (required)" if action.required and action.option_strings else ""
    return f"| {name}{required} | {_md(helps)}{_md(choices)} | {_md(shown)} |"


def commands_markdown() -> str:
    from nao_trainer.cli import build_parser

    top = build_parser()
    lines = ["# Commands and flags", "",
             "Generated from the command line's own parsers (`nao_trainer.cli.build_parser()`) when the site is built:",
             "every command, every flag, its default. `nao-trainer COMMAND --help` prints the same.", ""]
    commands = list(walk(top))
    lines += ["| command | what it does |", "| --- | --- |"]
    for path, _, helps in commands:
        anchor = "-".join(path)
        lines.append(f"| [`nao-trainer {' '.join(path)}`](#{anchor}) | {_md(helps)} |")
    lines.append("")
    for path, parser, helps in commands:
        anchor = "-".join(path)
        lines += [f"## `nao-trainer {' '.join(path)}` {{#{anchor}}}", ""]
        if parser.description and issubclass(parser.formatter_class, argparse.RawDescriptionHelpFormatter):
            lines += ["```text", parser.description.strip(), "```", ""]
        elif parser.description or helps:
            lines += [_md(parser.description or helps), ""]
        usage = parser.format_usage().strip().removeprefix("usage: ")
        lines += ["```text", usage, "```", ""]
        rows = [r for r in (_argument_row(a) for a in parser._actions) if r]
        if rows:
            lines += ["| argument | meaning | default |", "| --- | --- | --- |", *rows, ""]
        subs = list(_subcommands(parser))
        if subs:
            lines += ["Subcommands: " + ", ".join(f"[`{n}`](#{anchor}-{n})" for n, _, _ in subs) + ".", ""]
        if parser.epilog:
            lines += ["```text", parser.epilog.strip(), "```", ""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------- config


def _rule_text(rule: Any) -> str:
    from nao_trainer.core.settings import type_name

    parts = [type_name(rule.kind)]
    if rule.item is not None:
        parts.append(f"of {type_name(rule.item)}")
    if rule.length is not None:
        parts.append(f"exactly {rule.length} items")
    if rule.choices:
        parts.append("one of " + ", ".join(f"`{c}`" for c in rule.choices))
    if rule.min is not None:
        parts.append(f">= {rule.min:g}")
    if rule.above is not None:
        parts.append(f"> {rule.above:g}")
    if rule.max is not None:
        parts.append(f"<= {rule.max:g}")
    if rule.nullable:
        parts.append("or null")
    if rule.check is not None:
        doc = (rule.check.__doc__ or "").strip().splitlines()
        parts.append(f"checked by `{rule.check.__name__}`" + (f" ({doc[0].rstrip('.')})" if doc else ""))
    return ", ".join(parts)


def _defaults() -> dict[str, Any]:
    import yaml

    return yaml.safe_load((ROOT / "config" / "default.yaml").read_text(encoding="utf-8")) or {}


def _lookup(tree: Any, dotted: str) -> tuple[bool, Any]:
    for part in dotted.split("."):
        if not isinstance(tree, dict) or part not in tree:
            return False, None
        tree = tree[part]
    return True, tree


def _show(value: Any) -> str:
    return f"`{json.dumps(value, ensure_ascii=False)}`"


def settings_rows(cls: type, prefix: str, defaults: dict[str, Any]) -> Iterator[str]:
    """One table row per key of the settings class ``cls`` (nested classes flattened to dotted keys)."""
    from nao_trainer.core import settings as s

    for f in dataclasses.fields(cls):
        dotted = f"{prefix}.{f.name}" if prefix else f.name
        rule = s.rule_of(f)
        if rule is None:
            nested = s.nested_class(f)
            if s.is_settings(nested):
                yield from settings_rows(nested, dotted, defaults)
            continue
        found, value = _lookup(defaults, dotted)
        if not found and f.default is not dataclasses.MISSING:
            found, value = True, f.default
        elif not found and f.default_factory is not dataclasses.MISSING:
            found, value = True, f.default_factory()
        default = _show(list(value) if isinstance(value, tuple) else value) if found else "(required)"
        yield f"| `{dotted}` | {default} | {_md(_rule_text(rule))} | {_md(rule.doc)} |"


def plugin_settings() -> list[tuple[str, str, type]]:
    """(kind, name, settings class) of every registered plug-in that declares one (``settings`` attribute)."""
    from nao_trainer import registry
    from nao_trainer.core.settings import is_settings
    from nao_trainer.errors import ConfigError

    out = []
    for kind in registry.GROUPS:
        for spec in registry.specs(kind):
            try:
                target = spec.load()
            except ConfigError:
                continue
            for attr in ("settings", "Settings", "settings_class", "SETTINGS"):
                cls = getattr(target, attr, None)
                if is_settings(cls):
                    out.append((kind, spec.name, cls))
                    break
    return out


def config_markdown() -> str:
    from nao_trainer.session.config import SECTIONS

    defaults = _defaults()
    lines = ["# Configuration keys", "",
             "Generated from the settings declarations (`core.settings`: each field carries its rule) when the site",
             "is built. A study file (`config/studies/*.yaml`) overlays `config/default.yaml`; the default shown is",
             "that file's value (or the field's own where the file leaves it out). Relative paths resolve against",
             "the folder of the file that sets them.", ""]
    for section, cls in SECTIONS.items():
        lines += [f"## `{section}`", ""]
        doc = (cls.__doc__ or "").strip()
        if doc and not doc.startswith(cls.__name__ + "("):
            lines += [_md(doc.split("\n\n")[0]), ""]
        lines += ["| key | default | rule | meaning |", "| --- | --- | --- | --- |",
                  *settings_rows(cls, section, defaults), ""]
    plugins = plugin_settings()
    if plugins:
        lines += ["## Plug-in settings", "",
                  "Each plug-in registered in `nao_trainer/registry.py` owns its settings class.", ""]
        for kind, name, cls in plugins:
            lines += [f"### {kind} `{name}`", "", "| key | default | rule | meaning |", "| --- | --- | --- | --- |",
                      *settings_rows(cls, "", {}), ""]
    return "\n".join(lines)


PAGES = {"reference/commands.md": commands_markdown, "reference/config.md": config_markdown}


def main(argv: list[str]) -> int:
    out = Path(argv[0]) if argv else ROOT / "site-reference"
    for name, make in PAGES.items():
        target = out / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(make() + "\n", encoding="utf-8")
        print(target)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    sys.exit(main(sys.argv[1:]))
