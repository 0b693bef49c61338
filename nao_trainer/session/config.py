"""Study configuration: YAML files validated against a schema, with file:line in every error.

A study file (``config/studies/*.yaml``) overlays the documented defaults (``config/default.yaml``);
command-line flags overlay both. Validation happens once, at load, so an invalid study never
starts a session. Errors are one line: ``file:line: key 'timing.beep_hz': what is wrong; how to fix``.

NAOqi 2.9 credentials are never read from files: the robot client takes them from ``NAO_USER`` /
``NAO_PASSWORD``, and a robot URL holding ``user:password@`` is refused.
"""
from __future__ import annotations

import difflib
import hashlib
import math
import os
import re
import string
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable, Mapping

from nao_trainer.eeg.settings import EEGSettings
from nao_trainer.errors import ConfigError
from nao_trainer.robot.address import parse_url, redact_url
from nao_trainer.files import PROJECT_ROOT, read_yaml

#: Repository root (parent of the package). Relative paths in configs resolve against it, so
#: ``nao-trainer run`` works from any folder of a clone (installs are editable).
DEFAULT_CONFIG = PROJECT_ROOT / "config" / "default.yaml"
DEMO_STUDY = PROJECT_ROOT / "config" / "studies" / "demo.yaml"

INPUTS = ("simulated", "tactile", "keyboard")
#: ``robot.url`` values that are not addresses: the in-process stand-in, the laptop itself.
MOCK, DESKTOP = "mock", "desktop"
#: Paths read from the project (resolved against the folder of the file that sets them) and paths
#: written to (resolved against the current folder, like ``--out``).
INPUT_PATHS = ("session.dialogue", "session.behaviors")
#: No setting needs an integer this large; beyond it a number is a typo (and may not fit a float).
MAX_INT = 10**12


# ----------------------------------------------------------------------------------------------
# Schema
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Field:
    """One configuration key: its type, allowed values and a fix hint for error messages."""

    kind: type | tuple[type, ...]
    nullable: bool = False
    min: float | None = None
    max: float | None = None
    choices: tuple[Any, ...] | None = None
    item: type | tuple[type, ...] | None = None  # element type of a list
    length: int | None = None  # exact list length
    check: Callable[[Any], str | None] | None = None  # extra rule: returns a problem or None
    free: bool = False  # a free-form mapping (keys not checked)


def _robot_url(value: str) -> str | None:
    if value in (MOCK, DESKTOP):
        return None
    problem = parse_url(value)[1]  # the robot client's own rule: the two never disagree
    return f"{problem} (got {redact_url(value)!r})" if problem else None  # never echo a password


def is_robot_address(url: str) -> bool:
    """True for a NAOqi address (a robot, or a stand-in started elsewhere), False for mock/desktop."""
    return url not in (MOCK, DESKTOP)


def _policy_spec(value: str) -> str | None:
    if value in ("schedule", "random", "personalised") or re.fullmatch(r"usp:[^:\s]+(:[A-Za-z0-9_-]+)?", value):
        return None
    return "must be 'schedule', 'random', 'personalised' or 'usp:CLUSTER[:METHOD]'"


def _schedule(value: list) -> str | None:
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


def _state_path(value: str) -> str | None:
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


