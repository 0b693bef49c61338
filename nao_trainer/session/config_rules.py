"""The rules of study keys that need more than a type and a range (robot URL, policy spec, Bayes prior,
schedule, state path, pseudonym, console address, level lists).

The keys themselves are declared once, as fields of the section dataclasses of ``session.config``
(``core.settings.setting``); these functions are the ``check=`` of some of them. Each returns the
problem with a value (the words after ``key '...'`` in an error message) or None.
"""
from __future__ import annotations

import re
import string

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
    from nao_trainer import registry  # light: no plug-in is imported here

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


def policy_spec(value: str) -> str | None:
    if value in ("schedule", "random", "personalised", "bayes") or re.fullmatch(r"usp:[^:\s]+(:[A-Za-z0-9_-]+)?", value):
        return None
    return "must be 'schedule', 'random', 'personalised', 'bayes' or 'usp:CLUSTER[:METHOD]'"


def objective(value: str) -> str | None:
    if value == "score" or re.fullmatch(r"target(:(0?\.\d+))?", value):
        return None
    return "must be 'score' or 'target:R' with 0 < R < 1, e.g. target:0.75"


def bayes_prior(value: str) -> str | None:
    # a path is resolved and checked by session.config (against the folder of the file that sets it)
    return None if value.strip() else "must be 'clusters', 'psychometric', a psychometric prior file or a folder"


def schedule(value: list) -> str | None:
    from nao_trainer.core import mdp  # lazily: `nao-trainer --help` parses without numpy

    bad = [a for a in value if a not in mdp.ACTION_NAMES]
    if bad:
        return f"unknown action {bad[0]!r}; use {', '.join(mdp.ACTION_NAMES)}"
    if not value:
        return "needs at least one action"
    if value[0] not in mdp.ACTION_NAMES[:4]:
        return f"must start with a level action (L1..L4), got {value[0]!r}: there is no outcome to give feedback on yet"
    return None


STATE_PATH_FIELDS = ("pseudonym", "output")


def state_path(value: str) -> str | None:
    if value == "{session}":
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


def pseudonym(value: str) -> str | None:
    if re.fullmatch(r"[A-Za-z0-9_-]{1,40}", value):
        return None
    return "must be 1-40 letters, digits, '_' or '-' (it names the session folder; never a real name)"


def unit_values(value: list) -> str | None:
    return None if all(0 <= x <= 1 for x in value) else "values must lie in [0, 1]"


def assessment(value: list) -> str | None:
    return None if len(value) <= 12 and all(1 <= x <= 4 for x in value) else "must list levels 1..4, at most 12 turns"


def host(value: str) -> str | None:
    return None if re.fullmatch(r"[0-9A-Za-z.:-]{1,253}", value) else "must be an IP address or host name, e.g. 127.0.0.1"
