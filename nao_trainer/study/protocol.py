"""A study protocol: arms, sessions, allocation, blinding, outcomes and the analysis, fixed before the data.

A protocol is a YAML file (``config/protocols/example-3arm.yaml`` documents every key) validated once, at
load, into frozen dataclasses; every error is one line ``file:line: key 'x': what; how to fix``. Each arm
is a policy plus dotted overrides of the study configuration it starts from (``study_config``); every arm's
configuration is loaded through ``session.config.load_config`` here, so an arm that could not run is
refused before any participant is enrolled.

Balance: blocked randomisation draws each block as a random permutation of the arms repeated
``ratio`` times; a block must therefore hold a whole number of rounds (``block_size`` a multiple of the
sum of the ratios), and ``target_n`` must give every arm at least one participant whatever the draw
(at least ``block_size`` minus the smallest arm's places in a block, plus one).
"""
from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nao_trainer.errors import ConfigError
from nao_trainer.files import read_yaml
from nao_trainer.session.config import SCHEMA, StudyConfig, check_value, load_config
from nao_trainer.study.names import name_problem

#: Outcomes per session the analysis knows; ``span``: the length at the study's rate (``data.study``).
OUTCOMES: tuple[str, ...] = ("score", "engagement", "success_rate", "span")
#: The outcomes the power simulation plays (``study.power``); a span needs a posterior per session.
SIMULATED_OUTCOMES: tuple[str, ...] = ("score", "engagement", "success_rate")
#: Fixed effects a model may name besides the intercept.
TERMS: tuple[str, ...] = ("arm", "session")
_MODEL = re.compile(r"^\s*(\w+)\s*~\s*(.+?)\s*\+\s*\(\s*1\s*\|\s*participant\s*\)\s*$")
_KEYS = {"protocol", "study_config", "arms", "sessions", "target_n", "allocation", "blinding", "outcomes",
         "analysis", "pseudonym_prefix"}


@dataclass(frozen=True)
class Arm:
    name: str
    policy: str
    overrides: tuple[tuple[str, Any], ...]  # dotted study-configuration keys, in file order
    ratio: int  # allocation weight within a block

    def config_overrides(self) -> dict[str, Any]:
        return {"policy.kind": self.policy, **dict(self.overrides)}


@dataclass(frozen=True)
class Sessions:
    per_participant: int
    min_days: float
    max_days: float


@dataclass(frozen=True)
class Stratum:
    name: str
    levels: tuple[str, ...]


@dataclass(frozen=True)
class Allocation:
    block_size: int
    seed: int | None  # not used to allocate (see _allocation)
    strata: tuple[Stratum, ...]

    def stratum_keys(self) -> list[str]:
        """Every combination of stratum levels, as ``"age=young,sex=f"`` ("" without strata)."""
        keys = [""]
        for s in self.strata:
            keys = [",".join(filter(None, (k, f"{s.name}={lv}"))) for k in keys for lv in s.levels]
        return keys


#: How the analysis treats what is missing (``analysis.missing``), named in the protocol before the data:
#: ``observed-sessions``: intention to treat, every randomised participant in the arm allocated; a session
#: not completed is missing at random given the arm and the participant's other sessions (the mixed model's
#: likelihood, no imputation); a participant with no completed session is counted as randomised and
#: reported per arm, and contributes no outcome.
MISSING_RULES: tuple[str, ...] = ("observed-sessions",)
#: Residual variance structure (``analysis.variance``): ``arm`` = each arm its own (the default, Welch-type
#: tests with Satterthwaite's df), ``pooled`` = one for all arms (the former model, kept to reproduce it).
VARIANCES: tuple[str, ...] = ("arm", "pooled")
#: Outcomes the policy sets (the difficulty it chooses decides them): a manipulation check, never primary.
POLICY_SET: tuple[str, ...] = ("success_rate",)


@dataclass(frozen=True)
class Analysis:
    model: str  # as written, e.g. "outcome ~ arm + session + (1|participant)"
    terms: tuple[str, ...]  # fixed effects in the model (arm, session)
    reference_arm: str
    alpha: float
    primary_contrast: str = ""  # the arm compared with reference_arm on the primary outcome (tested at alpha)
    variance: str = "arm"
    multiplicity: str = "holm"  # every test but the primary one: Holm's step-down adjustment
    missing: str = "observed-sessions"
    baseline_covariate: bool = False  # session 1's outcome as a covariate of the later sessions


