"""How the robot looks during a session: eye colours, animated speech and postures per event.

Loaded from ``behaviors/*.yaml`` and validated at load, like the study configuration.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from nao_trainer.errors import ConfigError
from nao_trainer.files import read_yaml

#: Session events that have a behavior.
EVENTS: tuple[str, ...] = ("greeting", "instructions", "practice", "encouraging", "challenging",
                           "level", "sequence", "answer", "paused", "goodbye")
#: ALAnimatedSpeech body-language modes.
MODES: tuple[str, ...] = ("contextual", "random", "disabled")
#: Predefined postures of ALRobotPosture (NAO).
POSTURES: tuple[str, ...] = ("Stand", "StandInit", "StandZero", "Crouch", "Sit", "SitRelax", "LyingBelly", "LyingBack")
SAFE_POSTURES: tuple[str, ...] = ("Crouch", "Sit", "SitRelax")


@dataclass(frozen=True)
class Behavior:
    """What the robot does during one event."""

    leds: int  # 0xRRGGBB
    animated: bool = False
    mode: str = "contextual"


@dataclass(frozen=True)
class Behaviors:
    events: dict[str, Behavior]
    start_posture: str
    end_posture: str
    safe_posture: str
    led_fade_s: float
    leds_reset: int
    source: str = ""

    def __getitem__(self, event: str) -> Behavior:
        return self.events[event]


def _color(value: object, where: str, key: str) -> int:
    if isinstance(value, str) and re.fullmatch(r"#?[0-9A-Fa-f]{6}", value):
        return int(value.lstrip("#"), 16)
    raise ConfigError(f"{where}: key '{key}' must be a colour '#RRGGBB' (quoted), got {value!r}")


def load_behaviors(path: str | Path) -> Behaviors:
    """Load and validate a behaviors file; ``ConfigError`` names file, line and key on a problem."""
    path = Path(path)
    data, lines, _ = read_yaml(path, "behaviors file not found", "fix session.behaviors in the study config")

    def where(key: str) -> str:
        return f"{path}:{lines[key]}" if key in lines else str(path)

    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a behaviors file is a mapping with postures, events, led_fade_s, leds_reset")
    for key in data:
        if key not in ("postures", "events", "led_fade_s", "leds_reset"):
            raise ConfigError(f"{where(key)}: unknown key '{key}'; valid: postures, events, led_fade_s, leds_reset")
    postures = data.get("postures") or {}
    if not isinstance(postures, dict):
        raise ConfigError(f"{where('postures')}: key 'postures' must be a mapping like "
                          f"{{start: Stand, end: Crouch, safe: Crouch}}, got {postures!r}")
    chosen = {}
    for which in ("start", "end", "safe"):
        name = postures.get(which)
        allowed = SAFE_POSTURES if which == "safe" else POSTURES
        if name not in allowed:
            raise ConfigError(f"{where('postures.' + which) if 'postures.' + which in lines else where('postures')}: "
                              f"key 'postures.{which}' must be one of {', '.join(allowed)}, got {name!r}")
        chosen[which] = name
    events_data = data.get("events")
    if not isinstance(events_data, dict):
        raise ConfigError(f"{where('events')}: key 'events' must map each event to its behavior")
    events: dict[str, Behavior] = {}
    for name, spec in events_data.items():
        key = f"events.{name}"
        if name not in EVENTS:
            raise ConfigError(f"{where(key)}: unknown event '{name}'; events are {', '.join(EVENTS)}")
        if not isinstance(spec, dict):
            raise ConfigError(f"{where(key)}: key '{key}' must be a mapping like {{leds: '#FFFFFF', animated: false}}")
        extra = set(spec) - {"leds", "animated", "mode"}
        if extra:
            raise ConfigError(f"{where(key)}: unknown key '{key}.{sorted(extra)[0]}'; valid: leds, animated, mode")
        animated = spec.get("animated", False)
        mode = spec.get("mode", "contextual")
        if not isinstance(animated, bool):
            raise ConfigError(f"{where(key + '.animated')}: key '{key}.animated' must be true/false, got {animated!r}")
        if mode not in MODES:
            raise ConfigError(f"{where(key + '.mode')}: key '{key}.mode' must be one of {', '.join(MODES)}, got {mode!r}")
        events[name] = Behavior(_color(spec.get("leds"), where(key), f"{key}.leds"), animated, mode)
    missing = [e for e in EVENTS if e not in events]
    if missing:
        raise ConfigError(f"{where('events')}: event '{missing[0]}' has no behavior; add 'events.{missing[0]}'")
    fade = data.get("led_fade_s", 0.2)
    if isinstance(fade, bool) or not isinstance(fade, (int, float)) or not 0 <= fade <= 5:
        raise ConfigError(f"{where('led_fade_s')}: key 'led_fade_s' must be a number in 0..5, got {fade!r}")
    reset = _color(data.get("leds_reset", "#FFFFFF"), where("leds_reset"), "leds_reset")
    return Behaviors(events, chosen["start"], chosen["end"], chosen["safe"], float(fade), reset, str(path))