SCHEMA: dict[str, Any] = {
    "study": {"name": Field(str), "description": Field(str, nullable=True)},
    "participant": {"pseudonym": Field(str, check=lambda v: None if re.fullmatch(r"[A-Za-z0-9_-]{1,40}", v)
                                        else "must be 1-40 letters, digits, '_' or '-' (it names the session folder; never a real name)")},
    "robot": {
        "url": Field(str, check=_robot_url),
        "connect_deadline_s": Field((int, float), min=0.5, max=120),
        "max_reconnect_s": Field((int, float), min=0, max=3600),
        "backoff_initial_s": Field((int, float), min=0.05, max=60),
        "backoff_max_s": Field((int, float), min=0.1, max=300),
        "posture_speed": Field((int, float), min=0.05, max=1.0),
    },
    "session": {
        "turns": Field(int, min=1, max=500),
        "practice": Field(bool),
        "seed": Field(int, nullable=True, min=0),
        "language": Field(str, choices=("en",)),
        "dialogue": Field(str),
        "behaviors": Field(str),
        "output": Field(str),
        "max_duration_s": Field((int, float), nullable=True, min=1, max=86400),
    },
    "timing": {
        "speed": Field((int, float), min=0.1, max=200),
        "pause_before_level_s": Field((int, float), min=0, max=30),
        "letter_gap_s": Field((int, float), min=0, max=10),
        "beep_hz": Field(int, min=100, max=8000),
        "beep_s": Field((int, float), min=0.05, max=3),
        "beep_gain": Field((int, float), min=0.0, max=1.0),
        "response_timeout_base_s": Field((int, float), min=1, max=300),
        "response_timeout_per_letter_s": Field((int, float), min=0, max=60),
        "grace_s": Field((int, float), min=0, max=5),
        "listening_tail_s": Field((int, float), min=0, max=5),
    },
    "answers": {
        "input": Field(str, choices=INPUTS),
        "debounce_s": Field((int, float), min=0, max=1),
    },
    "participant_model": {
        "success_by_level": Field(list, item=(int, float), length=4, check=lambda v: None if all(0 <= x <= 1 for x in v) else "values must lie in [0, 1]"),
        "engagement_by_level": Field(list, item=(int, float), length=4, check=lambda v: None if all(0 <= x <= 1 for x in v) else "values must lie in [0, 1]"),
        "user_model": Field(str, nullable=True),
    },
    "policy": {
        "kind": Field(str, check=_policy_spec),
        "schedule": Field(list, item=str, check=_schedule),
        "learning": Field(bool),
        "state_path": Field(str, nullable=True, check=lambda v: _state_path(v)),
        "guidance": Field((int, float), min=0, max=10),
        # personalised (learn.personalised, docs/personalisation.md)
        "assessment": Field(list, item=int, check=lambda v: None if len(v) <= 12 and all(1 <= x <= 4 for x in v)
                            else "levels 1..4, at most 12 turns"),
        "kappa": Field((int, float), min=0.01),
        "margin": Field((int, float), min=0),
    },
    "console": {
        "enabled": Field(bool),
        "port": Field(int, min=0, max=65535),
        "bind": Field(str, check=lambda v: None if re.fullmatch(r"[0-9A-Za-z.:-]{1,253}", v)
                      else "must be an IP address or host name, e.g. 127.0.0.1"),
    },
    # Types only: the modes, scopes, stream properties and processing keys are judged by the one
    # validator of the section, eeg.settings.EEGSettings (called by load_config with file:line).
    "eeg": {
        "mode": Field(str),
        "required": Field(bool),
        "stream_type": Field(str),
        "stream_name": Field(str, nullable=True),
        "source_id": Field(str, nullable=True),
        "lsl_scope": Field(str),
        "processing": Field(dict, free=True),
        "xdf": Field(bool),
    },
}


# ----------------------------------------------------------------------------------------------
# Typed configuration
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StudySection:
    name: str
    description: str | None


@dataclass(frozen=True)
class ParticipantSection:
    pseudonym: str


@dataclass(frozen=True)
class RobotSection:
    url: str
    connect_deadline_s: float
    max_reconnect_s: float
    backoff_initial_s: float
    backoff_max_s: float
    posture_speed: float


@dataclass(frozen=True)
class SessionSection:
    turns: int
    practice: bool
    seed: int | None
    language: str
    dialogue: str
    behaviors: str
    output: str
    max_duration_s: float | None

    @property
    def dialogue_path(self) -> Path:
        """Absolute: resolved at load against the folder of the file that set it."""
        return Path(self.dialogue)

    @property
    def behaviors_path(self) -> Path:
        return Path(self.behaviors)

    @property
    def output_dir(self) -> Path:
        """``session.output`` resolved against the current folder when relative (``./sessions/``)."""
        return Path(os.path.expanduser(self.output)).resolve()


@dataclass(frozen=True)
class TimingSection:
    """Durations in session seconds; ``speed`` divides them all (see ``session.stage.Clock``)."""

    speed: float
    pause_before_level_s: float
    letter_gap_s: float
    beep_hz: int
    beep_s: float
    beep_gain: float
    response_timeout_base_s: float
    response_timeout_per_letter_s: float
    grace_s: float
    listening_tail_s: float

    def response_timeout_s(self, length: int) -> float:
        """Answer window in session seconds: base + per-letter x length (10 s + 2.5 s x L by default)."""
        return float(self.response_timeout_base_s + self.response_timeout_per_letter_s * length)


