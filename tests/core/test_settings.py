"""core.settings: one declaration per key (the dataclass field), one validator, one message style."""
from __future__ import annotations

import dataclasses

import pytest

from nao_trainer.core.settings import (SettingError, UnknownKey, build, check_value, optional_keys, schema_of, setting,
                                       settings, Rule)


@settings
class Inner:
    rate: float = setting(1.0, kind=(int, float), min=0, max=10, doc="a rate")
    on: bool = setting(True, kind=bool, doc="a switch")


@settings
class Outer:
    name: str = setting(kind=str, doc="required")
    mode: str = setting("a", kind=str, choices=("a", "b"), doc="a choice")
    levels: tuple[int, ...] = setting((1,), kind=list, item=int, length=1, doc="a list")
    inner: Inner = dataclasses.field(default_factory=Inner)

    def __post_init__(self) -> None:
        if self.mode == "b" and self.inner.rate > 5:
            raise SettingError("mode", "must be 'a' when inner.rate > 5")


def test_the_dataclass_is_its_own_schema():
    schema = schema_of(Outer)
    assert list(schema) == ["name", "mode", "levels", "inner"]
    assert isinstance(schema["mode"], Rule) and schema["inner"]["rate"].max == 10
    assert optional_keys({"outer": Outer}) == ["outer.mode", "outer.levels", "outer.inner.rate", "outer.inner.on"]


def test_build_types_values_and_keeps_defaults():
    o = build(Outer, {"name": "x", "levels": [3], "inner": {"rate": 2}}, "outer")
    assert o.levels == (3,) and o.inner == Inner(2.0, True) and isinstance(o.inner.rate, float) and o.mode == "a"


@pytest.mark.parametrize("data, message", [
    ({}, "key 'outer.name' is missing"),
    ({"name": "x", "mode": "c"}, "key 'outer.mode' must be one of a, b, got 'c'"),
    ({"name": "x", "inner": {"rate": 11}}, "key 'outer.inner.rate' must be <= 10, got 11"),
    ({"name": "x", "inner": {"rate": float("nan")}}, "key 'outer.inner.rate' must be a finite number"),
    ({"name": "x", "inner": {"on": "yes"}}, "key 'outer.inner.on' must be true/false, got 'yes'"),
    ({"name": "x", "inner": {"rtae": 1}}, "unknown key 'outer.inner.rtae'; did you mean 'outer.inner.rate'?"),
    ({"name": "x", "inner": 5}, "key 'outer.inner' must be a mapping of keys, got 5"),
    ({"name": "x", "levels": [1, 2]}, "key 'outer.levels' must have 1 values, got 2"),
    ({"name": "x", "mode": "b", "inner": {"rate": 6}}, "key 'outer.mode' must be 'a' when inner.rate > 5"),
])
def test_every_problem_is_one_line_in_one_style(data, message):
    with pytest.raises(SettingError) as err:
        build(Outer, data, "outer")
    assert str(err.value) == message or str(err.value).startswith(message), str(err.value)
    assert "\n" not in str(err.value)


def test_building_directly_checks_the_fields_too():
    with pytest.raises(SettingError, match=r"key 'rate' must be >= 0, got -1"):
        Inner(rate=-1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        Inner().rate = 2.0  # type: ignore[misc]


def test_check_value_refuses_control_characters_and_huge_numbers():
    assert "control characters" in check_value("a\x00b", Rule(str))
    assert "sensible size" in check_value(10**13, Rule(int))
    assert check_value(None, Rule(str, nullable=True)) is None
    assert isinstance(UnknownKey("a", "b", ["c"]), SettingError)
