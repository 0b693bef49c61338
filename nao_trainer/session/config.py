"""Study configuration: YAML files validated against the section dataclasses, with file:line in every error.

Each key is declared once, as a field of its section's dataclass with its rule (``core.settings``:
type, range, choices, an extra check from ``session.config_rules``, a doc line); ``SCHEMA`` is derived
from them and ``config/default.yaml`` is checked against them by a test (tests/session/test_config.py).

A study file (``config/studies/*.yaml``) overlays the documented defaults (``config/default.yaml``);
command-line flags overlay both. Validation happens once, at load, so an invalid study never
starts a session. Errors are one line: ``file:line: key 'timing.beep_hz': what is wrong; how to fix``.

NAOqi 2.9 credentials are never read from files: the robot client takes them from ``NAO_USER`` /
``NAO_PASSWORD``, and a robot URL holding ``user:password@`` is refused.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from nao_trainer import registry
from nao_trainer.core.settings import (Rule, SettingError, UnknownKey, build, check_value, optional_keys, schema_of,
                                       setting, settings)
from nao_trainer.eeg.settings import EEGSettings
from nao_trainer.tasks.settings import TaskSettings
from nao_trainer.errors import ConfigError
from nao_trainer.files import PROJECT_ROOT, read_yaml
from nao_trainer.policies.participant_state import state_file
from nao_trainer.policies.plugin import compose_section
from nao_trainer.robot.model import make_model
from nao_trainer.session import config_rules as rules
from nao_trainer.session.config_rules import DESKTOP, INPUTS, MOCK, is_robot_address  # noqa: F401 (importable from here)

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


NUMBER = (int, float)


@settings
class StudySection:
    name: str = setting(kind=str, doc="short name of the study")
    description: str | None = setting(kind=str, nullable=True, doc="free text, copied into session.json")


@settings
class ParticipantSection:
    pseudonym: str = setting(kind=str, nullable=True, check=rules.pseudonym,
                             doc="names the session folder; never a real name; null = entered per session")

    def __post_init__(self) -> None:
        # "simulated" when none was entered (session.participant refuses that when a person answers)
        if self.pseudonym is None:
            object.__setattr__(self, "pseudonym", "simulated")


@settings
class RobotSection:
    url: str = setting(kind=str, check=rules.robot_url, doc="mock | desktop | tcp://IP:9559 | tcps://IP:9503")
    connect_deadline_s: float = setting(kind=NUMBER, min=0.5, max=120, doc="give up connecting after this long")
    max_reconnect_s: float = setting(kind=NUMBER, min=0, max=3600, doc="keep reconnecting this long")
    backoff_initial_s: float = setting(kind=NUMBER, min=0.05, max=60, doc="first wait between attempts")
    backoff_max_s: float = setting(kind=NUMBER, min=0.1, max=300, doc="longest wait between attempts")
    posture_speed: float = setting(kind=NUMBER, min=0.05, max=1.0, doc="fraction of maximum joint speed")
    autonomous_life: str = setting(kind=str, choices=("disabled", "solitary", "interactive", "unchanged"),
                                   doc="the ALAutonomousLife state during a session (unchanged: leave it as found)")
    rest_at_end: bool = setting(kind=bool, doc="ALMotion.rest() at the end (motors off)")
    link_check_s: float = setting(kind=NUMBER, min=0.2, max=10,
                                  doc="during an answer window, a cheap call this often (wall seconds)")
    link_deadline_s: float = setting(kind=NUMBER, min=0.2, max=30,
                                     doc="the watchdog call's deadline, and how late the beep's reply may come: "
                                         "beyond it = a frozen link, the turn is replayed")
    model: str = setting(registry.default("robot_model"), kind=str, check=rules.robot_model,
                         doc="the robot model plug-in (nao-trainer plugins lists them): nao, pepper, ...")
    model_settings: dict = setting(factory=dict, kind=dict, free=True,
                                   doc="the model's own settings (its Settings class; nao-trainer plugins)")
    allow_life_on: bool = setting(False, kind=bool,
                                  doc="go on when the robot refuses to change Autonomous Life (else check and run fail)")

    def __post_init__(self) -> None:
        if self.backoff_max_s < self.backoff_initial_s:
            raise SettingError("backoff_max_s", "must be >= robot.backoff_initial_s")
        # the model's own settings, validated with the section (``key 'robot.model_settings.cool_posture' ...``)

        object.__setattr__(self, "_model", make_model(self.model, self.model_settings, prefix="model_settings"))

    def robot_model(self):
        """The robot model plug-in (``robot.model.RobotModel``) with its validated settings."""
        return self._model  # type: ignore[attr-defined]


@settings
class SessionSection:
    turns: int = setting(kind=int, min=1, max=500, doc="turns per session")
    practice: bool = setting(kind=bool, doc="one practice sequence before the first turn")
    seed: int | None = setting(kind=int, nullable=True, min=0, doc="null = drawn and recorded")
    language: str = setting(kind=str, choices=tuple(rules.LANGUAGES),
                            doc="dialogue and speech language (en, fr, de, ...): set on the robot")
    dialogue: str = setting(kind=str, doc="dialogue file (relative: to the file that sets it)")
    behaviors: str = setting(kind=str, doc="behaviors file (relative: to the file that sets it)")
    output: str = setting(kind=str, doc="session folders are created under this folder")
    max_duration_s: float | None = setting(kind=NUMBER, nullable=True, min=1, max=86400, doc="null = no limit")

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


@settings
class TimingSection:
    """Durations in session seconds; ``speed`` divides them all (see ``session.stage.Clock``)."""

    speed: float = setting(kind=NUMBER, min=0.1, max=200, doc="divides every spoken/slept duration")
    pause_before_level_s: float = setting(kind=NUMBER, min=0, max=30, doc="silence before the level")
    letter_gap_s: float = setting(kind=NUMBER, min=0, max=10, doc="silence between two letters")
    beep_hz: int = setting(kind=int, min=100, max=8000, doc="the beep that opens the answer window")
    beep_s: float = setting(kind=NUMBER, min=0.05, max=3, doc="beep duration")
    beep_gain: float = setting(kind=NUMBER, min=0.0, max=1.0, doc="beep volume")
    response_timeout_base_s: float = setting(kind=NUMBER, min=1, max=300, doc="answer window base")
    response_timeout_per_letter_s: float = setting(kind=NUMBER, min=0, max=60, doc="answer window per letter")
    grace_s: float = setting(kind=NUMBER, min=0, max=5, doc="extra presses within this count as too many")
    listening_tail_s: float = setting(kind=NUMBER, min=0, max=5, doc="listening phase ends this long after the beep")

    def response_timeout_s(self, length: int) -> float:
        """Answer window in session seconds: base + per-letter x length (10 s + 2.5 s x L by default)."""
        return float(self.response_timeout_base_s + self.response_timeout_per_letter_s * length)


@settings
class AnswersSection:
    input: str = setting(kind=str, choices=INPUTS, doc="simulated | tactile | keyboard")
    debounce_s: float = setting(kind=NUMBER, min=0, max=1, doc="presses closer than this count once")


@settings
class ParticipantModelSection:
    success_by_level: tuple[float, ...] = setting(kind=list, item=NUMBER, length=4, check=rules.unit_values,
                                                  doc="P(success) for levels 1-4")
    engagement_by_level: tuple[float, ...] = setting(kind=list, item=NUMBER, length=4, check=rules.unit_values,
                                                     doc="engagement per level, 0-1")
    user_model: str | None = setting(kind=str, nullable=True, doc="cluster id or simulator JSON")


#: The ``policy`` section: ``kind``, the keys learning policies share, and each installed policy's own keys,
#: each declared once by its owner (``policies.plugin.compose_section``; the built-ins: ``policies.kinds``).
PolicySection = compose_section()


@settings
class ConsoleSection:
    enabled: bool = setting(kind=bool, doc="serve the supervisor console")
    port: int = setting(kind=int, min=0, max=65535, doc="0 = a free port")
    bind: str = setting(kind=str, check=rules.host, doc="loopback unless --console-bind")


#: The sections of a study, in file order. Each dataclass is its own schema (``core.settings``).
SECTIONS: dict[str, type] = {
    "study": StudySection, "task": TaskSettings, "participant": ParticipantSection, "robot": RobotSection,
    "session": SessionSection,
    "timing": TimingSection, "answers": AnswersSection, "participant_model": ParticipantModelSection,
    "policy": PolicySection, "console": ConsoleSection, "eeg": EEGSettings,
}
#: section -> key -> ``core.settings.Rule`` (or a nested section's schema), derived from ``SECTIONS``.
SCHEMA: dict[str, Any] = {name: schema_of(cls) for name, cls in SECTIONS.items()}
#: Dotted keys that may be left out (the field has a default: ``eeg.processing.*``, a policy's own keys).
OPTIONAL: frozenset[str] = frozenset(optional_keys(SECTIONS))
_COMPOSED_FOR = registry.names("policy")


def refresh_policies() -> None:
    """Compose the ``policy`` section again when the installed policies changed (a plug-in package
    installed in a running process, after ``registry.reload_entry_points()``); cheap when nothing did."""
    global PolicySection, OPTIONAL, _COMPOSED_FOR
    if registry.names("policy") == _COMPOSED_FOR:
        return
    PolicySection = compose_section()
    SECTIONS["policy"] = PolicySection
    SCHEMA["policy"] = schema_of(PolicySection)
    OPTIONAL = frozenset(optional_keys(SECTIONS))
    _COMPOSED_FOR = registry.names("policy")


@dataclass(frozen=True)
class StudyConfig:
    """A validated study configuration: one frozen dataclass per section.

    ``values`` is the merged nested dict (JSON-ready), kept for ``session.json``.
    """

    values: dict[str, Any]
    sources: tuple[str, ...]  # files that were merged, in order
    text_sha256: str  # sha256 over the texts of those files and the overrides
    study: StudySection
    task: TaskSettings  # which task is trained (``tasks.settings``)
    participant: ParticipantSection
    robot: RobotSection
    session: SessionSection
    timing: TimingSection
    answers: AnswersSection
    participant_model: ParticipantModelSection
    policy: Any  # PolicySection (composed from the installed policies)
    console: ConsoleSection
    eeg: EEGSettings  # what the EEG monitor takes

    @classmethod
    def build(cls, values: dict[str, Any], sources: tuple[str, ...], text_sha256: str,
              overrides: dict[str, Any] | None = None) -> "StudyConfig":
        """Typed sections from ``values``; ``core.settings.SettingError`` (dotted key) for a value or a
        relation between values that breaks a rule."""
        sections = {name: build(section, values[name], name) for name, section in SECTIONS.items()}
        return cls(values=values, sources=sources, text_sha256=text_sha256, overrides=overrides, **sections)

    def output_dir(self) -> Path:
        return self.session.output_dir

    def policy_state_file(self) -> Path | None:
        """The persisting policy's state file for this participant (``policy.state_path``); None = the session
        folder, or a policy that keeps no participant state."""
        if not self.policy.persists:
            return None
        return state_file(self.policy.kind, self.policy.state_path, self.participant.pseudonym, self.output_dir())

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
            raise ConfigError(f"{where}: {UnknownKey(prefix, str(key), [str(k) for k in schema])}")
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
            if dotted in OPTIONAL:
                continue
            raise ConfigError(f"{where}: key '{dotted}' is missing; add it (see {DEFAULT_CONFIG})")
        problem = check_value(values[key], spec)
        if problem:
            raise ConfigError(f"{where}: key '{dotted}' {problem}")
        if isinstance(spec.kind, tuple) and float in spec.kind and isinstance(values[key], int):
            values[key] = float(values[key])


def _schema_at(dotted: str) -> Rule | dict | None:
    """The rule of a dotted key, the schema of a nested section (``eeg.processing``), or None when unknown."""
    node: Any = SCHEMA
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node if isinstance(node, (Rule, dict)) and "." in dotted else None


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
    refresh_policies()
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
        spec = _schema_at(dotted)
        if spec is None:
            raise ConfigError(f"command line: unknown configuration key '{dotted}'")
        if isinstance(spec, dict):  # a nested section given whole (eeg.processing): replaces the files' one
            section: dict[str, Any] = {}
            flag_locs: dict[str, _Loc] = {}
            _merge(section, value, spec, dotted, flag_locs, str(flag_loc))
            locs.update({key: flag_loc for key in flag_locs})  # every key of it was set here
            value = section
        else:
            problem = check_value(value, spec)
            if problem:
                raise ConfigError(f"{flag_loc}: key '{dotted}' {problem}")
        _set_dotted(values, dotted, value)
        locs[f"@{dotted}"] = flag_loc
        digest.update(f"{dotted}={value!r}".encode())
    _validate(values, SCHEMA, "", locs)
    _resolve_input_paths(values, locs)
    _resolve_prior(values, locs)
    _check_combination(values, locs)

    def where(dotted: str) -> _Loc:  # the key's place, else its section's (a relation between two keys)
        while dotted:
            loc = locs.get(f"@{dotted}") or locs.get(dotted)
            if loc is not None:
                return loc
            dotted = dotted.rpartition(".")[0]
        return _Loc("configuration", None)

    try:
        return StudyConfig.build(values, tuple(sources), digest.hexdigest(),
                                 {k: v for k, v in (overrides or {}).items() if v is not None})
    except SettingError as exc:  # a relation between keys (e.g. robot.backoff_max_s >= robot.backoff_initial_s)
        raise ConfigError(f"{where(exc.key)}: {exc}") from None


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


def _resolve_prior(values: dict, locs: dict[str, _Loc]) -> None:
    """``policy.prior`` other than the named priors: a psychometric prior file or a folder of user simulators,
    resolved like the dialogue file (against the folder of the file that sets it) and stored absolute, so a
    resumed session finds it from any folder."""
    prior = values["policy"].get("prior")
    if prior is None or prior in ("clusters", "psychometric"):
        return
    where = locs.get("@policy.prior", _Loc(str(DEFAULT_CONFIG), None))
    given = Path(os.path.expanduser(prior))
    base = Path(where.file).parent if Path(where.file).is_file() else Path.cwd()
    path = Path(os.path.abspath(given if given.is_absolute() else base / given))
    if not (path.is_dir() or (path.is_file() and path.suffix == ".json")):
        whose = "the folder of the file that sets it" if Path(where.file).is_file() else "the current folder"
        rule = "" if given.is_absolute() else f" (a relative path resolves against {base}, {whose})"
        raise ConfigError(f"{where}: key 'policy.prior' must be 'clusters', 'psychometric', a psychometric prior file "
                          f"(*.json) or a folder of user simulator files; {path} is neither{rule}")
    values["policy"]["prior"] = str(path)


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