@dataclass(frozen=True)
class AnswersSection:
    input: str
    debounce_s: float


@dataclass(frozen=True)
class ParticipantModelSection:
    success_by_level: tuple[float, ...]
    engagement_by_level: tuple[float, ...]
    user_model: str | None


@dataclass(frozen=True)
class PolicySection:
    kind: str
    schedule: tuple[str, ...]
    learning: bool
    state_path: str | None
    guidance: float
    assessment: tuple[int, ...]
    kappa: float
    margin: float

    def state_file(self, pseudonym: str, output: Path) -> Path | None:
        """Where a learning policy keeps its state across sessions: by default the participant's
        folder ``<output>/participants/<pseudonym>/policy_state.json``; None = the session folder."""
        if self.state_path == "{session}":
            return None
        template = self.state_path or str(Path("{output}") / "participants" / "{pseudonym}" / "policy_state.json")
        return Path(template.format(pseudonym=pseudonym, output=output)).expanduser().resolve()


@dataclass(frozen=True)
class ConsoleSection:
    enabled: bool
    port: int
    bind: str


#: The dataclass of each schema section (keys = field names, checked at import below).
SECTIONS: dict[str, type] = {
    "study": StudySection, "participant": ParticipantSection, "robot": RobotSection, "session": SessionSection,
    "timing": TimingSection, "answers": AnswersSection, "participant_model": ParticipantModelSection,
    "policy": PolicySection, "console": ConsoleSection, "eeg": EEGSettings,
}
assert all(tuple(SCHEMA[name]) == tuple(f.name for f in fields(cls)) for name, cls in SECTIONS.items()), \
    "config SECTIONS and SCHEMA disagree"


