"""Dialogue and behavior files: shipped ones are complete; broken ones are refused at load."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nao_trainer.session import behaviors as beh
from nao_trainer.session import dialogue as dia
from nao_trainer.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
EN = ROOT / "dialogue" / "en.yaml"


def test_english_dialogue_has_every_event_with_variants():
    d = dia.load_dialogue(EN)
    assert set(d.variants) == set(dia.EVENTS)
    for kind in ("encouraging", "challenging"):
        for outcome in ("success", "failure"):
            assert len(d.variants[f"{kind}_{outcome}"]) >= 3
    assert d.say("level", np.random.default_rng(0), level=3, length=7) == "Level 3."
    assert "17 points" in d.say("goodbye", np.random.default_rng(0), total=17, turns=25)


def test_variants_are_picked_with_the_seeded_generator():
    d = dia.load_dialogue(EN)
    pick = lambda seed: [d.feedback(1, False, np.random.default_rng(seed)) for _ in range(1)][0]
    assert pick(5) == pick(5)
    seen = {d.feedback(2, True, np.random.default_rng(s)) for s in range(30)}
    assert seen == set(d.variants["challenging_success"])
    assert d.feedback(1, True, np.random.default_rng(1)) in d.variants["encouraging_success"]
    assert d.feedback(2, False, np.random.default_rng(1)) in d.variants["challenging_failure"]


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "d.yaml"
    p.write_text(text)
    return p


def test_unknown_placeholder_is_refused_with_line(tmp_path):
    text = EN.read_text().replace('"Level {level}."', '"Level {levle}."')
    line = next(i for i, ln in enumerate(text.splitlines(), 1) if ln.startswith("level:"))
    with pytest.raises(ConfigError, match=rf"d.yaml:{line}: event 'level' uses unknown placeholder {{levle}}; allowed: {{length}}, {{level}}"):
        dia.load_dialogue(write(tmp_path, text))


def test_missing_event_and_empty_variant_are_refused(tmp_path):
    text = EN.read_text()
    cut = text[: text.index("goodbye:")]
    with pytest.raises(ConfigError, match="event 'goodbye' is missing"):
        dia.load_dialogue(write(tmp_path, cut))
    with pytest.raises(ConfigError, match="event 'paused' has an empty"):
        dia.load_dialogue(write(tmp_path, text.replace('"Sorry, I need a short break. Please wait a moment."', '""')))
    with pytest.raises(ConfigError, match="unknown event 'farewell'"):
        dia.load_dialogue(write(tmp_path, text + "farewell:\n  - bye\n"))


def test_default_behaviors_cover_every_event():
    b = beh.load_behaviors(ROOT / "behaviors" / "default.yaml")
    assert set(b.events) == set(beh.EVENTS)
    assert b.start_posture == "Stand" and b.safe_posture in beh.SAFE_POSTURES
    assert b["paused"].leds == 0xFF0000 and b["greeting"].animated and not b["sequence"].animated


@pytest.mark.parametrize("old, new, words", [
    ('leds: "#FF0000"', 'leds: "red"', "events.paused.leds' must be a colour"),
    ("safe: Crouch", "safe: Stand", "'postures.safe' must be one of Crouch, Sit, SitRelax"),
    ("goodbye:  ", "farewell: ", "unknown event 'farewell'"),
    ("mode: contextual}\n  instructions", "mode: wild}\n  instructions", "'events.greeting.mode' must be one of"),
])
def test_bad_behaviors_are_refused(tmp_path, old, new, words):
    text = (ROOT / "behaviors" / "default.yaml").read_text()
    assert old in text
    p = tmp_path / "b.yaml"
    p.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        beh.load_behaviors(p)
    assert words in str(err.value) and str(p) in str(err.value)


@pytest.mark.parametrize("loader", [dia.load_dialogue, beh.load_behaviors], ids=["dialogue", "behaviors"])
def test_a_folder_or_binary_file_is_a_one_line_error(tmp_path, loader):
    with pytest.raises(ConfigError, match=r"cannot read \(Is a directory\); fix session\."):
        loader(tmp_path)
    binary = tmp_path / "x.yaml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ConfigError, match="not a text file"):
        loader(binary)


@pytest.mark.parametrize("bad, words", [
    ('"Level {level."', "broken placeholder"),
    ('"Level }."', "broken placeholder"),
    ('"Level {level!x}."', "cannot be filled"),
    ('"Level {level:q}."', "cannot be filled"),
    ('"Level {level:%}{length:.2s}."', "cannot be filled"),
])
def test_a_placeholder_that_cannot_be_filled_is_refused_at_load(tmp_path, bad, words):
    text = EN.read_text().replace('"Level {level}."', bad)
    line = next(i for i, ln in enumerate(text.splitlines(), 1) if ln.startswith("level:"))
    with pytest.raises(ConfigError, match=rf"d.yaml:{line}: event 'level' has a") as err:
        dia.load_dialogue(write(tmp_path, text))
    assert words in str(err.value) and "\n" not in str(err.value)


def test_format_specs_that_fit_the_values_are_accepted(tmp_path):
    text = EN.read_text().replace('"Level {level}."', '"Level {level:d} ({length:>2}), {{x}}."')
    d = dia.load_dialogue(write(tmp_path, text))
    assert d.say("level", np.random.default_rng(0), level=3, length=7) == "Level 3 ( 7), {x}."


@pytest.mark.parametrize("value", ["[Stand, Crouch, Crouch]", "Stand"])
def test_postures_that_are_not_a_mapping_are_refused(tmp_path, value):
    text = (ROOT / "behaviors" / "default.yaml").read_text()
    start = text.index("postures:")
    end = text.index("\n", text.index("safe:", start))
    p = tmp_path / "b.yaml"
    p.write_text(text[:start] + f"postures: {value}" + text[end:])
    line = next(i for i, ln in enumerate(p.read_text().splitlines(), 1) if ln.startswith("postures:"))
    with pytest.raises(ConfigError, match=rf"b.yaml:{line}: key 'postures' must be a mapping"):
        beh.load_behaviors(p)
