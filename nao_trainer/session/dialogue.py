"""What the robot says: dialogue files with several variants per event, validated at load.

A variant is picked with the session's seeded generator, so a session replays identically for
the same seed. Placeholders (``{level}``, ``{total}``) are checked against the event's allowed set
when the file is loaded, so a typo is found before a participant sits in front of the robot.
"""
from __future__ import annotations

import string
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.errors import ConfigError
from nao_trainer.files import read_yaml

#: Every event the session speaks, with the placeholders its variants may use.
EVENTS: dict[str, frozenset[str]] = {
    "greeting": frozenset({"pseudonym"}),
    "instructions": frozenset({"turns"}),
    "practice_intro": frozenset(),
    "practice_success": frozenset(),
    "practice_failure": frozenset(),
    "level": frozenset({"level", "length"}),
    "encouraging_success": frozenset({"level"}),
    "encouraging_failure": frozenset({"level"}),
    "challenging_success": frozenset({"level"}),
    "challenging_failure": frozenset({"level"}),
    "paused": frozenset(),
    "resumed": frozenset(),
    "goodbye": frozenset({"total", "turns"}),
    # The goodbye when the total is zero or negative: "you scored -2 points" is not said to a participant.
    "goodbye_no_points": frozenset({"turns"}),
}

#: Values of the kind the session passes, used to trial-format every variant at load.
SAMPLE_FIELDS: dict[str, Any] = {"pseudonym": "P01", "turns": 25, "level": 3, "length": 7, "total": 17}


@dataclass(frozen=True)
class Dialogue:
    """Variants per event of one language."""

    language: str
    variants: dict[str, tuple[str, ...]]
    source: str = ""

    def say(self, event: str, rng: np.random.Generator, **fields: Any) -> str:
        """One variant of ``event`` (drawn with ``rng``) with its placeholders filled."""
        options = self.variants[event]
        text = options[int(rng.integers(len(options)))] if len(options) > 1 else options[0]
        return text.format(**fields)

    @staticmethod
    def goodbye_event(total: int) -> str:
        """The closing event: with the score when it is positive, without a number otherwise."""
        return "goodbye" if total > 0 else "goodbye_no_points"

    def feedback(self, kind: int, success: bool, rng: np.random.Generator, **fields: Any) -> str:
        """The feedback utterance of an RF action: ``kind`` 1 encouraging / 2 challenging, on the last outcome."""
        style = {1: "encouraging", 2: "challenging"}[kind]
        return self.say(f"{style}_{'success' if success else 'failure'}", rng, **fields)


def load_dialogue(path: str | Path) -> Dialogue:
    """Load and validate a dialogue file; ``ConfigError`` names file, line and event on a problem."""
    path = Path(path)
    data, lines, _ = read_yaml(path, "dialogue file not found", "fix session.dialogue in the study config")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a dialogue file is a mapping of events to lists of sentences")
    language = data.pop("language", None)
    if not isinstance(language, str):
        raise ConfigError(f"{path}: key 'language' is missing; add e.g. 'language: en'")
    variants: dict[str, tuple[str, ...]] = {}
    for event, items in data.items():
        where = f"{path}:{lines.get(str(event), '?')}"
        if event not in EVENTS:
            raise ConfigError(f"{where}: unknown event '{event}'; events are {', '.join(EVENTS)}")
        if isinstance(items, str):
            items = [items]
        if not isinstance(items, list) or not items:
            raise ConfigError(f"{where}: event '{event}' needs a list of at least one sentence")
        for item in items:
            if not isinstance(item, str) or not item.strip():
                raise ConfigError(f"{where}: event '{event}' has an empty or non-text variant {item!r}")
            try:
                used = {name for _, name, _, _ in string.Formatter().parse(item) if name is not None}
            except ValueError as exc:
                raise ConfigError(f"{where}: event '{event}' has a broken placeholder in {item!r} ({exc}); "
                                  "write {name} for a value and {{ }} for a literal brace") from None
            unknown = used - EVENTS[event]
            if unknown:
                allowed = ", ".join("{%s}" % a for a in sorted(EVENTS[event])) or "none"
                raise ConfigError(f"{where}: event '{event}' uses unknown placeholder {{{sorted(unknown)[0]}}}; allowed: {allowed}")
            try:
                item.format(**SAMPLE_FIELDS)
            except (ValueError, KeyError, IndexError, AttributeError) as exc:
                raise ConfigError(f"{where}: event '{event}' has a placeholder that cannot be filled in {item!r} "
                                  f"({type(exc).__name__}: {exc}); write plain {{name}} placeholders") from None
        variants[event] = tuple(items)
    missing = [e for e in EVENTS if e not in variants]
    if missing:
        raise ConfigError(f"{path}: event '{missing[0]}' is missing; add at least one sentence for it")
    return Dialogue(language=language, variants=variants, source=str(path))
