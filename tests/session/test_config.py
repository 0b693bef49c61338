"""Study configuration: defaults, overrides, and one-line errors naming file, line and key."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from nao_trainer.session.config import DEFAULT_CONFIG, SCHEMA, load_config
from nao_trainer.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]


def study(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "study.yaml"
    path.write_text(text)
    return path


def test_shipped_studies_load_and_override_defaults():
    demo = load_config()
    assert demo.participant.pseudonym == "demo" and demo.session.turns == 25
    assert demo.timing.speed > 1 and demo.robot.url == "mock"
    assert demo.response_timeout_s(3) == pytest.approx(10 + 2.5 * 3)
    paper = load_config(ROOT / "config" / "studies" / "paper-2018.yaml")
    assert paper.answers.input == "tactile" and paper.eeg.mode == "lsl"
    assert paper.timing.speed == 1.0 and paper.session.turns == 25
    assert demo.text_sha256 != paper.text_sha256 and len(demo.sources) == 2


def test_every_schema_key_is_documented_in_the_default_file():
    text = DEFAULT_CONFIG.read_text()
    for section, keys in SCHEMA.items():
        for key in keys:
            line = next((ln for ln in text.splitlines() if ln.strip().startswith(f"{key}:")), None)
            assert line is not None, f"{section}.{key} missing from default.yaml"
    # every key line of default.yaml carries a comment (on the line or just above)
    lines = text.splitlines()
    for i, ln in enumerate(lines):
        if ln.startswith("  ") and ":" in ln and not ln.strip().startswith("#"):
            assert "#" in ln or lines[i - 1].strip().startswith("#"), f"undocumented: {ln}"


def test_unknown_key_names_file_line_and_suggests(tmp_path):
    path = study(tmp_path, "session:\n  turns: 10\n  tunrs: 5\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert f"{path}:3" in msg and "session.tunrs" in msg and "did you mean 'session.turns'" in msg
    assert "\n" not in msg


def test_a_key_with_a_newline_is_echoed_escaped_on_one_line(tmp_path):
    """Issue 17: 1 of 1000 fuzzed configs echoed a key with a newline raw (a two-line error)."""
    with pytest.raises(ConfigError) as err:
        load_config(study(tmp_path, '"ses\\nsion": {turns: 3}\n'))
    msg = str(err.value)
    assert "\n" not in msg and "unknown key 'ses\\nsion'" in msg and "did you mean 'session'" in msg


def test_unknown_section(tmp_path):
    with pytest.raises(ConfigError, match=r"study.yaml:2: unknown key 'robto'.*did you mean 'robot'"):
        load_config(study(tmp_path, "# x\nrobto:\n  url: mock\n"))


@pytest.mark.parametrize("text, line, key, words", [
    ("timing:\n  speed: fast\n", 2, "timing.speed", "must be a number"),
    ("session:\n  turns: 0\n", 2, "session.turns", ">= 1"),
    ("session:\n  turns: 2.5\n", 2, "session.turns", "must be an integer"),
    ("answers:\n  input: mouse\n", 2, "answers.input", "must be one of simulated, tactile, keyboard"),
    ("robot:\n  url: tcps://nao:secret@10.0.0.2:9503\n", 2, "robot.url", "NAO_USER and NAO_PASSWORD"),
    ("robot:\n  url: http://10.0.0.2\n", 2, "robot.url", "tcp://HOST:9559"),
    ("policy:\n  schedule: [RF1, L2]\n", 2, "policy.schedule", "must start with a level action"),
    ("policy:\n  kind: greedy\n", 2, "policy.kind", "must be one of bayes | personalised | random | schedule | usp:CLUSTER[:METHOD]"),
    ("policy:\n  prior: no/such/folder\n", 2, "policy.prior", "must be 'clusters', 'psychometric', a psychometric"),
    ("participant_model:\n  success_by_level: [1, 1, 1]\n", 2, "participant_model.success_by_level", "4 values"),
    ("participant_model:\n  success_by_level: [1, 1, 1, 1.5]\n", 2, "participant_model.success_by_level", "[0, 1]"),
    ("policy:\n  assessment: [9, 9]\n", 2, "policy.assessment", "must list levels 1..4, at most 12 turns"),
    ("eeg:\n  required: yes please\n", 2, "eeg.required", "true/false"),
    ("eeg:\n  mode: lsl\n  lsl_scope: universe\n", 3, "eeg.lsl_scope", "machine"),
    ("participant:\n  pseudonym: John Smith\n", 2, "participant.pseudonym", "never a real name"),
    ("eeg:\n  mode: lsl\n  stream_name: \"Muse's\"\n", 3, "eeg.stream_name", "must not contain a quote"),
    ("eeg:\n  source_id: \"Muse'00\"\n", 2, "eeg.source_id", "must not contain a quote"),
    ("eeg:\n  stream_type: \"EEG'\"\n", 2, "eeg.stream_type", "must not contain a quote"),
])
def test_bad_values_name_file_line_key(tmp_path, text, line, key, words):
    path = study(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}:{line}:"), msg
    assert f"'{key}'" in msg and words in msg


def test_eeg_processing_is_checked_by_the_monitor_at_load(tmp_path):
    cfg = load_config(study(tmp_path, "eeg:\n  processing:\n    ewma_a: 0.9\n    window_s: 1.0\n"))
    assert cfg.values["eeg"]["processing"] == {"ewma_a": 0.9, "window_s": 1.0}
    assert cfg.eeg.processing.ewma_a == 0.9 and cfg.eeg.processing.window_s == 1.0  # typed, for the monitor
    path = study(tmp_path, "eeg:\n  mode: simulated\n  processing:\n    window_s: 1.0\n    ewma: 0.1\n")
    # one message style for every section, eeg.processing included (core.settings)
    with pytest.raises(ConfigError, match=rf"{path}:5: unknown key 'eeg.processing.ewma'; did you mean 'eeg.processing.ewma_a'"):
        load_config(path)


def test_yaml_syntax_error_has_a_line(tmp_path):
    with pytest.raises(ConfigError, match=r"study.yaml:3: not valid YAML"):
        load_config(study(tmp_path, "session:\n  turns: 3\n   seed: 4\n"))


def test_missing_file_is_a_user_error(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "nope.yaml")


def test_overrides_win_and_are_validated(tmp_path):
    cfg = load_config(None, {"session.turns": 3, "timing.speed": 40, "robot.url": None})
    assert cfg.session.turns == 3 and cfg.timing.speed == 40.0 and isinstance(cfg.timing.speed, float)
    assert cfg.robot.url == "mock"  # None = flag not given
    with pytest.raises(ConfigError, match=r"command line \(session.turns\): key 'session.turns' must be >= 1"):
        load_config(None, {"session.turns": -2})
    assert load_config(None, {"session.turns": 3}).text_sha256 != load_config(None, {"session.turns": 4}).text_sha256


def test_relative_output_resolves_against_current_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert load_config().output_dir() == tmp_path / "sessions"
    assert load_config().session.dialogue_path == ROOT / "dialogue" / "en.yaml"


def test_sections_are_frozen_dataclasses_matching_the_schema():
    import dataclasses

    cfg = load_config()
    for name, keys in SCHEMA.items():
        section = getattr(cfg, name)
        assert dataclasses.is_dataclass(section)
        assert [f.name for f in dataclasses.fields(section)] == list(keys)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.timing.speed = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.eeg.processing.window_s = 2.0
    assert cfg.policy.schedule == tuple(cfg.values["policy"]["schedule"])
    assert cfg.snapshot()["values"]["session"]["turns"] == cfg.session.turns


def _float_settings() -> list[str]:
    return [f"{section}.{key}" for section, keys in SCHEMA.items() for key, spec in keys.items()
            if not isinstance(spec, dict) and isinstance(spec.kind, tuple) and float in spec.kind]


@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_nan_and_infinity_are_refused_for_every_float_setting(tmp_path, value):
    keys = _float_settings()
    assert len(keys) >= 14
    for dotted in keys:
        section, key = dotted.split(".")
        path = study(tmp_path, f"study: {{name: x}}\n{section}:\n  {key}: {value}\n")
        with pytest.raises(ConfigError, match=rf"study.yaml:3: key '{dotted}' must be a finite number"):
            load_config(path)


@pytest.mark.parametrize("text, line, key", [
    ("eeg:\n  processing:\n    hop_s: " + "9" * 400 + "\n", 3, "eeg.processing.hop_s"),
    ("eeg:\n  processing: {window_s: " + "9" * 400 + "}\n", 2, "eeg.processing.window_s"),
    ("session:\n  seed: " + "9" * 400 + "\n", 2, "session.seed"),
    ("participant_model:\n  success_by_level: [0.5, 0.5, " + "9" * 400 + ", 0.5]\n", 2, "participant_model.success_by_level"),
])
def test_huge_integers_are_refused_not_overflowed(tmp_path, text, line, key):
    with pytest.raises(ConfigError, match=rf"study.yaml:{line}: .*{key}.*sensible size, got one with 400 digits"):
        load_config(study(tmp_path, text))


@pytest.mark.parametrize("key", ["session.dialogue", "session.behaviors", "session.output", "policy.state_path"])
@pytest.mark.parametrize("value, code", [('"a\\0b"', "U+0000"), ('"\\ud800"', "U+D800"), ('"x\\udfffy"', "U+DFFF")])
def test_nul_and_lone_surrogates_in_paths_are_refused(tmp_path, key, value, code):
    section, name = key.split(".")
    path = study(tmp_path, f"{section}:\n  {name}: {value}\n")
    # libyaml's parser (PyYAML's C loader, which files.read_yaml uses where installed) refuses a surrogate escape
    # itself; the pure-Python parser reads it and the key's check refuses it: one line naming the file and line
    ours = rf"key '{key}' must not contain control characters or invalid Unicode \(found {re.escape(code)}\)"
    libyaml = r"not valid YAML \(found invalid Unicode character escape code\); fix the syntax"
    with pytest.raises(ConfigError, match=rf"study.yaml:2: ({ours}|{libyaml})" if code != "U+0000" else rf"study.yaml:2: {ours}"):
        load_config(path)


@pytest.mark.parametrize("text", ["", "\n", "# a comment only\n", "---\n"])
def test_an_empty_study_file_is_refused(tmp_path, text):
    with pytest.raises(ConfigError, match=r"study.yaml: the file is empty"):
        load_config(study(tmp_path, text))


def test_file_values_are_validated_even_when_a_flag_overrides_them(tmp_path):
    path = study(tmp_path, 'session:\n  turns: "five"\n')
    with pytest.raises(ConfigError, match=r"study.yaml:2: key 'session.turns' must be an integer, got 'five'"):
        load_config(path, {"session.turns": 3})
    with pytest.raises(ConfigError, match=r"command line \(timing.speed\): key 'timing.speed' must be a finite number"):
        load_config(None, {"timing.speed": float("nan")})


def test_a_repeated_section_is_refused_instead_of_dropping_settings(tmp_path):
    path = study(tmp_path, "eeg:\n  mode: lsl\n  required: true\nsession:\n  turns: 3\neeg:\n  mode: lsl\n")
    with pytest.raises(ConfigError, match=r"study.yaml:6: key 'eeg' is given twice \(first on line 1\)"):
        load_config(path)


@pytest.mark.parametrize("url, words", [("tcp://10.0.0.5:99999", "port 99999, out of range 1..65535"),
                                        ("tcp://10.0.0.5:0", "port 0, out of range")])
def test_a_robot_port_out_of_range_is_refused_at_load(tmp_path, url, words):
    with pytest.raises(ConfigError, match=rf"study.yaml:2: key 'robot.url' has {words}"):
        load_config(study(tmp_path, f"robot:\n  url: {url}\n"))


@pytest.mark.parametrize("url", ["10.0.0.5", "tcp://nao.local", "tcps://[fe80::1]:9503", "[::1]:9559"])
def test_the_config_accepts_every_address_the_robot_client_accepts(tmp_path, url):
    from nao_trainer.robot.address import normalize_url
    normalize_url(url)  # the client takes it ...
    assert load_config(study(tmp_path, f"robot:\n  url: '{url}'\n")).robot.url == url  # ... and so does the config


def test_a_password_in_the_robot_address_is_not_echoed(tmp_path):
    with pytest.raises(ConfigError) as err:
        load_config(study(tmp_path, "robot:\n  url: tcps://nao:s3cret@10.0.0.2:9503\n"))
    assert "s3cret" not in str(err.value) and "NAO_PASSWORD" in str(err.value)


def test_default_file_matches_the_section_dataclasses_key_for_key():
    """config/default.yaml against the one declaration of each key (the section dataclasses)."""
    from nao_trainer.core.settings import Rule, check_value
    from nao_trainer.files import read_yaml
    from nao_trainer.session.config import OPTIONAL, SECTIONS

    data = read_yaml(DEFAULT_CONFIG, fix="")[0]
    assert list(data) == list(SECTIONS)  # same sections, same order

    def walk(node: dict, schema: dict, prefix: str) -> None:
        for key, spec in schema.items():
            dotted = f"{prefix}.{key}"
            if isinstance(spec, dict):
                walk(node.get(key) or {}, spec, dotted)
                continue
            assert isinstance(spec, Rule) and spec.doc, f"{dotted}: declared without a rule and a doc line"
            if dotted in OPTIONAL and key not in node:
                continue
            assert key in node, f"{dotted} is declared but missing from default.yaml"
            assert check_value(node[key], spec) is None, f"{dotted}: default.yaml's value breaks its rule"
        undeclared = set(node) - set(schema)
        assert not undeclared, f"{prefix}: default.yaml has undeclared keys {sorted(undeclared)}"

    for name, keys in SCHEMA.items():
        walk(data[name], keys, name)


def test_a_relation_between_keys_names_the_key_and_its_line(tmp_path):
    path = study(tmp_path, "robot:\n  backoff_initial_s: 5\n  backoff_max_s: 1\n")
    with pytest.raises(ConfigError, match=rf"{path}:3: key 'robot.backoff_max_s' must be >= robot.backoff_initial_s"):
        load_config(path)
    path = study(tmp_path, "eeg:\n  processing:\n    window_s: 1.0\n    hop_s: 2.0\n")
    with pytest.raises(ConfigError, match=rf"{path}:4: key 'eeg.processing.hop_s' must not exceed window_s"):
        load_config(path)
    with pytest.raises(ConfigError, match=r"command line \(eeg.mode\): key 'eeg.mode' must be one of off, simulated, lsl"):
        load_config(None, {"eeg.mode": "bluetooth"})


def test_a_nested_section_given_whole_on_the_command_line_is_checked_key_by_key():
    cfg = load_config(None, {"eeg.processing": {"window_s": 1.0}})
    assert cfg.eeg.processing.window_s == 1.0 and cfg.values["eeg"]["processing"] == {"window_s": 1.0}
    with pytest.raises(ConfigError, match=r"^command line \(eeg.processing\): unknown key 'eeg.processing.windw'"):
        load_config(None, {"eeg.processing": {"windw": 1}})
    with pytest.raises(ConfigError, match=r"^command line \(eeg.processing\): key 'eeg.processing.hop_s' must not exceed"):
        load_config(None, {"eeg.processing": {"hop_s": 9.0}})


def test_policy_prior_path_resolves_against_the_file_that_sets_it(tmp_path, monkeypatch):
    (tmp_path / "users").mkdir()
    path = study(tmp_path, "policy:\n  kind: bayes\n  prior: users\n")
    monkeypatch.chdir(tmp_path.parent)  # not the study's folder: the path is the file's
    assert load_config(path).policy.prior == str(path.parent / "users")
    assert load_config(path, {"policy.prior": "psychometric"}).policy.prior == "psychometric"
    assert load_config(path, {"policy.prior": None}).policy.prior == str(path.parent / "users")
    with pytest.raises(ConfigError, match=r"^command line \(policy.prior\): key 'policy.prior' .* is neither "
                                          r"\(a relative path resolves against .*, the current folder\)$"):
        load_config(path, {"policy.prior": "users"})
