"""Study configuration: defaults, overrides, and one-line errors naming file, line and key."""
from __future__ import annotations

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
    ("policy:\n  kind: greedy\n", 2, "policy.kind", "'schedule', 'random', 'personalised' or 'usp:CLUSTER"),
    ("participant_model:\n  success_by_level: [1, 1, 1]\n", 2, "participant_model.success_by_level", "4 values"),
    ("participant_model:\n  success_by_level: [1, 1, 1, 1.5]\n", 2, "participant_model.success_by_level", "[0, 1]"),
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
    with pytest.raises(ConfigError, match=rf"{path}:5: eeg.processing.ewma: unknown key"):
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
