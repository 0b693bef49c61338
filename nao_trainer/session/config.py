"""Study configuration: YAML files validated against the schema (``session.config_schema``), with
file:line in every error.

A study file (``config/studies/*.yaml``) overlays the documented defaults (``config/default.yaml``);
command-line flags overlay both. Validation happens once, at load, so an invalid study never
starts a session. Errors are one line: ``file:line: key 'timing.beep_hz': what is wrong; how to fix``.

NAOqi 2.9 credentials are never read from files: the robot client takes them from ``NAO_USER`` /
``NAO_PASSWORD``, and a robot URL holding ``user:password@`` is refused.
"""
from __future__ import annotations

import difflib
import hashlib
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Mapping

from nao_trainer.eeg.settings import EEGSettings
from nao_trainer.errors import ConfigError
from nao_trainer.files import PROJECT_ROOT, read_yaml
from nao_trainer.session.config_schema import (DESKTOP, INPUTS, MOCK, SCHEMA, Field,  # noqa: F401 (importable from here)
                                               check_value, is_robot_address)

#: Repository root (parent of the package). Relative paths in configs resolve against it, so
#: ``nao-trainer run`` works from any folder of a clone (installs are editable).
DEFAULT_CONFIG = PROJECT_ROOT / "config" / "default.yaml"
DEMO_STUDY = PROJECT_ROOT / "config" / "studies" / "demo.yaml"

#: Paths read from the project (resolved against the folder of the file that sets them) and paths
#: written to (resolved against the current folder, like ``--out``).
INPUT_PATHS = ("session.dialogue", "session.behaviors")


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
    objective: str = "score"

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
            problem = check_value(value, spec)  # every file's own values, even those a flag overrides later
            if problem:
                raise ConfigError(f"{where}: key '{dotted}' {problem}")
            base[key] = value
            locs[f"@{dotted}"] = where  # where the value in force came from


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
        problem = check_value(values[key], spec)
        if problem:
            raise ConfigError(f"{where}: key '{dotted}' {problem}")
        if isinstance(spec.kind, tuple) and float in spec.kind and isinstance(values[key], int):
            values[key] = float(values[key])


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
        problem = check_value(value, SCHEMA[section][key])
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
