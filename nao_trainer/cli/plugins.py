"""`nao-trainer plugins`: every installed task, policy, EEG device and robot model, with origin and settings."""
from __future__ import annotations

import argparse
import json
from dataclasses import MISSING
from typing import Any

from nao_trainer import registry
from nao_trainer.core.settings import declared, rule_text
from nao_trainer.policies.plugin import PolicyCommon

#: Where a kind's settings live in a study configuration (the dotted prefix of its keys).
PREFIX = {"policy": "policy.", "eeg_device": "eeg.device_settings.", "robot_model": "robot.model_settings.",
          "task": "task.settings."}
TITLES = {"task": "tasks", "policy": "policies", "eeg_device": "EEG devices", "robot_model": "robot models"}


def register(sub) -> None:
    p = sub.add_parser(
        "plugins",
        help="list the installed tasks, policies, EEG devices and robot models, with their settings",
        description="List every plug-in the registry knows (nao_trainer/registry.py): the built-in ones and those "
                    "installed packages add through the entry-point groups nao_trainer.tasks, .policies, "
                    ".eeg_devices and .robot_models. For each: its name, where it comes from (the distribution), "
                    "its entry point, what it is, and each setting it declares (key, default, rule). A plug-in "
                    "that cannot be loaded is listed with the reason (exit code 1).",
    )
    p.add_argument("--kind", choices=tuple(registry.GROUPS), help="only this kind")
    p.add_argument("--json", action="store_true", help="print JSON (one object per plug-in)")
    p.set_defaults(func=run)


def _value(value: Any) -> Any:
    if value is MISSING:
        return "(required)"
    return list(value) if isinstance(value, tuple) else value


def describe(kind: str) -> list[dict[str, Any]]:
    """The plug-ins of ``kind`` as plain data (what ``--json`` prints)."""
    out = []
    for item in registry.installed(kind):
        keys = [] if item.settings is None else _keys(item.settings, PREFIX.get(kind, ""))
        entry = {"kind": kind, "name": item.spec.name, "origin": item.spec.origin,
                 "entry_point": item.spec.entry_point, "summary": item.summary, "settings": keys}
        if item.error:
            entry["error"] = item.error
        out.append(entry)
    return out


def _keys(settings: type, prefix: str) -> list[dict[str, Any]]:
    return [{"key": prefix + key, "default": _value(default), "rule": rule_text(rule), "doc": rule.doc}
            for key, default, rule in declared(settings)]


def _text(kind: str, entries: list[dict[str, Any]]) -> list[str]:
    lines = [f"{TITLES[kind]} ({len(entries)}):"]
    if kind == "policy":  # the keys that are no single policy's own
        lines.append("  (every policy) " + ", ".join(k["key"] for k in _keys(PolicyCommon, "policy.")))
    if not entries:
        lines.append("  none installed")
    for e in entries:
        lines.append(f"  {e['name']:<14} from {e['origin']:<12} {e['entry_point']}")
        if e.get("error"):
            lines.append(f"    CANNOT BE LOADED: {e['error']}")
            continue
        if e["summary"]:
            lines.append(f"    {e['summary']}")
        for k in e["settings"]:
            lines.append(f"    {k['key']} = {json.dumps(k['default'])}  ({k['rule']})" + (f": {k['doc']}" if k["doc"] else ""))
    return lines


def run(args: argparse.Namespace) -> int:
    kinds = (args.kind,) if args.kind else tuple(registry.GROUPS)
    found = {kind: describe(kind) for kind in kinds}
    if args.json:
        print(json.dumps([e for entries in found.values() for e in entries], indent=1, default=str))
    else:
        print("\n".join(line for kind in kinds for line in _text(kind, found[kind])))
    return 1 if any(e.get("error") for entries in found.values() for e in entries) else 0
