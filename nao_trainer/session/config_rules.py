"""The rules of study keys that need more than a type and a range (robot URL, pseudonym, console address,
level lists). The ``policy`` keys' rules belong to the policies that declare them (``policies.kinds``).

The keys themselves are declared once, as fields of the section dataclasses of ``session.config``
(``core.settings.setting``); these functions are the ``check=`` of some of them. Each returns the
problem with a value (the words after ``key '...'`` in an error message) or None.
"""
from __future__ import annotations

import re

from nao_trainer import registry
from nao_trainer.errors import ConfigError
from nao_trainer.robot.address import parse_url, redact_url

INPUTS = ("simulated", "tactile", "keyboard")
#: ``robot.url`` values that are not addresses: the in-process stand-in, the laptop itself.
MOCK, DESKTOP = "mock", "desktop"


def robot_url(value: str) -> str | None:
    if value in (MOCK, DESKTOP):
        return None
    problem = parse_url(value)[1]  # the robot client's own rule: the two never disagree
    return f"{problem} (got {redact_url(value)!r})" if problem else None  # never echo a password


def robot_model(value: str) -> str | None:
    try:
        registry.spec("robot_model", value)
    except ConfigError as exc:
        return str(exc)
    return None


#: session.language -> the NAOqi speech language of that code (ALTextToSpeech.setLanguage takes the name;
#: NAO's standard voices: naoqi/audio/altexttospeech.html and family/nao_technical/languages_nao.html).
LANGUAGES: dict[str, str] = {"en": "English", "fr": "French", "de": "German", "it": "Italian", "es": "Spanish",
                             "nl": "Dutch", "ja": "Japanese", "zh": "Chinese", "pl": "Polish", "pt": "Portuguese",
                             "el": "Greek"}


def is_robot_address(url: str) -> bool:
    """True for a NAOqi address (a robot, or a stand-in started elsewhere), False for mock/desktop."""
    return url not in (MOCK, DESKTOP)


def pseudonym(value: str) -> str | None:
    if re.fullmatch(r"[A-Za-z0-9_-]{1,40}", value):
        return None
    return "must be 1-40 letters, digits, '_' or '-' (it names the session folder; never a real name)"


def unit_values(value: list) -> str | None:
    return None if all(0 <= x <= 1 for x in value) else "values must lie in [0, 1]"


def host(value: str) -> str | None:
    return None if re.fullmatch(r"[0-9A-Za-z.:-]{1,253}", value) else "must be an IP address or host name, e.g. 127.0.0.1"