@dataclass(frozen=True)
class Protocol:
    name: str
    description: str
    study_config: Path
    arms: tuple[Arm, ...]
    sessions: Sessions
    target_n: int
    allocation: Allocation
    blinding: bool
    primary: str
    secondary: tuple[str, ...]
    analysis: Analysis
    pseudonym_prefix: str
    source: str
    text: str
    base: str = ""  # the folder a relative study_config resolved against (the registry records it)

    @property
    def sha256(self) -> str:
        return protocol_hash(self.text)

    @property
    def outcomes(self) -> tuple[str, ...]:
        return (self.primary, *self.secondary)

    def arm(self, name: str) -> Arm:
        return next(a for a in self.arms if a.name == name)

    def arm_config(self, arm: Arm, extra: dict[str, Any] | None = None) -> StudyConfig:
        """The study configuration one arm runs with (``extra``: the session's own keys and run flags)."""
        return load_config(self.study_config, {**arm.config_overrides(), **(extra or {})})


def protocol_hash(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class _Where:
    """file:line of dotted keys, for one-line errors."""

    def __init__(self, path: Path, lines: dict[str, int]) -> None:
        self.path, self.lines = path, lines

    def error(self, key: str, problem: str) -> ConfigError:
        line = self.lines.get(key)
        while line is None and "." in key:
            key_up = key.rsplit(".", 1)[0]
            line, key = self.lines.get(key_up), key_up
        return ConfigError(f"{self.path}{f':{line}' if line else ''}: key '{key}': {problem}")


def _get(d: Any, key: str, where: _Where, dotted: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
    if not isinstance(d, dict) or key not in d:
        if default is ...:
            raise where.error(dotted, "is missing; add it (see config/protocols/example-3arm.yaml)")
        return default
    value = d[key]
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
        raise where.error(dotted, f"must be {getattr(kind, '__name__', kind)}, got {value!r}")
    return value


def load_protocol(path: str | os.PathLike, base: Path | None = None, fallback: Path | None = None) -> Protocol:
    """Read and validate a protocol file; ``ConfigError`` (one line, file:line) for the first problem.

    ``base``: the folder a relative ``study_config`` resolves against (default: the protocol's own folder;
    a study folder's frozen copy passes the folder of the file it was copied from). ``fallback``: a second
    folder tried when the first holds no such file (``study amend``: the study's own, so that an edited copy
    of ``protocol.yaml`` resolves as the frozen copy does, wherever the copy lives).
    """
    path = Path(os.path.abspath(os.path.expanduser(path)))
    data, lines, text = read_yaml(path, fix="give a protocol file (see config/protocols/example-3arm.yaml)")
    where = _Where(path, lines)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a protocol is a mapping of keys (see config/protocols/example-3arm.yaml)")
    for key in data:
        if key not in _KEYS:
            raise where.error(str(key), f"unknown key; valid keys: {', '.join(sorted(_KEYS))}")
    head = _get(data, "protocol", where, "protocol", dict)
    name = _get(head, "name", where, "protocol.name", str)
    if name_problem(name, "name"):
        raise where.error("protocol.name", f"{name!r} must be {name_problem(name, 'name')}")
    description = _get(head, "description", where, "protocol.description", str, "")
    given = Path(_get(data, "study_config", where, "study_config", str)).expanduser()
    folders = [Path(base or path.parent)] + ([Path(fallback)] if fallback is not None and not given.is_absolute()
                                            and Path(fallback).resolve() != Path(base or path.parent).resolve()
                                            else [])
    tried = [given if given.is_absolute() else (folder / given).resolve() for folder in folders]
    found = next((i for i, c in enumerate(tried) if c.is_file()), None)
    if found is None:
        where_ = (f"relative paths resolve against the protocol's folder, then the study's {folders[1]}"
                  if len(folders) > 1 else "relative paths resolve against the protocol's folder")
        raise where.error("study_config", f"{' nor '.join(str(c) for c in tried)} is not a file ({where_}); "
                                          "fix the path")
    config_path, resolved_in = tried[found], folders[found]
    arms = _arms(_get(data, "arms", where, "arms", list), where)
    s = _get(data, "sessions", where, "sessions", dict)
    per = _get(s, "per_participant", where, "sessions.per_participant", int)
    if per < 1:
        raise where.error("sessions.per_participant", f"must be >= 1, got {per}")
    interval = _get(s, "interval_days", where, "sessions.interval_days", dict)
    lo = _get(interval, "min", where, "sessions.interval_days.min", float)
    hi = _get(interval, "max", where, "sessions.interval_days.max", float)
    if not 0 <= lo <= hi:
        raise where.error("sessions.interval_days", f"needs 0 <= min <= max, got min {lo}, max {hi}")
    target = _get(data, "target_n", where, "target_n", int)
    allocation = _allocation(_get(data, "allocation", where, "allocation", dict), where)
    _check_balance(arms, allocation, target, where)
    blinding = _get(data, "blinding", where, "blinding", bool)
    outcomes = _get(data, "outcomes", where, "outcomes", dict)
    primary = _get(outcomes, "primary", where, "outcomes.primary", str)
    secondary = tuple(_get(outcomes, "secondary", where, "outcomes.secondary", list, []))
    for i, o in enumerate((primary, *secondary)):
        if o not in OUTCOMES:
            raise where.error("outcomes.primary" if i == 0 else "outcomes.secondary",
                              f"unknown outcome {o!r}; use one of {', '.join(OUTCOMES)}")
    if primary in POLICY_SET:
        raise where.error("outcomes.primary", f"{primary!r} is set by the policy (the difficulty it chooses), so it "
                                              "measures the policy, not a benefit; keep it as a secondary outcome "
                                              "(a manipulation check) and make span or score primary")
    analysis = _analysis(_get(data, "analysis", where, "analysis", dict), where, arms)
    prefix = _get(data, "pseudonym_prefix", where, "pseudonym_prefix", str, "P")
    if name_problem(prefix):
        raise where.error("pseudonym_prefix", f"{prefix!r} must be {name_problem(prefix)}")
    protocol = Protocol(name, description, config_path, arms, Sessions(per, lo, hi), target, allocation, blinding,
                        primary, secondary, analysis, prefix, str(path), text, str(resolved_in))
    for i, arm in enumerate(arms):  # every arm's configuration must load (overrides, policy, files)
        try:
            protocol.arm_config(arm)
        except ConfigError as exc:
            raise where.error(f"arms[{i}]", f"arm {arm.name!r} does not load: {exc}") from None
    return protocol


def _arms(items: list, where: _Where) -> tuple[Arm, ...]:
    arms = []
    for i, item in enumerate(items):
        key = f"arms[{i}]"
        if not isinstance(item, dict):
            raise where.error("arms", f"arm {i + 1} must be a mapping with name and policy")
        unknown = set(item) - {"name", "policy", "overrides", "ratio"}
        if unknown:
            raise where.error("arms", f"arm {i + 1}: unknown key(s) {', '.join(sorted(unknown))}; "
                                      "valid: name, policy, overrides, ratio")
        name = _get(item, "name", where, key, str)
        if name_problem(name):
            raise where.error("arms", f"arm name {name!r} must be {name_problem(name)} (it becomes a BIDS label)")
        policy = _get(item, "policy", where, key, str)
        problem = check_value(policy, SCHEMA["policy"]["kind"])
        if problem:
            raise where.error("arms", f"arm {name!r}: unknown policy {policy!r}: {problem}")
        overrides = _get(item, "overrides", where, key, dict, {})
        for k in overrides:
            section, _, sub = str(k).partition(".")
            if section not in SCHEMA or sub not in SCHEMA[section]:
                raise where.error("arms", f"arm {name!r}: override {k!r} is not a study configuration key "
                                          "(SECTION.KEY, see config/default.yaml)")
            if k in ("policy.kind", "participant.pseudonym", "session.output"):
                raise where.error("arms", f"arm {name!r}: override {k!r} is set by the study itself; remove it")
        ratio = _get(item, "ratio", where, key, int, 1)
        if ratio < 1:
            raise where.error("arms", f"arm {name!r}: ratio {ratio}: an arm with no participants possible; "
                                      "give ratio >= 1 or remove the arm")
        arms.append(Arm(name, policy, tuple(overrides.items()), ratio))
    if len(arms) < 2:
        raise where.error("arms", f"a controlled study needs at least 2 arms, got {len(arms)}")
    names = [a.name for a in arms]
    if len(set(names)) != len(names):
        raise where.error("arms", f"arm names must differ, got {names}")
    return tuple(arms)


def _allocation(a: dict, where: _Where) -> Allocation:
    method = _get(a, "method", where, "allocation.method", str, "blocked")
    if method != "blocked":
        raise where.error("allocation.method", f"{method!r}: only 'blocked' randomisation is supported")
    size = _get(a, "block_size", where, "allocation.block_size", int)
    # Not used to allocate (study init draws the seed from the operating system's entropy, or takes one
    # supplied by a third party): a seed in a protocol anyone can read would reveal the sequence.
    seed = _get(a, "seed", where, "allocation.seed", int, None)
    strata = []
    for name, levels in _get(a, "strata", where, "allocation.strata", dict, {}).items():
        if not isinstance(levels, list) or len(levels) < 2 or not all(isinstance(v, str) and v for v in levels):
            raise where.error(f"allocation.strata.{name}", "must list at least 2 levels (strings)")
        strata.append(Stratum(str(name), tuple(levels)))
    return Allocation(size, seed, tuple(strata))


def _check_balance(arms: tuple[Arm, ...], allocation: Allocation, target: int, where: _Where) -> None:
    round_size = sum(a.ratio for a in arms)
    if allocation.block_size < round_size or allocation.block_size % round_size:
        raise where.error("allocation.block_size", f"{allocation.block_size} cannot balance {len(arms)} arms with "
                                                   f"ratios {[a.ratio for a in arms]}: use a multiple of {round_size}")
    # The first block may put all of the smallest arm's places last: it is sure of a participant only when
    # target_n reaches past the block's other places.
    need = allocation.block_size - min(a.ratio for a in arms) * (allocation.block_size // round_size) + 1
    if target < need:
        raise where.error("target_n", f"{target} participants leave an arm with no participants possible (blocks of "
                                      f"{allocation.block_size}); give at least {need}, or a smaller block size")


def _analysis(a: dict, where: _Where, arms: tuple[Arm, ...]) -> Analysis:
    model = _get(a, "model", where, "analysis.model", str)
    m = _MODEL.match(model)
    fix = "write it as 'outcome ~ arm + session + (1|participant)'"
    if not m or m.group(1) != "outcome":
        raise where.error("analysis.model", f"{model!r} is not a model this analysis fits; {fix}")
    terms = tuple(t.strip() for t in m.group(2).split("+"))
    if "arm" not in terms or any(t not in TERMS for t in terms) or len(set(terms)) != len(terms):
        raise where.error("analysis.model", f"fixed effects {terms}: use arm and optionally session; {fix}")
    ref = _get(a, "reference_arm", where, "analysis.reference_arm", str, arms[0].name)
    if ref not in [x.name for x in arms]:
        raise where.error("analysis.reference_arm", f"{ref!r} is not an arm; use one of "
                                                    f"{', '.join(x.name for x in arms)}")
    alpha = _get(a, "alpha", where, "analysis.alpha", float, 0.05)
    if not 0 < alpha < 0.5:
        raise where.error("analysis.alpha", f"{alpha} must be in (0, 0.5)")
    others = [x.name for x in arms if x.name != ref]
    contrast = _get(a, "primary_contrast", where, "analysis.primary_contrast", str, others[0] if others else "")
    if contrast not in others:
        raise where.error("analysis.primary_contrast", f"{contrast!r} is not an arm other than the reference "
                                                       f"{ref!r}; use one of {', '.join(others)}")
    variance = _get(a, "variance", where, "analysis.variance", str, "arm")
    if variance not in VARIANCES:
        raise where.error("analysis.variance", f"{variance!r}: use arm (each arm its own residual variance) or pooled")
    multiplicity = _get(a, "multiplicity", where, "analysis.multiplicity", str, "holm")
    if multiplicity != "holm":
        raise where.error("analysis.multiplicity", f"{multiplicity!r}: the analysis adjusts the non-primary tests "
                                                   "by holm")
    missing = _get(a, "missing", where, "analysis.missing", str, "observed-sessions")
    if missing not in MISSING_RULES:
        raise where.error("analysis.missing", f"{missing!r}: use {', '.join(MISSING_RULES)}")
    baseline = _get(a, "baseline_covariate", where, "analysis.baseline_covariate", bool, False)
    if baseline and "session" not in terms:
        raise where.error("analysis.baseline_covariate", "needs the session term (session 1 is the baseline)")
    return Analysis(model, terms, ref, alpha, contrast, variance, multiplicity, missing, baseline)