def _frozen(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


@dataclass(frozen=True)
class StudyConfig:
    """A validated study configuration: one frozen dataclass per section.

    ``values`` is the merged nested dict (JSON-ready), kept for ``session.json``.
    """

    values: dict[str, Any]
    sources: tuple[str, ...]  # files that were merged, in order
    text_sha256: str  # sha256 over the texts of those files and the overrides
    study: StudySection
    participant: ParticipantSection
    robot: RobotSection
    session: SessionSection
    timing: TimingSection
    answers: AnswersSection
    participant_model: ParticipantModelSection
    policy: PolicySection
    console: ConsoleSection
    eeg: EEGSettings  # what the EEG monitor takes

    @classmethod
    def build(cls, values: dict[str, Any], sources: tuple[str, ...], text_sha256: str,
              eeg: EEGSettings, overrides: dict[str, Any] | None = None) -> "StudyConfig":
        """Typed sections from validated ``values`` (``eeg`` validated by its own settings class)."""
        sections = {name: section(**{k: _frozen(v) for k, v in values[name].items()})
                    for name, section in SECTIONS.items() if name != "eeg"}
        return cls(values=values, sources=sources, text_sha256=text_sha256, eeg=eeg, overrides=overrides, **sections)

    def output_dir(self) -> Path:
        return self.session.output_dir

    def policy_state_file(self) -> Path | None:
        """The learning policy's state file for this participant (``policy.state_path``), None = session folder."""
        return self.policy.state_file(self.participant.pseudonym, self.output_dir())

    def response_timeout_s(self, length: int) -> float:
        return self.timing.response_timeout_s(length)

    overrides: dict[str, Any] | None = None  # the command line's dotted keys (to rebuild the same config)

    def snapshot(self) -> dict[str, Any]:
        """What session.json stores: the merged values (never holds credentials), and what to load them again."""
        return {"values": self.values, "sources": list(self.sources), "sha256": self.text_sha256,
                "overrides": {k: v for k, v in (self.overrides or {}).items() if v is not None}}


@dataclass
class _Loc:
    file: str
    line: int | None

    def __str__(self) -> str:
        return f"{self.file}:{self.line}" if self.line else self.file


# ----------------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------------


def _read_yaml(path: Path) -> tuple[Any, dict[str, _Loc], str]:
    """Parse ``path`` (absolute, so messages show where it was looked for); returns (data, locations, text)."""
    data, lines, text = read_yaml(path, fix="check the path")
    if data is None:
        raise ConfigError(f"{path}: the file is empty (or only comments); a study file sets at least study.name "
                          "(see config/studies/demo.yaml)")
    return data, {key: _Loc(str(path), line) for key, line in lines.items()}, text


def _merge(base: dict, over: Mapping, schema: dict, prefix: str, locs: dict[str, _Loc], file: str) -> None:
    """Overlay ``over`` on ``base`` in place, rejecting keys the schema does not know."""
    if not isinstance(over, Mapping):
        where = locs.get(prefix, _Loc(file, None))
        raise ConfigError(f"{where}: key '{prefix or '(top level)'}' must be a mapping of keys, got {type(over).__name__}")
    for key, value in over.items():
        dotted = f"{prefix}.{key}" if prefix else str(key)
        where = locs.get(dotted, _Loc(file, None))
        if key not in schema:
            hint = difflib.get_close_matches(str(key), [str(k) for k in schema], n=1)
            fix = f"did you mean '{(prefix + '.') if prefix else ''}{hint[0]}'?" if hint else f"valid keys here: {', '.join(schema)}"
            raise ConfigError(f"{where}: unknown key '{dotted}'; {fix}")
        spec = schema[key]
        if isinstance(spec, dict):
            base.setdefault(key, {})
            _merge(base[key], value if value is not None else {}, spec, dotted, locs, file)
        else:
            problem = _check(value, spec)  # every file's own values, even those a flag overrides later
            if problem:
                raise ConfigError(f"{where}: key '{dotted}' {problem}")
            base[key] = value
            locs[f"@{dotted}"] = where  # where the value in force came from


def _type_name(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    names = {int: "an integer", float: "a number", str: "a text", bool: "true/false", list: "a list", dict: "a mapping"}
    return " or ".join(names.get(k, k.__name__) for k in kinds if not (k is int and float in kinds))


def _is_kind(value: Any, kind: type | tuple[type, ...]) -> bool:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool) and bool not in kinds:
        return False
    return isinstance(value, kinds)


def _validate(values: dict, schema: dict, prefix: str, locs: dict[str, _Loc]) -> None:
    for key, spec in schema.items():
        dotted = f"{prefix}.{key}" if prefix else key
        where = locs.get(f"@{dotted}", locs.get(dotted, _Loc(str(DEFAULT_CONFIG), None)))
        if isinstance(spec, dict):
            if key not in values:
                raise ConfigError(f"{where}: section '{dotted}' is missing; copy it from {DEFAULT_CONFIG}")
            _validate(values[key], spec, dotted, locs)
            continue
        if key not in values:
            raise ConfigError(f"{where}: key '{dotted}' is missing; add it (see {DEFAULT_CONFIG})")
        problem = _check(values[key], spec)
        if problem:
            raise ConfigError(f"{where}: key '{dotted}' {problem}")
        if isinstance(spec.kind, tuple) and float in spec.kind and isinstance(values[key], int):
            values[key] = float(values[key])


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


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check(value: Any, spec: Field) -> str | None:
    if value is None:
        return None if spec.nullable else f"needs a value ({_type_name(spec.kind)}), got nothing"
    if not _is_kind(value, spec.kind):
        return f"must be {_type_name(spec.kind)}, got {_short(value)}"
    problem = _number_problem(value) or (_text_problem(value) if isinstance(value, str) else None)
    if problem:
        return problem
    if spec.choices is not None and value not in spec.choices:
        return f"must be one of {', '.join(map(str, spec.choices))}, got {value!r}"
    if spec.min is not None and value < spec.min:
        return f"must be >= {spec.min:g}, got {value!r}"
    if spec.max is not None and value > spec.max:
        return f"must be <= {spec.max:g}, got {value!r}"
    if isinstance(value, list):
        if spec.length is not None and len(value) != spec.length:
            return f"must have {spec.length} values, got {len(value)}"
        for item in value:
            if spec.item is not None and not _is_kind(item, spec.item):
                return f"values must each be {_type_name(spec.item)}, got {_short(item)}"
            problem = _number_problem(item) or (_text_problem(item) if isinstance(item, str) else None)
            if problem:
                return f"values: {problem}"
    if spec.check is not None:
        problem = spec.check(value)
        if problem:
            return f"{problem} (got {_short(value)})" if "got" not in problem else problem
    return None


def _set_dotted(values: dict, dotted: str, value: Any) -> None:
    *parents, last = dotted.split(".")
    node = values
    for part in parents:
        node = node.setdefault(part, {})
    node[last] = value


def load_config(study: str | Path | None = None, overrides: Mapping[str, Any] | None = None,
                default: str | Path | None = None) -> StudyConfig:
    """Defaults, then ``study`` (a file; None = the demo study), then ``overrides`` (dotted keys).

    Raises ``ConfigError`` naming file, line and key for the first problem found.
    """
    default_path = Path(os.path.abspath(default)) if default else DEFAULT_CONFIG
    study_path = Path(os.path.abspath(os.path.expanduser(study))) if study is not None else DEMO_STUDY
    values: dict[str, Any] = {}
    locs: dict[str, _Loc] = {}
    digest = hashlib.sha256()
    sources = []
    for path in (default_path, study_path) if study_path.resolve() != default_path.resolve() else (default_path,):
        data, file_locs, text = _read_yaml(path)
        locs.update(file_locs)
        _merge(values, data or {}, SCHEMA, "", locs, str(path))
        digest.update(text.encode())
        sources.append(str(path))
    for dotted, value in (overrides or {}).items():
        if value is None:
            continue
        flag_loc = _Loc(f"command line ({dotted})", None)
        section, _, key = dotted.partition(".")
        if section not in SCHEMA or key not in SCHEMA[section]:
            raise ConfigError(f"command line: unknown configuration key '{dotted}'")
        problem = _check(value, SCHEMA[section][key])
        if problem:
            raise ConfigError(f"{flag_loc}: key '{dotted}' {problem}")
        _set_dotted(values, dotted, value)
        locs[f"@{dotted}"] = flag_loc
        digest.update(f"{dotted}={value!r}".encode())
    _validate(values, SCHEMA, "", locs)
    _resolve_input_paths(values, locs)
    _check_combination(values, locs)

    def where(dotted: str) -> _Loc:
        return locs.get(f"@{dotted}") or locs.get(dotted) or locs.get("@eeg.processing") or _Loc("configuration", None)

    eeg = EEGSettings.from_mapping(values["eeg"], where=where)
    t = values["robot"]
    if t["backoff_max_s"] < t["backoff_initial_s"]:
        raise ConfigError(f"{locs.get('@robot.backoff_max_s')}: key 'robot.backoff_max_s' must be >= robot.backoff_initial_s")
    return StudyConfig.build(values, tuple(sources), digest.hexdigest(), eeg,
                             {k: v for k, v in (overrides or {}).items() if v is not None})


def _resolve_input_paths(values: dict, locs: dict[str, _Loc]) -> None:
    """Dialogue and behaviors files: relative paths resolve against the folder of the file that set them
    (the current folder for a flag); must exist. Replaced by the absolute path (what session.json shows)."""
    for dotted in INPUT_PATHS:
        section, key = dotted.split(".")
        where = locs.get(f"@{dotted}", _Loc(str(DEFAULT_CONFIG), None))
        given = Path(os.path.expanduser(values[section][key]))
        base = Path(where.file).parent if Path(where.file).is_file() else Path.cwd()
        path = Path(os.path.abspath(given if given.is_absolute() else base / given))
        if not path.is_file():
            rule = "" if given.is_absolute() else f" (relative paths resolve against {base}, the folder of the file that sets them)"
            raise ConfigError(f"{where}: key '{dotted}': {path} is not a file{rule}; fix the path")
        values[section][key] = str(path)


def _check_combination(values: dict, locs: dict[str, _Loc]) -> None:
    """Settings that are each valid but must not go together."""
    if values["robot"]["url"] == DESKTOP and values["answers"]["input"] == "tactile":
        where = locs.get("@answers.input", _Loc("configuration", None))
        raise ConfigError(f"{where}: key 'answers.input' is 'tactile', but --robot desktop has no head buttons: "
                          "answer with --input keyboard (or simulated)")
    if values["eeg"]["mode"] == "simulated" and values["answers"]["input"] != "simulated":
        where = locs.get("@eeg.mode", _Loc("configuration", None))
        raise ConfigError(f"{where}: key 'eeg.mode' is 'simulated', but a person answers "
                          f"(answers.input: {values['answers']['input']}): a simulated Muse would record made-up "
                          "engagement for them; use eeg.mode 'lsl' (a real Muse) or 'off' (--eeg off)")
